// One photometric update pass (max_passes = 1, stop_threshold = 0: reference packing, linearisation sweep (which
// also fills the residual image and RMS), 14x14 solve, covariance) and three passes at the working resolutions of
// interest, on rendered textured images.
// Also the bare linearisation sweep, to separate the pixel loop from the fixed per-update cost.
#include <map>
#include <memory>
#include <vector>

#include <benchmark/benchmark.h>

#include "../test/core/two_view_scene.h"
#include "diekf/photometric_update.h"

namespace {

using diekf::test_util::TwoViewScene;

const TwoViewScene& sceneForWidth(int width_px) {
  static std::map<int, std::unique_ptr<TwoViewScene>> cache;
  auto it = cache.find(width_px);
  if (it == cache.end()) {
    const int height_px = width_px == 90 ? 58 : width_px == 180 ? 116 : 240;
    it = cache
             .emplace(width_px, std::make_unique<TwoViewScene>(
                                    diekf::test_util::makeTwoViewScene(width_px, height_px, 2)))
             .first;
  }
  return *it->second;
}

diekf::State startState(const TwoViewScene& s) {
  diekf::State x;
  x.alpha = 1.0 / s.truth.d_m;
  x.mu = diekf::UnitVector(s.truth.mu);
  return x;
}

diekf::ErrorCov priorCov() {
  diekf::ErrorVec sd;
  sd << 0.5, 0.5, 0.5, 0.5, 0.1, 0.1, 0.05, 0.05, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01, 0.005, 0.005, 0.01;
  return sd.array().square().matrix().asDiagonal();
}

// One update with exactly `passes` Gauss-Newton passes (stop_threshold = 0: all of them run).
void runPhotometricUpdate(benchmark::State& bs, int passes) {
  const TwoViewScene& s = sceneForWidth(static_cast<int>(bs.range(0)));
  diekf::PhotometricParams params;
  params.max_passes = passes;
  params.stop_threshold = 0.0;
  diekf::PhotometricUpdate update(params, diekf::PreprocessParams{});
  const diekf::State x0 = startState(s);
  const diekf::ErrorCov P0 = priorCov();
  for (auto _ : bs) {
    diekf::State x = x0;
    diekf::ErrorCov P = P0;
    const diekf::UpdateStats st = update.update(s.ref, s.cur, s.K, s.w_C, s.dt_s, &x, &P);
    benchmark::DoNotOptimize(st);
    benchmark::DoNotOptimize(x);
    if (!st.applied || st.passes != passes) bs.SkipWithError("update not applied with the requested passes");
  }
  bs.counters["px"] = s.K.width * s.K.height;
}

void BM_PhotometricUpdateOnePass(benchmark::State& bs) { runPhotometricUpdate(bs, 1); }
BENCHMARK(BM_PhotometricUpdateOnePass)->Arg(90)->Arg(180)->Arg(376)->Unit(benchmark::kMicrosecond);

// The same with the image timing of the default estimator (docs/algorithm.md sections 3.6-3.7): the camera-IMU
// time offset and the rolling-shutter readout estimated, a 16 ms readout (each row warped at its own time); and
// with the focal-length scale estimated as well (section 3.8: its column's fit over a 5x5 grid per pass).
void runTimedUpdate(benchmark::State& bs, bool focal_scale) {
  const TwoViewScene& s = sceneForWidth(static_cast<int>(bs.range(0)));
  diekf::PhotometricParams params;
  params.max_passes = 1;
  params.stop_threshold = 0.0;
  diekf::PhotometricUpdate update(params, diekf::PreprocessParams{});
  diekf::State x0 = startState(s);
  x0.readout_s = 0.016;
  const diekf::ErrorCov P0 = priorCov();
  std::vector<float> row_weight(static_cast<size_t>(s.K.height));
  for (int y = 0; y < s.K.height; ++y) row_weight[static_cast<size_t>(y)] = (y - 0.5 * (s.K.height - 1)) / s.K.height;
  diekf::ImageTiming timing;
  timing.estimate_offset = true;
  timing.estimate_readout = true;
  timing.estimate_focal_scale = focal_scale;
  timing.rates_valid = true;
  timing.accel_C = diekf::Vec3(0.3, -0.2, -9.7);
  timing.rate_change_C = diekf::Vec3(0.02, -0.01, 0.03);
  timing.row_weight = row_weight.data();
  timing.rows = s.K.height;
  for (auto _ : bs) {
    diekf::State x = x0;
    diekf::ErrorCov P = P0;
    const diekf::UpdateStats st = update.update(s.ref, s.cur, s.K, s.w_C, s.dt_s, &x, &P, 0.0, timing);
    benchmark::DoNotOptimize(st);
    benchmark::DoNotOptimize(x);
    if (!st.applied || st.passes != 1) bs.SkipWithError("update not applied");
  }
  bs.counters["px"] = s.K.width * s.K.height;
}
void BM_PhotometricUpdateOnePassTimed(benchmark::State& bs) { runTimedUpdate(bs, false); }
BENCHMARK(BM_PhotometricUpdateOnePassTimed)->Arg(90)->Arg(180)->Arg(376)->Unit(benchmark::kMicrosecond);
void BM_PhotometricUpdateOnePassCalibrated(benchmark::State& bs) { runTimedUpdate(bs, true); }
BENCHMARK(BM_PhotometricUpdateOnePassCalibrated)->Arg(90)->Arg(180)->Arg(376)->Unit(benchmark::kMicrosecond);

// The per-pass cost is (this - one pass) / 2.
void BM_PhotometricUpdateThreePasses(benchmark::State& bs) { runPhotometricUpdate(bs, 3); }
BENCHMARK(BM_PhotometricUpdateThreePasses)->Arg(90)->Arg(180)->Arg(376)->Unit(benchmark::kMicrosecond);

void BM_PhotometricLinearize(benchmark::State& bs) {
  const TwoViewScene& s = sceneForWidth(static_cast<int>(bs.range(0)));
  diekf::PhotometricUpdate update(diekf::PhotometricParams{}, diekf::PreprocessParams{});
  const diekf::State x = startState(s);
  diekf::ObservedInfo A;
  diekf::ObservedVec b;
  for (auto _ : bs) {
    const int valid = update.linearize(s.ref, s.cur, s.K, s.w_C, s.dt_s, x, &A, &b);
    benchmark::DoNotOptimize(valid);
    benchmark::DoNotOptimize(A);
  }
  bs.counters["px"] = s.K.width * s.K.height;
}
BENCHMARK(BM_PhotometricLinearize)->Arg(90)->Arg(180)->Arg(376)->Unit(benchmark::kMicrosecond);

}  // namespace
