// Prediction: propagation of the state and its covariance over one IMU step (docs/algorithm.md §2).
//
// Mean over a step dt with the mean readings a_m, w_m over it (a = a_m - b_a, w = w_m - b_w, g0 = gravity
// magnitude, R = exp(-dt [w]x) the turn of world-fixed directions seen from C):
//   u         = R (vartheta + dt alpha g0 g) + dt alpha (I - dt/2 [w]x) a     (v(t+dt) / d(t), in C(t+dt))
//   s0 = mu . vartheta,  s1 = (1 + dt s0) (R mu) . u,  kappa = exp(dt (s0 + s1) / 2)   (= d(t) / d(t+dt))
//   alpha' = kappa alpha,  vartheta' = kappa u,  mu' = R mu,  g' = R g,  b_a', b_w' unchanged.
// Exact in the rotation and the gravity term for a constant rate, second order in the rest; the step is
// meant to be fed the mean of the (interpolated) readings over it (meanImuOver), not a sample held over it.
// Error convention x = x_hat [+] delta (State::boxplus / State::boxminus).
#pragma once

#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {

/// Mean of the linear interpolation between two consecutive filtered samples `prev` and `next` over the
/// sub-interval [t0_s, t1_s] of [prev.t_s, next.t_s], i.e. its value at the midpoint (t_s set to t1_s). The
/// prediction step is fed this (the integral of the inputs is then second-order accurate; holding `next` over
/// the step is first order: a time error of half the step).
ImuSample meanImuOver(const ImuSample& prev, const ImuSample& next, double t0_s, double t1_s);

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
/// `column_accel_C` (optional, m/s^2): the acceleration at the step's start in C (specific force plus gravity,
/// bias removed) that the distance's column of F uses instead of the reading's a - b_a + g0 g (docs/algorithm.md
/// section 2.1, "The distance's column"); the mean is unchanged. `sensitivity` (optional): an error-state
/// direction carried by the dynamics, s <- F s (the focal length's, FrameResult::focal_sensitivity).
void predict(const Vec3& accel_C, const Vec3& gyro_C, double dt_s, const ImuParams& imu,
             const ProcessNoiseParams& process, State* x, ErrorCov* P, const Vec3* column_accel_C = nullptr,
             ErrorVec* sensitivity = nullptr);

}  // namespace diekf
