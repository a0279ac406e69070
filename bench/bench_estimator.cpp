// The Estimator facade per camera frame, as the ROS node drives it: 500 Hz raw IMU samples (about 17 per frame,
// through the IMU low-pass/decimation, 3-4 prediction steps) and one 752x480 image (copy, preprocessing to the
// working size, iterated photometric update with covariance). A periodic flight over a textured plane
// (test/core/periodic_flight.h) supplies the images, pre-rendered once; the filter is warmed up for 2 s before
// timing. Counter update_ms: the Estimator's own FrameResult::update_ms (wall time of preprocessing + update).
#include <map>
#include <memory>

#include <benchmark/benchmark.h>

#include "../test/core/periodic_flight.h"
#include "diekf/estimator.h"

namespace {

using diekf::test_util::PeriodicFlight;

const PeriodicFlight& flight() {
  static const PeriodicFlight f(30);
  return f;
}

struct Driver {
  explicit Driver(const diekf::EstimatorParams& params) : estimator(flight().camera(), params) {}
  diekf::Estimator estimator;
  long frame = 0;
  long imu = 0;
  diekf::FrameResult result;
  double update_ms_sum = 0.0;
  long results = 0;
};

// One camera frame: the IMU samples up to 50 ms past the image (covers the IMU filter's delay), then the image.
inline void step(Driver* d) {
  const PeriodicFlight& f = flight();
  const double t_img = d->frame / PeriodicFlight::kCameraRateHz;
  while (d->imu / PeriodicFlight::kImuRateHz <= t_img + 0.05) {
    d->estimator.addImu(f.imu(d->imu / PeriodicFlight::kImuRateHz));
    ++d->imu;
  }
  d->estimator.addImage(t_img, f.image(d->frame));
  ++d->frame;
  while (d->estimator.popResult(&d->result)) {
    d->update_ms_sum += d->result.update_ms;
    ++d->results;
  }
}

// The frames before the timed ones, under another name: scripts/callgrind_per_call.py's '*feedFrame*' counts the
// timed frames only. (Google Benchmark runs a case more than once, each run with its own warm-up: counted with the
// timed frames, the warm-ups were most of the difference between two runs.)
[[gnu::noinline]] void warmUp(Driver* d, int frames) {
  for (int i = 0; i < frames; ++i) step(d);
}

// A timed frame.
[[gnu::noinline]] void feedFrame(Driver* d) { step(d); }

void runFrames(benchmark::State& bs, const diekf::EstimatorParams& params) {
  Driver d(params);
  warmUp(&d, 60);  // 2 s: converged, buffers allocated
  d.update_ms_sum = 0.0;
  d.results = 0;
  int passes = 0;
  for (auto _ : bs) {
    feedFrame(&d);
    passes += d.result.passes;
    benchmark::ClobberMemory();
  }
  if (d.result.status != diekf::FilterStatus::kTracking) bs.SkipWithError("filter not tracking");
  bs.counters["update_ms"] = d.results > 0 ? d.update_ms_sum / d.results : 0.0;
  bs.counters["passes"] = static_cast<double>(passes) / static_cast<double>(bs.iterations());
}

void BM_EstimatorFrame(benchmark::State& bs) {
  diekf::EstimatorParams params;
  params.preprocess.working_width_px = static_cast<int>(bs.range(0));
  params.mode = bs.range(1) == 0 ? diekf::UpdateMode::kIterated : diekf::UpdateMode::kEkf;
  params.init.alpha0_inv_m = 1.0;  // start near the truth (d = 1 m): timing of the tracking phase
  runFrames(bs, params);
}

// The same frame with the pair's brightness estimated (photometric/brightness_model; docs/noise_model.md
// section 12).
void BM_EstimatorFrameBrightness(benchmark::State& bs) {
  diekf::EstimatorParams params;
  params.preprocess.working_width_px = static_cast<int>(bs.range(0));
  params.photometric.brightness_model =
      bs.range(1) == 1 ? diekf::BrightnessModel::kGain : diekf::BrightnessModel::kAffine;
  params.init.alpha0_inv_m = 1.0;
  runFrames(bs, params);
}
// Args: working width (px), mode (0 = iterated "iekf", 3 passes max; 1 = one pass "ekf").
BENCHMARK(BM_EstimatorFrame)
    ->Args({90, 0})
    ->Args({90, 1})
    ->Args({180, 0})
    ->Args({376, 0})
    ->Unit(benchmark::kMillisecond);
// Args: working width (px), brightness model (1 = gain, 2 = affine).
BENCHMARK(BM_EstimatorFrameBrightness)->Args({90, 1})->Args({90, 2})->Args({180, 1})->Args({180, 2})
    ->Unit(benchmark::kMillisecond);

}  // namespace
