// Prediction: forward-Euler propagation of the state and its covariance over one IMU interval (ALGORITHM.md §2).
#pragma once

#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {

/// Number of noise inputs: accel white (3), gyro white (3), accel bias walk (3), gyro bias walk (3),
/// alpha (1), vartheta (3), mu (2), g (2).
constexpr int kNoiseDim = 20;
using NoiseJacobian = Eigen::Matrix<double, kErrorDim, kNoiseDim>;
using NoiseVec = Eigen::Matrix<double, kNoiseDim, 1>;

/// Mean propagation. accel_C (m/s^2) and gyro_C (rad/s) are raw readings in C (biases subtracted inside).
State predictState(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s, double gravity_mps2);

/// F = d(x' [-] f(x))/d dx and G = d x'/d noise (noise as unit-variance-per-step inputs scaled inside by
/// sqrt(density^2 * dt)), both evaluated at x.
void predictionJacobians(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s,
                         double gravity_mps2, ErrorCov* F, NoiseJacobian* G);

/// Per-step noise standard deviations (diagonal of sqrt(Q_d)) for the inputs of NoiseJacobian.
NoiseVec discreteNoiseSigmas(const ImuParams& imu, const ProcessNoiseParams& process, double dt_s);

/// x <- f(x), P <- F P F^T + G Q G^T (kept symmetric).
void predict(const Vec3& accel_C, const Vec3& gyro_C, double dt_s, const ImuParams& imu,
             const ProcessNoiseParams& process, State* x, ErrorCov* P);

}  // namespace diekf
