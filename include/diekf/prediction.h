// Prediction: forward-Euler propagation of the state and its covariance over one IMU interval (ALGORITHM.md §2).
//
// Mean (a = a_m - b_a, w = w_m - b_w, s = mu . vartheta, g0 = gravity magnitude):
//   alpha'    = alpha (1 + s dt)
//   vartheta' = vartheta + dt (alpha (a + g0 g) - w x vartheta + s vartheta)
//   mu'       = exp(-dt (I - mu mu^T) w) mu,   g' = exp(-dt (I - g g^T) w) g
//   b_a', b_w' unchanged.
// Error convention x = x_hat [+] delta (State::boxplus / State::boxminus).
#pragma once

#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {

/// Number of noise inputs n (see NoiseIdx).
constexpr int kNoiseDim = 20;
using NoiseJacobian = Eigen::Matrix<double, kErrorDim, kNoiseDim>;
using NoiseVec = Eigen::Matrix<double, kNoiseDim, 1>;

/// Offsets of the blocks of the noise vector n of one prediction step. Each input enters the step as follows:
///   kAccel   (3) white noise added to the accelerometer reading a_m, m/s^2
///   kGyro    (3) white noise added to the gyroscope reading w_m, rad/s
///   kBaWalk  (3) accelerometer-bias random-walk increment over the step, m/s^2:   b_a' = b_a + n
///   kBwWalk  (3) gyroscope-bias random-walk increment over the step, rad/s:       b_w' = b_w + n
///   kAlpha   (1) process increment on alpha, 1/m:                                 alpha' += n
///   kVartheta(3) process increment on vartheta, 1/s:                              vartheta' += n
///   kMu      (2) process increment on mu, rad (tangent of mu'):                    mu' <- mu' [+] n
///   kG       (2) process increment on g, rad (tangent of g'):                      g' <- g' [+] n
struct NoiseIdx {
  static constexpr int kAccel = 0;
  static constexpr int kGyro = 3;
  static constexpr int kBaWalk = 6;
  static constexpr int kBwWalk = 9;
  static constexpr int kAlpha = 12;
  static constexpr int kVartheta = 13;
  static constexpr int kMu = 16;
  static constexpr int kG = 18;
};

/// Mean propagation. accel_C (m/s^2) and gyro_C (rad/s) are raw readings in C (biases subtracted inside).
State predictState(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s, double gravity_mps2);

/// F = d(f(x [+] dx) [-] f(x))/d dx and G = d(f(x, n) [-] f(x, 0))/d n, both at dx = 0, n = 0 (n as in
/// NoiseIdx, in its physical units). Either output pointer may be null.
void predictionJacobians(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s,
                         double gravity_mps2, ErrorCov* F, NoiseJacobian* G);

/// Per-step standard deviations of n (Q_d = diag(sigma^2)), so that G Q_d G^T grows linearly with dt:
/// white reading noise sigma = density / sqrt(dt); bias random walks sigma = random_walk * sqrt(dt);
/// process noises sigma = density * sqrt(dt). All zero for dt_s <= 0.
NoiseVec discreteNoiseSigmas(const ImuParams& imu, const ProcessNoiseParams& process, double dt_s);

/// x <- f(x), P <- F P F^T + G Q_d G^T (kept symmetric). No-op for dt_s <= 0. No heap allocation.
void predict(const Vec3& accel_C, const Vec3& gyro_C, double dt_s, const ImuParams& imu,
             const ProcessNoiseParams& process, State* x, ErrorCov* P);

}  // namespace diekf
