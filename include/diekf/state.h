// Filter state x = (alpha, vartheta, mu, g, b_a, b_w, t_d, readout, focal_scale), in the camera frame C, and its manifold operations.
#pragma once

#include "diekf/types.h"
#include "diekf/unit_vector.h"

namespace diekf {

struct State {
  double alpha = 10.0;               ///< inverse distance 1/d to the plane, 1/m
  Vec3 vartheta = Vec3::Zero();      ///< velocity over distance v/d, 1/s
  UnitVector mu;                     ///< plane normal, camera -> plane
  UnitVector g;                      ///< gravity direction (down)
  Vec3 b_a = Vec3::Zero();           ///< accelerometer bias in C, m/s^2
  Vec3 b_w = Vec3::Zero();           ///< gyroscope bias in C, rad/s
  /// Camera-IMU time offset on top of the calibration's timeshift_cam_imu, s: an image stamped t_cam was taken
  /// at IMU time t_cam + timeshift_cam_imu + t_d_s (docs/algorithm.md section 3.6).
  double t_d_s = 0.0;
  /// Rolling-shutter readout time of a frame, first to last raw row, s (0: global shutter; docs/algorithm.md
  /// section 3.7).
  double readout_s = 0.0;
  /// Relative correction of the calibrated focal length, unitless: the camera's focal lengths are
  /// (1 + focal_scale) times the calibration's (docs/algorithm.md section 3.8).
  double focal_scale = 0.0;

  /// x [+] delta (vector parts add, S^2 parts use UnitVector::boxplus).
  State boxplus(const ErrorVec& delta) const;
  /// this [-] other.
  ErrorVec boxminus(const State& other) const;
  /// L = d((this [+] d) [-] ref)/d d at d = 0: identity except the two 2x2 S^2 blocks.
  ErrorCov boxminusJacobian(const State& ref) const;

  double distance_m() const { return 1.0 / alpha; }
  Vec3 velocity_mps() const { return vartheta / alpha; }
  /// Height along gravity h = d / (mu . g), m.
  double height_m() const { return distance_m() / mu.vector().dot(g.vector()); }
  bool allFinite() const;
};

// Uncertainty of the derived quantities, first order in the error state (the one definition for the estimator's
// checks, its results and the ROS messages; docs/algorithm.md section 8).
/// 1-sigma of the distance d = 1/alpha: sigma_alpha / alpha^2, m.
double sigmaDistance_m(const State& x, const ErrorCov& P);
/// Relative 1-sigma of the distance, sigma_d / d = sigma_alpha / alpha (dimensionless).
double relativeSigmaDistance(const State& x, const ErrorCov& P);
/// Covariance of the velocity v = vartheta / alpha (C frame): J P J^T with J = [-vartheta/alpha^2, I/alpha] over
/// (alpha, vartheta), (m/s)^2.
Mat3 velocityCovariance(const State& x, const ErrorCov& P);
/// 1-sigma of each velocity axis (C frame), m/s.
Vec3 sigmaVelocity_mps(const State& x, const ErrorCov& P);
/// Adds a relative uncertainty of the scale, variance `relative_var`, to P: alpha and vartheta off by the same
/// relative amount (the distance to which layer of a scene that is not one plane; docs/noise_model.md section 13).
/// The distance's relative variance grows by relative_var, the velocity v = vartheta / alpha is unchanged.
void addScaleAmbiguity(const State& x, double relative_var, ErrorCov* P);
/// The image's motion defined only to a relative variance (a scene whose parts move differently: movers, or
/// relief the outlier weights kept): P += relative_var g g^T with g = vartheta in the vartheta rows, 0 elsewhere.
/// The velocity's relative variance grows by relative_var along v (v v^T relative_var), the distance is unchanged
/// (docs/noise_model.md section 13).
void addMotionAmbiguity(const State& x, double relative_var, ErrorCov* P);
/// Adds an uncertain small rotation dtheta of the camera frame, variance `var_rad2` per axis, to P: vartheta, mu
/// and g turned together by dtheta (vartheta off by dtheta x vartheta, mu and g by dtheta's component in their
/// tangent planes; alpha unchanged). The velocity's covariance grows by var_rad2 [v]x [v]x^T, the distance's not
/// (the calibration's camera-IMU rotation and principal point; docs/noise_model.md section 9).
void addFrameRotationUncertainty(const State& x, double var_rad2, ErrorCov* P);

}  // namespace diekf
