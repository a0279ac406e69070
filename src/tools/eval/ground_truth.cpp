#include "diekf/eval/ground_truth.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace diekf {
namespace eval {

namespace {

constexpr double kPi = 3.14159265358979323846;

bool finitePose(const PoseSample& pose) {
  return std::isfinite(pose.t_s) && pose.p_WI_m.allFinite() && pose.q_WI.coeffs().allFinite() &&
         pose.q_WI.norm() > 1e-9;
}

}  // namespace

GroundPlane GroundPlane::fromCoefficients(double a, double b, double c, double e) {
  const Eigen::Vector3d n(a, b, c);
  const double norm = n.norm();
  if (!n.allFinite() || !std::isfinite(e) || norm < 1e-12) {
    throw std::invalid_argument("plane coefficients need a finite non-zero normal (a, b, c)");
  }
  GroundPlane plane;
  plane.n_W = n / norm;
  plane.e_m = e / norm;
  return plane;
}

GroundPlane GroundPlane::inclined(double incline_deg) {
  const double a = incline_deg * kPi / 180.0;
  return fromCoefficients(0.0, -std::sin(a), std::cos(a), 0.0);
}

GroundTruth::GroundTruth(std::vector<PoseSample> poses, const GroundPlane& plane,
                         const Eigen::Isometry3d& T_cam_imu, const GroundTruthOptions& options) {
  for (const PoseSample& pose : poses) {
    if (!finitePose(pose)) {
      throw std::invalid_argument("ground truth: non-finite pose at t = " + std::to_string(pose.t_s) + " s");
    }
  }
  std::stable_sort(poses.begin(), poses.end(),
                   [](const PoseSample& a, const PoseSample& b) { return a.t_s < b.t_s; });
  for (const PoseSample& pose : poses) {
    if (!poses_.empty() && pose.t_s <= poses_.back().t_s) continue;  // duplicated stamp
    PoseSample p = pose;
    p.q_WI.normalize();
    // Keep consecutive quaternions in the same hemisphere so that slerp takes the short way.
    if (!poses_.empty() && poses_.back().q_WI.coeffs().dot(p.q_WI.coeffs()) < 0.0) p.q_WI.coeffs() *= -1.0;
    poses_.push_back(p);
  }
  if (poses_.size() < 2) {
    throw std::invalid_argument("ground truth needs at least two poses with distinct stamps (got " +
                                std::to_string(poses_.size()) + ")");
  }
  const GroundPlane unit = GroundPlane::fromCoefficients(plane.n_W.x(), plane.n_W.y(), plane.n_W.z(), plane.e_m);
  n_W_ = unit.n_W;
  e_m_ = unit.e_m;
  const Eigen::Isometry3d T_IC = T_cam_imu.inverse();
  R_IC_ = T_IC.linear();
  t_IC_m_ = T_IC.translation();

  // Camera centre at every pose stamp, then central differences over +-k samples.
  const std::size_t n = poses_.size();
  std::vector<Eigen::Vector3d> p_WC(n);
  for (std::size_t i = 0; i < n; ++i) p_WC[i] = poses_[i].p_WI_m + poses_[i].q_WI * t_IC_m_;
  const double mean_dt_s = (poses_.back().t_s - poses_.front().t_s) / static_cast<double>(n - 1);
  std::size_t k = 1;
  if (options.velocity_window_s > 0.0 && mean_dt_s > 0.0) {
    k = std::max<std::size_t>(1, static_cast<std::size_t>(std::lround(0.5 * options.velocity_window_s / mean_dt_s)));
  }
  v_WC_mps_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t lo = i >= k ? i - k : 0;
    const std::size_t hi = std::min(n - 1, i + k);
    v_WC_mps_[i] = (p_WC[hi] - p_WC[lo]) / (poses_[hi].t_s - poses_[lo].t_s);
  }
}

PoseSample GroundTruth::poseAt(double t_s) const {
  if (t_s <= poses_.front().t_s) return poses_.front();
  if (t_s >= poses_.back().t_s) return poses_.back();
  const auto it = std::upper_bound(poses_.begin(), poses_.end(), t_s,
                                   [](double t, const PoseSample& p) { return t < p.t_s; });
  const PoseSample& b = *it;
  const PoseSample& a = *(it - 1);
  const double s = (t_s - a.t_s) / (b.t_s - a.t_s);
  PoseSample out;
  out.t_s = t_s;
  out.p_WI_m = (1.0 - s) * a.p_WI_m + s * b.p_WI_m;
  out.q_WI = a.q_WI.slerp(s, b.q_WI).normalized();
  return out;
}

bool GroundTruth::at(double t_s, TruthSample* out) const {
  if (!std::isfinite(t_s) || t_s < poses_.front().t_s || t_s > poses_.back().t_s) return false;
  const PoseSample pose = poseAt(t_s);
  const auto it = std::upper_bound(poses_.begin(), poses_.end(), t_s,
                                   [](double t, const PoseSample& p) { return t < p.t_s; });
  std::size_t i1 = static_cast<std::size_t>(it - poses_.begin());
  if (i1 >= poses_.size()) i1 = poses_.size() - 1;
  const std::size_t i0 = i1 - 1;
  const double s = std::clamp((t_s - poses_[i0].t_s) / (poses_[i1].t_s - poses_[i0].t_s), 0.0, 1.0);
  const Eigen::Vector3d v_W = (1.0 - s) * v_WC_mps_[i0] + s * v_WC_mps_[i1];

  const Eigen::Matrix3d R_WI = pose.q_WI.toRotationMatrix();
  const Eigen::Matrix3d R_WC = R_WI * R_IC_;
  const Eigen::Vector3d p_WC = pose.p_WI_m + R_WI * t_IC_m_;

  TruthSample truth;
  truth.t_s = t_s;
  truth.d_m = n_W_.dot(p_WC) + e_m_;
  truth.mu_C = -R_WC.transpose() * n_W_;
  truth.g_C = R_WC.transpose() * Eigen::Vector3d(0.0, 0.0, -1.0);
  truth.v_C_mps = R_WC.transpose() * v_W;
  truth.h_m = truth.d_m / truth.mu_C.dot(truth.g_C);
  *out = truth;
  return true;
}

}  // namespace eval
}  // namespace diekf
