// Test and benchmark helper (header-only): a periodic flight over a textured level plane for driving the
// Estimator facade frame by frame. The camera (752x480 pinhole, the MYNT EYE's raw size, no distortion, IMU frame
// = camera frame) looks down from about 1 m and moves on a closed curve with period `frames` / 30 Hz, so the
// pre-rendered images repeat exactly: frame k of any period is image k % frames, with analytic 500 Hz IMU
// samples consistent with the motion. Rendering happens once, in the constructor.
#pragma once

#include <cmath>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/types.h"
#include "render_plane.h"

namespace diekf {
namespace test_util {

class PeriodicFlight {
 public:
  static constexpr double kCameraRateHz = 30.0;
  static constexpr double kImuRateHz = 500.0;
  static constexpr double kGravity = 9.81;  // m/s^2, as ImuParams' default

  explicit PeriodicFlight(int frames = 30) : frames_(frames), omega_(2.0 * M_PI * kCameraRateHz / frames) {
    camera_.K = PinholeK{365.0, 365.0, 375.5, 239.5, 752, 480};
    const PlaneTexture texture(11, 12, 0.08, 0.6);
    const Plane ground;
    for (int k = 0; k < frames_; ++k) {
      const double t = k / kCameraRateHz;
      CameraPose pose;
      pose.R_WC = R_WC(t);
      pose.p_WC = position(t);
      images_.push_back(toGray8(renderPlane(texture, ground, camera_.K, pose, 1)));
    }
  }

  const CameraModel& camera() const { return camera_; }
  /// Image of camera frame k (stamp k / 30 Hz).
  const cv::Mat& image(long k) const { return images_[static_cast<size_t>(k % frames_)]; }
  /// Raw IMU sample at t_s (IMU frame = camera frame): specific force and body rate.
  ImuSample imu(double t_s) const {
    const Mat3 R = R_WC(t_s);
    ImuSample s;
    s.t_s = t_s;
    s.accel_mps2 = R.transpose() * (acceleration(t_s) + Vec3(0.0, 0.0, kGravity));
    s.gyro_radps = R.transpose() * Vec3(0.0, 0.0, yawRate(t_s));
    return s;
  }

  /// Closed curve around (0, 0, 1 m): a few cm/s to ~0.3 m/s.
  Vec3 position(double t) const {
    return Vec3(0.05 * std::sin(omega_ * t), 0.04 * std::sin(omega_ * t + 0.5), 1.0 + 0.02 * std::sin(omega_ * t));
  }
  Vec3 acceleration(double t) const {
    const double w2 = omega_ * omega_;
    return -w2 * Vec3(0.05 * std::sin(omega_ * t), 0.04 * std::sin(omega_ * t + 0.5), 0.02 * std::sin(omega_ * t));
  }
  double yaw(double t) const { return 0.05 * std::sin(omega_ * t); }
  double yawRate(double t) const { return 0.05 * omega_ * std::cos(omega_ * t); }
  /// Camera-to-world rotation: looking down, yawed about the vertical.
  Mat3 R_WC(double t) const { return lookDownPose(Vec3::Zero(), yaw(t)).R_WC; }

 private:
  int frames_;
  double omega_;  // rad/s
  CameraModel camera_;
  std::vector<cv::Mat> images_;
};

}  // namespace test_util
}  // namespace diekf
