#include "diekf/state.h"

#include <algorithm>
#include <cmath>

namespace diekf {

State State::boxplus(const ErrorVec& delta) const {
  State out;
  out.alpha = alpha + delta(ErrIdx::kAlpha);
  out.vartheta = vartheta + delta.segment<3>(ErrIdx::kVartheta);
  out.mu = mu.boxplus(delta.segment<2>(ErrIdx::kMu));
  out.g = g.boxplus(delta.segment<2>(ErrIdx::kG));
  out.b_a = b_a + delta.segment<3>(ErrIdx::kBa);
  out.b_w = b_w + delta.segment<3>(ErrIdx::kBw);
  out.t_d_s = t_d_s + delta(ErrIdx::kTd);
  out.readout_s = readout_s + delta(ErrIdx::kRo);
  out.focal_scale = focal_scale + delta(ErrIdx::kFs);
  return out;
}

ErrorVec State::boxminus(const State& other) const {
  ErrorVec e;
  e(ErrIdx::kAlpha) = alpha - other.alpha;
  e.segment<3>(ErrIdx::kVartheta) = vartheta - other.vartheta;
  e.segment<2>(ErrIdx::kMu) = mu.boxminus(other.mu);
  e.segment<2>(ErrIdx::kG) = g.boxminus(other.g);
  e.segment<3>(ErrIdx::kBa) = b_a - other.b_a;
  e.segment<3>(ErrIdx::kBw) = b_w - other.b_w;
  e(ErrIdx::kTd) = t_d_s - other.t_d_s;
  e(ErrIdx::kRo) = readout_s - other.readout_s;
  e(ErrIdx::kFs) = focal_scale - other.focal_scale;
  return e;
}

ErrorCov State::boxminusJacobian(const State& ref) const {
  ErrorCov L = ErrorCov::Identity();
  L.block<2, 2>(ErrIdx::kMu, ErrIdx::kMu) = mu.boxminusJacobian(ref.mu);
  L.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = g.boxminusJacobian(ref.g);
  return L;
}

bool State::allFinite() const {
  return std::isfinite(alpha) && vartheta.allFinite() && mu.quaternion().coeffs().allFinite() &&
         g.quaternion().coeffs().allFinite() && b_a.allFinite() && b_w.allFinite() && std::isfinite(t_d_s) &&
         std::isfinite(readout_s) && std::isfinite(focal_scale);
}

double sigmaDistance_m(const State& x, const ErrorCov& P) {
  // d = 1/alpha  =>  sigma_d = sigma_alpha / alpha^2.
  const double var_alpha = std::max(0.0, P(ErrIdx::kAlpha, ErrIdx::kAlpha));
  return std::sqrt(var_alpha) / (x.alpha * x.alpha);
}

double relativeSigmaDistance(const State& x, const ErrorCov& P) {
  return std::sqrt(std::max(0.0, P(ErrIdx::kAlpha, ErrIdx::kAlpha))) / x.alpha;
}

Mat3 velocityCovariance(const State& x, const ErrorCov& P) {
  // v = vartheta / alpha  =>  dv = dvartheta / alpha - vartheta / alpha^2 dalpha.
  Eigen::Matrix<double, 3, 4> J;
  J.col(0) = -x.vartheta / (x.alpha * x.alpha);
  J.rightCols<3>() = Mat3::Identity() / x.alpha;
  const Eigen::Matrix4d S = P.block<4, 4>(ErrIdx::kAlpha, ErrIdx::kAlpha);  // alpha, vartheta
  return J * S * J.transpose();
}

Vec3 sigmaVelocity_mps(const State& x, const ErrorCov& P) {
  return velocityCovariance(x, P).diagonal().cwiseMax(0.0).cwiseSqrt();
}

void addScaleAmbiguity(const State& x, double relative_var, ErrorCov* P) {
  if (!(relative_var > 0.0)) return;
  ErrorVec g = ErrorVec::Zero();
  g(ErrIdx::kAlpha) = x.alpha;
  g.segment<3>(ErrIdx::kVartheta) = x.vartheta;
  P->noalias() += relative_var * g * g.transpose();
}

void addMotionAmbiguity(const State& x, double relative_var, ErrorCov* P) {
  if (!(relative_var > 0.0)) return;
  P->block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta).noalias() += relative_var * x.vartheta * x.vartheta.transpose();
}

void addFrameRotationUncertainty(const State& x, double var_rad2, ErrorCov* P) {
  if (!(var_rad2 > 0.0)) return;
  // Error of the state per unit rotation dtheta of the frame: d vartheta = dtheta x vartheta = -[vartheta]x dtheta;
  // a unit vector n turned by dtheta is n [+] N^T dtheta (n [+] d = exp(N d) n, N orthonormal and perpendicular
  // to n: the rotation about n itself leaves it).
  Eigen::Matrix<double, kErrorDim, 3> G = Eigen::Matrix<double, kErrorDim, 3>::Zero();
  G.block<3, 3>(ErrIdx::kVartheta, 0) = -skew(x.vartheta);
  G.block<2, 3>(ErrIdx::kMu, 0) = x.mu.N().transpose();
  G.block<2, 3>(ErrIdx::kG, 0) = x.g.N().transpose();
  P->noalias() += var_rad2 * G * G.transpose();
}

}  // namespace diekf
