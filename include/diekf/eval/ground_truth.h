// True values of the filter's quantities from a motion-capture pose stream and a ground plane
// (docs/conventions.md section 2). ROS-free: the bag runner fills the inputs from /mocap/pose and
// /ground_truth/plane, the tests from analytic motions.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace diekf {
namespace eval {

/// One pose of the IMU frame in the world, T_W_I.
struct PoseSample {
  double t_s = 0.0;                                          ///< stamp, s (IMU clock)
  Eigen::Vector3d p_WI_m = Eigen::Vector3d::Zero();          ///< IMU origin in W, m
  Eigen::Quaterniond q_WI = Eigen::Quaterniond::Identity();  ///< rotation I -> W
};

/// The plane {X in W : n.X + e = 0}, n pointing to the camera's side. Level ground by default.
struct GroundPlane {
  Eigen::Vector3d n_W = Eigen::Vector3d::UnitZ();  ///< normal (normalised on use)
  double e_m = 0.0;                                ///< offset, m (scaled with n on normalisation)

  /// From shape_msgs/Plane coefficients [a, b, c, e]; throws std::invalid_argument on a zero or non-finite normal.
  static GroundPlane fromCoefficients(double a, double b, double c, double e);
  /// A plane through the world origin whose normal is tilted from +z by `incline_deg` about the world x axis.
  static GroundPlane inclined(double incline_deg);
};

/// True state at one instant, all vectors in the camera frame C.
struct TruthSample {
  double t_s = 0.0;                                  ///< s
  double d_m = 0.0;                                  ///< orthogonal camera-plane distance, m
  double h_m = 0.0;                                  ///< height along gravity d / (mu.g), m
  Eigen::Vector3d v_C_mps = Eigen::Vector3d::Zero(); ///< camera velocity in C, m/s
  Eigen::Vector3d mu_C = Eigen::Vector3d::UnitZ();   ///< unit plane normal, camera -> plane
  Eigen::Vector3d g_C = Eigen::Vector3d::UnitZ();    ///< unit gravity direction (down)
};

struct GroundTruthOptions {
  /// Base of the central difference for dp_WC/dt, s. 0 uses the adjacent samples (i-1, i+1); a larger value
  /// differences samples about +-window/2 apart, which smooths mocap jitter.
  double velocity_window_s = 0.0;
};

/// Interpolates the pose stream (linear position, slerp rotation) and evaluates the true d, h, v, mu, g at any
/// stamp inside it.
class GroundTruth {
 public:
  /// `poses` in any order (sorted here; duplicated stamps dropped); needs at least two distinct stamps, throws
  /// std::invalid_argument otherwise or on non-finite values.
  GroundTruth(std::vector<PoseSample> poses, const GroundPlane& plane, const Eigen::Isometry3d& T_cam_imu,
              const GroundTruthOptions& options = GroundTruthOptions());

  /// True values at `t_s`; false when `t_s` lies outside the pose stream.
  bool at(double t_s, TruthSample* out) const;

  double startTime() const { return poses_.front().t_s; }
  double endTime() const { return poses_.back().t_s; }
  std::size_t size() const { return poses_.size(); }

  /// Pose T_W_I interpolated at `t_s` (clamped to the stream's ends).
  PoseSample poseAt(double t_s) const;

 private:
  std::vector<PoseSample> poses_;
  std::vector<Eigen::Vector3d> v_WC_mps_;  ///< camera-centre velocity in W at each pose stamp
  Eigen::Vector3d n_W_;
  double e_m_ = 0.0;
  Eigen::Matrix3d R_IC_;
  Eigen::Vector3d t_IC_m_;
};

}  // namespace eval
}  // namespace diekf
