// Pinhole camera with radtan or equidistant distortion and IMU extrinsics, read from a Kalibr camchain.
#pragma once

#include <string>

#include "diekf/types.h"

namespace diekf {

enum class DistortionModel { kNone, kRadTan, kEquidistant };

struct PinholeK {
  double fx = 0, fy = 0, cx = 0, cy = 0;  ///< pixels
  int width = 0, height = 0;              ///< pixels
};

/// K with both focal lengths scaled by (1 + focal_scale), the principal point kept (the focal-length state,
/// docs/algorithm.md section 3.8).
inline PinholeK scaledFocal(const PinholeK& K, double focal_scale) {
  PinholeK out = K;
  out.fx = K.fx * (1.0 + focal_scale);
  out.fy = K.fy * (1.0 + focal_scale);
  return out;
}

class CameraModel {
 public:
  /// Reads `cam` (e.g. "cam0") from a Kalibr camchain YAML. Throws std::runtime_error naming file and key.
  static CameraModel fromKalibrYaml(const std::string& path, const std::string& cam = "cam0");

  PinholeK K;                                           ///< intrinsics at calibration resolution
  DistortionModel distortion = DistortionModel::kNone;
  Vec4 distortion_coeffs = Vec4::Zero();                ///< radtan: k1 k2 r1 r2; equidistant: k1..k4
  /// radtan only: OpenCV's further radial coefficients k3, k4, k5, k6 (ROS plumb_bob has k3,
  /// rational_polynomial all four): radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3).
  /// Zero for Kalibr's radtan.
  Vec4 radial_extra = Vec4::Zero();
  Eigen::Isometry3d T_cam_imu = Eigen::Isometry3d::Identity();  ///< p_C = T_cam_imu p_I
  double timeshift_cam_imu_s = 0.0;                     ///< t_imu = t_cam + timeshift
  double line_delay_s = 0.0;  ///< rolling shutter: readout time per image row, s (camchain key line_delay_s; 0 = global)
  std::string rostopic;                                 ///< image topic named in the calibration

  /// Normalised undistorted coordinates (x/z, y/z) -> distorted normalised coordinates.
  Vec2 distort(const Vec2& xn) const;
  /// Inverse of distort (iterative); returns false if it did not converge.
  bool undistort(const Vec2& xd, Vec2* xn) const;
  /// Camera-frame point -> distorted pixel at calibration resolution; false if behind the camera.
  bool project(const Vec3& p_C, Vec2* px) const;
  /// Distorted pixel -> undistorted normalised coordinates.
  bool unproject(const Vec2& px, Vec2* xn) const;

  Mat3 R_CI() const { return T_cam_imu.linear(); }
  Vec3 t_CI() const { return T_cam_imu.translation(); }
};

}  // namespace diekf
