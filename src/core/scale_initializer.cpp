#include "scale_initializer.h"

#include <Eigen/Cholesky>

namespace diekf {
namespace internal {

namespace {
constexpr int kUnknowns = 7;  // d_0, v_0 (3), c (3)
}

void ScaleInitializer::reset() {
  phase_ = Phase::kWaiting;
  rows_.clear();
  // Rows of the longest window, reserved once (no allocation per frame).
  const double per_s = 1.0 / std::max(cfg_.row_spacing_s, 1e-3);
  rows_.reserve(static_cast<size_t>(std::ceil(cfg_.max_window_s * per_s)) + 4);
  d0_m_ = 1.0;
  sigma_d0_m_ = 0.0;
}

void ScaleInitializer::step(double dt, const Vec3& accel, const Vec3& gyro) {
  // A direction fixed in the world turns by exp(-dt [w]x) seen from the camera (prediction.cpp); the specific
  // force is accumulated in C_0 at the step's middle rotation.
  const Mat3 half = expSO3(-0.5 * dt * gyro);
  const Mat3 mid = half * R_;
  last_accel_C0_ = mid.transpose() * accel;
  last_gyro_ = gyro;
  delta_ += dt * last_accel_C0_;
  R_ = half * mid;
}

bool ScaleInitializer::addFrame(double t_s, const State& x, const ErrorCov& P, const ImageVartheta* image) {
  if (phase_ == Phase::kDone || !(x.alpha > 0.0)) return false;
  const Mat3 P_vt = P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta);
  // The row's vartheta and the time it belongs to: the image's own measurement at its time (lag_s before t_s),
  // or the filter's at t_s.
  const Vec3& vartheta = image != nullptr ? image->vartheta : x.vartheta;
  const double lag = image != nullptr ? std::max(0.0, image->lag_s) : 0.0;
  const double t_meas_s = t_s - lag;
  const double s_now = x.mu.vector().dot(vartheta);  // d ln rho / dt = -mu . vartheta
  auto record = [&]() {
    Row r;
    r.t_s = t_meas_s - t_first_s_;
    // The rotation and the integrated specific force back to the measurement's time over the last IMU step.
    const Mat3 R = lag > 0.0 ? Mat3(expSO3(lag * last_gyro_) * R_) : R_;
    const double rho = std::exp(log_rho_);
    r.a = rho * (R.transpose() * vartheta);
    r.var_a = rho * rho * (image != nullptr ? image->cov.trace() : P_vt.trace()) / 3.0;
    r.delta = delta_ - lag * last_accel_C0_;
    if (rows_.size() < rows_.capacity()) rows_.push_back(r);
  };
  if (phase_ == Phase::kWaiting) {
    const Eigen::LDLT<Mat3> ldlt(P_vt);
    if (ldlt.info() != Eigen::Success) return false;
    const double chi2 = x.vartheta.dot(ldlt.solve(x.vartheta));
    if (!(chi2 > cfg_.motion_chi2)) return false;
    phase_ = Phase::kCollecting;
    t_first_s_ = t_s;  // the IMU is integrated from here (C_0: the camera at t_first_s_)
    R_.setIdentity();
    delta_.setZero();
    last_accel_C0_.setZero();
    last_gyro_.setZero();
    g_first_ = x.g.vector();
    const double g0 = cfg_.gravity_mps2;
    var_c_ = g0 * g0 * 0.5 * P.block<2, 2>(ErrIdx::kG, ErrIdx::kG).trace() +
             P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa).trace() / 3.0;
    rows_.clear();
    log_rho_ = 0.0;  // d_0: the distance at this frame's measurement
    s_last_ = s_now;
    t_last_s_ = t_meas_s;
    if (lag == 0.0) record();  // a measurement before t_first_s_ has no IMU to place it: from the next frame
    return false;
  }
  log_rho_ -= 0.5 * (s_last_ + s_now) * (t_meas_s - t_last_s_);
  s_last_ = s_now;
  t_last_s_ = t_meas_s;
  const double t_rel = t_s - t_first_s_;
  if (rows_.empty() || t_meas_s - t_first_s_ - rows_.back().t_s >= cfg_.row_spacing_s) record();
  if (t_rel >= cfg_.window_s && solve() && sigma_d0_m_ < cfg_.max_relative_sigma * d0_m_) {
    phase_ = Phase::kDone;
    // The distance at t_s: d_0 rho at the last measurement, then on over the lag.
    const double rho = std::exp(log_rho_ - lag * s_now);
    distance_m_ = d0_m_ * rho;
    sigma_distance_m_ = sigma_d0_m_ * rho;
    return true;
  }
  if (t_rel >= cfg_.max_window_s) phase_ = Phase::kDone;  // not enough motion: the filter goes on without
  return false;
}

