// Basic fixed-size types and error-state layout shared by the whole core (no ROS).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace diekf {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Vec4 = Eigen::Vector4d;
using Mat2 = Eigen::Matrix2d;
using Mat3 = Eigen::Matrix3d;
using Mat32 = Eigen::Matrix<double, 3, 2>;
using Mat23 = Eigen::Matrix<double, 2, 3>;

/// Dimension of the error state (tangent space of the filter state).
constexpr int kErrorDim = 17;
/// The motion states (everything but the sensors' calibration: time offset, readout, focal-length scale): the
/// block published as
/// PlanarState.covariance.
constexpr int kMotionDim = 14;
using ErrorVec = Eigen::Matrix<double, kErrorDim, 1>;
using ErrorCov = Eigen::Matrix<double, kErrorDim, kErrorDim>;

/// Offsets of the blocks in the 17-D error state
/// [d_alpha, d_vartheta(3), d_mu(2), d_g(2), d_b_a(3), d_b_w(3), d_t_d, d_readout, d_focal_scale].
struct ErrIdx {
  static constexpr int kAlpha = 0;
  static constexpr int kVartheta = 1;
  static constexpr int kMu = 4;
  static constexpr int kG = 6;
  static constexpr int kBa = 8;
  static constexpr int kBw = 11;
  static constexpr int kTd = 14;  ///< camera-IMU time offset (docs/algorithm.md section 3.6)
  static constexpr int kRo = 15;  ///< rolling-shutter readout time of a frame (docs/algorithm.md section 3.7)
  static constexpr int kFs = 16;  ///< relative error of the calibrated focal length (docs/algorithm.md section 3.8)
  static constexpr int kTimeStates = kFs - kTd + 1;  ///< the sensors' states from kTd on: offset, readout, focal scale
};

/// Skew-symmetric matrix [v]x with [v]x u = v x u.
inline Mat3 skew(const Vec3& v) {
  Mat3 m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

/// Rotation matrix exp([phi]x) (Rodrigues), exact for all angles, stable near zero.
Mat3 expSO3(const Vec3& phi);

/// Left Jacobian of SO(3) (the "Gamma" of docs/algorithm.md §1): d exp(phi + dphi) = exp([Gamma dphi]x) exp(phi).
Mat3 leftJacobianSO3(const Vec3& phi);

/// One IMU reading: specific force (m/s^2) and angular rate (rad/s), stamp in seconds.
struct ImuSample {
  double t_s = 0.0;
  Vec3 accel_mps2 = Vec3::Zero();
  Vec3 gyro_radps = Vec3::Zero();
};

}  // namespace diekf
