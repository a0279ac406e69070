// Cost of one prediction step (state + covariance) and of one raw IMU sample through the preprocessor.
#include <benchmark/benchmark.h>

#include <cmath>

#include "diekf/imu_filter.h"
#include "diekf/prediction.h"

namespace {

using diekf::ErrorCov;
using diekf::ImuParams;
using diekf::ImuPreprocessor;
using diekf::ImuSample;
using diekf::ProcessNoiseParams;
using diekf::State;
using diekf::UnitVector;
using diekf::Vec3;

void BM_PredictStep(benchmark::State& bs) {
  const ImuParams imu;
  const ProcessNoiseParams process;
  State x;
  x.alpha = 1.0;
  x.vartheta = Vec3(0.1, -0.05, 0.02);
  x.mu = UnitVector(Vec3(0.2, -0.1, 0.97));
  x.g = UnitVector(Vec3(0.05, 0.02, 1.0));
  ErrorCov P = ErrorCov::Identity() * 0.01;
  const Vec3 gyro_radps(0.02, -0.01, 0.03);
  double t = 0.0;
  for (auto _ : bs) {
    // Hover-like, slowly varying input so the state stays bounded over millions of iterations.
    const Vec3 accel_mps2 = -imu.gravity_mps2 * x.g.vector() + Vec3(0.1 * std::sin(t), 0.0, 0.0);
    diekf::predict(accel_mps2, gyro_radps, 0.01, imu, process, &x, &P);
    t += 0.01;
    if (t > 100.0) {  // keep the covariance in a realistic range
      P = ErrorCov::Identity() * 0.01;
      t = 0.0;
    }
    benchmark::DoNotOptimize(P.data());
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_PredictStep);

// Arg 500: the default design (order 2); arg 200: a rate that folds the vibration (order 4 and the notches, their
// spectrum of 256 samples every 32, here on two folded tones so that both notches run).
void BM_ImuPreprocessorPush(benchmark::State& bs) {
  ImuParams params;
  params.input_rate_hz = static_cast<double>(bs.range(0));
  params.decimation_factor = static_cast<int>(bs.range(0) / 100);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.5 * M_PI, Vec3::UnitZ()).toRotationMatrix();
  T.translation() = Vec3(0.05, 0.01, 0.02);
  ImuPreprocessor pre(T, params);
  ImuSample s, out;
  int k = 0;
  for (auto _ : bs) {
    s.t_s = k / params.input_rate_hz;
    const double t = s.t_s;
    const double vib = std::sin(2 * M_PI * 130.0 * t) + std::sin(2 * M_PI * 165.0 * t);  // folded at 200 Hz
    s.accel_mps2 = Vec3(0.1 + vib, std::sin(0.1 * k), 9.81);
    s.gyro_radps = Vec3(0.01, 0.02, std::cos(0.07 * k));
    benchmark::DoNotOptimize(pre.push(s, &out));
    benchmark::ClobberMemory();
    ++k;
  }
}
BENCHMARK(BM_ImuPreprocessorPush)->Arg(500)->Arg(200);

}  // namespace