bool ScaleInitializer::solve() {
  if (rows_.size() < 4 || !(var_c_ > 0.0)) return false;
  const double g0 = cfg_.gravity_mps2;
  const double q = cfg_.accel_noise_density * cfg_.accel_noise_density;
  double s = 1.0;  // d_0 (the rows' weights depend on it)
  // Row r: A theta = target, A = [a | -I | -t I], weighted by the inverse of its variance at d_0 = s.
  const auto target = [&](const Row& r) -> Vec3 { return r.delta + g0 * r.t_s * g_first_; };
  const auto weight = [&](const Row& r) { return 1.0 / (s * s * r.var_a + q * r.t_s + 1e-8); };
  Eigen::Matrix<double, kUnknowns, kUnknowns> N;
  Eigen::Matrix<double, kUnknowns, 1> theta;
  for (int iter = 0; iter < 3; ++iter) {
    N.setZero();
    Eigen::Matrix<double, kUnknowns, 1> rhs = Eigen::Matrix<double, kUnknowns, 1>::Zero();
    for (int i = 4; i < kUnknowns; ++i) N(i, i) = 1.0 / var_c_;  // prior c ~ N(0, var_c I)
    for (const Row& r : rows_) {
      Eigen::Matrix<double, 3, kUnknowns> A;
      A.col(0) = r.a;
      A.block<3, 3>(0, 1) = -Mat3::Identity();
      A.block<3, 3>(0, 4) = -r.t_s * Mat3::Identity();
      const double w = weight(r);
      N += w * A.transpose() * A;
      rhs += w * A.transpose() * target(r);
    }
    const Eigen::LDLT<Eigen::Matrix<double, kUnknowns, kUnknowns>> ldlt(N);
    if (ldlt.info() != Eigen::Success) return false;
    theta = ldlt.solve(rhs);
    if (!theta.allFinite() || !(theta(0) > 0.0)) return false;
    s = theta(0);
  }
  // Weighted residual (rows and prior) against its degrees of freedom: a fit worse than its noise widens the
  // 1-sigma (model error: the window's velocities, gravity, bias).
  double chi2 = theta.tail<3>().squaredNorm() / var_c_;
  for (const Row& r : rows_) {
    const Vec3 e = s * r.a - theta.segment<3>(1) - r.t_s * theta.tail<3>() - target(r);
    chi2 += e.squaredNorm() * weight(r);
  }
  const double dof = 3.0 * static_cast<double>(rows_.size()) + 3.0 - kUnknowns;
  const Eigen::Matrix<double, kUnknowns, kUnknowns> cov =
      N.ldlt().solve(Eigen::Matrix<double, kUnknowns, kUnknowns>::Identity());
  const double var_s = cov(0, 0) * std::max(1.0, chi2 / std::max(dof, 1.0));
  if (!(var_s > 0.0) || !std::isfinite(var_s)) return false;
  d0_m_ = s;
  sigma_d0_m_ = std::sqrt(var_s);
  return true;
}

}  // namespace internal
}  // namespace diekf
