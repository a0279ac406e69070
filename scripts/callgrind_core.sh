#!/bin/bash
# Instructions per call (valgrind callgrind) of the core's per-frame functions, from the Google Benchmark cases of
# diekf_benchmark. Usage (from the catkin workspace, after `catkin_make diekf_benchmark`):
#   bash <package>/scripts/callgrind_core.sh devel/lib/diekf/diekf_benchmark
# or `make benchmark-callgrind` in the package. Takes several minutes (valgrind runs each case twice).
set -euo pipefail
BENCH=${1:?path of diekf_benchmark}
PER_CALL="python3 $(dirname "$0")/callgrind_per_call.py"
for size in 90/58 180/116 376/240; do
  echo -n "preprocess ${size}: "
  $PER_CALL --function 'diekf::ImagePreprocessor::process*' -- "$BENCH" --benchmark_filter="BM_PreprocessFrame/${size}\$"
done
for w in 90 180 376; do
  echo -n "update, 1 pass, ${w}: "
  $PER_CALL --function 'diekf::PhotometricUpdate::update*' -- "$BENCH" --benchmark_filter="BM_PhotometricUpdateOnePass/${w}\$"
  echo -n "update, 3 passes, ${w}: "
  $PER_CALL --function 'diekf::PhotometricUpdate::update*' -- "$BENCH" --benchmark_filter="BM_PhotometricUpdateThreePasses/${w}\$"
  echo -n "linearisation sweep, ${w}: "
  $PER_CALL --function 'diekf::PhotometricUpdate::linearize*' -- "$BENCH" --benchmark_filter="BM_PhotometricLinearize/${w}\$"
done
echo -n "projector-dot detector, one sampled 752x480 image: "
$PER_CALL --function 'diekf::internal::DotDetector::addImage*' -- "$BENCH" --benchmark_filter='BM_DotDetectorAddImage$'
echo -n "prediction step: "
$PER_CALL --function 'diekf::predict(*' -- "$BENCH" --benchmark_filter='BM_PredictStep$'
for args in 90/0 90/1 180/0 376/0; do
  echo -n "Estimator frame ${args} (IMU + image): "
  $PER_CALL --min-times 0.1,0.5 --function '*feedFrame*' -- "$BENCH" --benchmark_filter="BM_EstimatorFrame/${args}\$"
done
