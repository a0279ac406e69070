// IMU simulation: exact specific force and angular rate from a trajectory, plus MEMS errors
// (white noise, bias random walk, random initial bias) and propeller vibration.
#pragma once

#include <cstdint>
#include <vector>

#include "diekf/sim/trajectory.h"
#include "diekf/types.h"

namespace diekf {
namespace sim {

/// Continuous-time noise densities in Kalibr's convention; defaults: consumer MEMS (BMI088 / MPU-6050 class).
struct ImuNoiseParams {
  double rate_hz = 500.0;
  double accel_noise_density = 2.0e-3;   ///< m/s^2/sqrt(Hz)
  double accel_random_walk = 4.0e-4;     ///< m/s^3/sqrt(Hz)
  double gyro_noise_density = 1.7e-4;    ///< rad/s/sqrt(Hz)
  double gyro_random_walk = 2.0e-5;      ///< rad/s^2/sqrt(Hz)
  double accel_bias_sigma = 0.05;        ///< initial accelerometer bias, 1-sigma per axis (m/s^2)
  double gyro_bias_sigma = 0.005;        ///< initial gyroscope bias, 1-sigma per axis (rad/s)
};

/// Propeller vibration: two tones whose frequency follows rotor speed (~ sqrt(thrust)), in 100..200 Hz.
struct VibrationParams {
  bool enabled = true;
  double hover_freq1_hz = 130.0;   ///< first tone at hover thrust (Hz); clamped to [100, 200]
  double hover_freq2_hz = 165.0;   ///< second tone at hover thrust (Hz)
  double accel_amplitude_mps2 = 1.5;  ///< peak amplitude per tone per axis (m/s^2, scaled per axis)
  double gyro_amplitude_radps = 0.03; ///< peak amplitude per tone per axis (rad/s)
};

struct ImuSimOptions {
  ImuNoiseParams noise;
  VibrationParams vibration;
  bool errors = true;  ///< false: exact readings (no noise, bias or vibration)
};

struct ImuSimResult {
  std::vector<ImuSample> samples;   ///< t_s on the simulation clock
  Vec3 accel_bias0 = Vec3::Zero();  ///< initial biases actually drawn (m/s^2, rad/s)
  Vec3 gyro_bias0 = Vec3::Zero();
};

/// Samples at t = k / rate_hz for k = 0 .. while t <= duration_s.
ImuSimResult simulateImu(const Trajectory& traj, double duration_s, const ImuSimOptions& opt, std::uint64_t seed);

}  // namespace sim
}  // namespace diekf
