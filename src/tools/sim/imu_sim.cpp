#include "diekf/sim/imu_sim.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace diekf {
namespace sim {

ImuSimResult simulateImu(const Trajectory& traj, double duration_s, const ImuSimOptions& opt, std::uint64_t seed) {
  ImuSimResult res;
  std::mt19937_64 rng(seed ^ 0xA5A5A5A5DEADBEEFull);
  std::normal_distribution<double> nd(0.0, 1.0);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const ImuNoiseParams& N = opt.noise;
  const double dt = 1.0 / N.rate_hz;
  const auto gauss3 = [&]() { return Vec3(nd(rng), nd(rng), nd(rng)); };

  Vec3 ba = Vec3::Zero(), bw = Vec3::Zero();
  if (opt.errors) {
    ba = N.accel_bias_sigma * gauss3();
    bw = N.gyro_bias_sigma * gauss3();
  }
  res.accel_bias0 = ba;
  res.gyro_bias0 = bw;
  // Vibration: per-axis amplitude factors and phases (accelerometer z, along thrust, strongest).
  const VibrationParams& V = opt.vibration;
  const bool vib = opt.errors && V.enabled;
  Vec3 acc_amp[2], gyr_amp[2];
  double phase[2] = {2 * M_PI * uni(rng), 2 * M_PI * uni(rng)};
  Vec3 axis_phase[2];
  for (int k = 0; k < 2; ++k) {
    acc_amp[k] = V.accel_amplitude_mps2 * Vec3(0.4 + 0.4 * uni(rng), 0.4 + 0.4 * uni(rng), 0.8 + 0.4 * uni(rng));
    gyr_amp[k] = V.gyro_amplitude_radps * Vec3(0.5 + 0.5 * uni(rng), 0.5 + 0.5 * uni(rng), 0.3 + 0.3 * uni(rng));
    axis_phase[k] = Vec3(2 * M_PI * uni(rng), 2 * M_PI * uni(rng), 2 * M_PI * uni(rng));
  }
  const double f_hover[2] = {std::clamp(V.hover_freq1_hz, 100.0, 200.0), std::clamp(V.hover_freq2_hz, 100.0, 200.0)};

  const double sa = N.accel_noise_density / std::sqrt(dt), sw = N.gyro_noise_density / std::sqrt(dt);
  const double rwa = N.accel_random_walk * std::sqrt(dt), rww = N.gyro_random_walk * std::sqrt(dt);
  const long n = static_cast<long>(std::floor(duration_s * N.rate_hz + 1e-9)) + 1;
  res.samples.reserve(static_cast<std::size_t>(n));
  for (long i = 0; i < n; ++i) {
    const double t = i * dt;
    const KinematicState k = traj.evaluate(t);
    ImuSample s;
    s.t_s = t;
    s.accel_mps2 = k.f_I;
    s.gyro_radps = k.w_I;
    if (opt.errors) {
      s.accel_mps2 += ba + sa * gauss3();
      s.gyro_radps += bw + sw * gauss3();
      ba += rwa * gauss3();
      bw += rww * gauss3();
    }
    if (vib) {
      const double thrust_ratio = std::sqrt(std::max(0.1, k.f_I.norm() / kGravityMps2));
      for (int j = 0; j < 2; ++j) {
        const double f = std::clamp(f_hover[j] * thrust_ratio, 100.0, 200.0);
        phase[j] += 2 * M_PI * f * dt;
        for (int a = 0; a < 3; ++a) {
          s.accel_mps2[a] += acc_amp[j][a] * std::sin(phase[j] + axis_phase[j][a]);
          s.gyro_radps[a] += gyr_amp[j][a] * std::sin(phase[j] + axis_phase[j][a] + 1.0);
        }
      }
    }
    res.samples.push_back(s);
  }
  return res;
}

}  // namespace sim
}  // namespace diekf
