#!/usr/bin/env bash
# End-to-end demo without hardware or downloads: simulate a paper-like flight, run it through the estimator
# offline, print the evaluation and write plots, all into one folder.
#
#   scripts/demo.sh [OUTPUT_DIR]          (make demo: OUTPUT_DIR = demo_output/ in the package)
#
# Environment: DIEKF_BIN_DIR (folder with diekf_simulate and diekf_bag_runner; default: the catkin workspace's
# devel/lib/diekf, workspace from DIEKF_WS or the one `make build` uses, see `make ws-path`), DEMO_PRESET
# (flight4), DEMO_DURATION_S (30), DEMO_SEED (1), DEMO_MODE (iekf), DEMO_RUNNER_ARGS (extra runner arguments,
# e.g. "--width 90").
set -euo pipefail

script_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
pkg_dir=$(dirname "$script_dir")
out_dir=${1:-$pkg_dir/demo_output}
preset=${DEMO_PRESET:-flight4}
duration_s=${DEMO_DURATION_S:-30}
seed=${DEMO_SEED:-1}
mode=${DEMO_MODE:-iekf}
if [ -n "${DIEKF_BIN_DIR:-}" ]; then
  bin_dir=$DIEKF_BIN_DIR
else
  ws=${DIEKF_WS:-$(make -s --no-print-directory -C "$pkg_dir" ws-path 2>/dev/null || true)}
  bin_dir=$ws/devel/lib/diekf
fi

for tool in diekf_simulate diekf_bag_runner; do
  if [ ! -x "$bin_dir/$tool" ]; then
    echo "demo.sh: $bin_dir/$tool not found; build first (make build) or set DIEKF_BIN_DIR" >&2
    exit 1
  fi
done
python3 -c 'import matplotlib, numpy' 2>/dev/null || {
  echo "demo.sh: python3 with matplotlib and numpy is needed for the plots (apt-get install python3-matplotlib)" >&2
  exit 1
}

rm -rf "$out_dir"
mkdir -p "$out_dir/sequence"
start=$(date +%s)

echo "== 1/3 simulating $preset, $duration_s s (seed $seed) -> $out_dir/sequence"
"$bin_dir/diekf_simulate" --preset "$preset" --duration "$duration_s" --seed "$seed" \
  --output "$out_dir/sequence" | tee "$out_dir/simulate.log"

echo "== 2/3 running the estimator ($mode) on the simulated bag"
# shellcheck disable=SC2086
"$bin_dir/diekf_bag_runner" --bag "$out_dir/sequence/sequence.bag" --camchain "$out_dir/sequence/camchain.yaml" \
  --imu "$out_dir/sequence/imu.yaml" --mode "$mode" --sequence "$preset" --output "$out_dir" \
  ${DEMO_RUNNER_ARGS:-} | tee "$out_dir/summary.txt"

echo "== 3/3 plots"
python3 "$script_dir/plot_results.py" "$out_dir" --title "$preset ($mode)"

echo
echo "== demo finished in $(( $(date +%s) - start )) s; results in $out_dir"
echo "   estimates.csv groundtruth.csv evaluation.json, plots: distance.png velocity.png normal_gravity.png"
echo "   errors.png update_time.png"
cat "$out_dir/summary.txt"
# The paper's Table I (D-IEKF / D-EKF / LK) for the flight this preset imitates, for comparison.
declare -A paper_d=([flight1]="2.2 / 2.3 / 4.9" [flight2]="3.7 / 3.7 / 7.3" [flight3]="3.2 / 3.2 / 73.6"
  [flight4]="2.9 / 3.6 / 5.5" [flight5]="3.2 / 5.7 / 29.7" [flight6]="5.9 / 6.1 / 85.1" [flight7]="5.8 / diverged / 75.3")
declare -A paper_v=([flight1]="2.0 / 2.0 / 1.4" [flight2]="1.2 / 1.2 / 1.8" [flight3]="2.2 / 2.2 / 118.5"
  [flight4]="1.4 / 1.4 / 1.4" [flight5]="2.0 / 2.2 / 35.4" [flight6]="6.1 / 6.3 / 145.0" [flight7]="7.0 / diverged / 146.2")
if [ -n "${paper_d[$preset]:-}" ]; then
  echo "  paper, real $preset (D-IEKF / D-EKF / LK): distance RMSE ${paper_d[$preset]} cm," \
    "velocity RMSE ${paper_v[$preset]} cm/s"
fi
