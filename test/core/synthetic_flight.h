// Test helper (header-only, no ROS, no file I/O): an analytic flight over a textured level plane, the matching
// 500 Hz IMU, a camera model and a renderer, shared by the end-to-end and the robustness tests.
//
//   const SyntheticFlight flight;                    // analytic trajectory (W: z up)
//   const CameraModel cam = syntheticCamera();       // 188x120 downward camera (scale 0.5: 94x60)
//   estimator.addImu(flight.imuSample(t));           // specific force and rate in the IMU frame
//   renderFlightImage(flight, cam, t, &image);       // CV_8UC1 view of the plane at time t
//   const FlightTruth truth = flightTruth(flight, cam, t);  // d (m) and v in C (m/s)
#pragma once

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/types.h"

namespace diekf {
namespace test_util {

constexpr double kFlightGravityMps2 = 9.81;

/// Analytic IMU trajectory in W (z up): position, velocity, acceleration, attitude about a fixed axis.
/// `rate` scales every frequency (speeds scale with it, accelerations with its square).
struct SyntheticFlight {
  Vec3 axis = Vec3(1.0, 0.6, 0.2).normalized();
  double height_m = 0.9;
  double rate = 1.0;
  Vec3 drift_mps = Vec3::Zero();  // a constant velocity on top of the oscillations (a dash), m/s
  double angle_rad = 0.08;        // amplitude of the attitude's oscillation about `axis`
  double angle_freq = 1.3;        // its angular frequency per unit of `rate`, rad/s

  Vec3 position(double t) const {
    const double s = rate * t;
    return Vec3(0.4 * std::sin(0.9 * s), 0.3 * std::sin(0.7 * s + 0.5), height_m + 0.25 * std::sin(0.5 * s)) +
           t * drift_mps;
  }
  Vec3 velocity(double t) const {
    const double s = rate * t;
    return rate * Vec3(0.36 * std::cos(0.9 * s), 0.21 * std::cos(0.7 * s + 0.5), 0.125 * std::cos(0.5 * s)) +
           drift_mps;
  }
  Vec3 acceleration(double t) const {
    const double s = rate * t;
    return rate * rate *
           Vec3(-0.324 * std::sin(0.9 * s), -0.147 * std::sin(0.7 * s + 0.5), -0.0625 * std::sin(0.5 * s));
  }
  double angle(double t) const { return angle_rad * std::sin(angle_freq * rate * t); }
  double angleRate(double t) const { return angle_rad * angle_freq * rate * std::cos(angle_freq * rate * t); }
  Mat3 R_WI(double t) const { return Eigen::AngleAxisd(angle(t), axis).toRotationMatrix(); }
  /// Body rate about a fixed axis: omega_I = theta'(t) axis.
  Vec3 gyro_I(double t) const { return angleRate(t) * axis; }
  /// Specific force f_I = R_WI^T (a_W - g_W), g_W = (0, 0, -g).
  Vec3 accel_I(double t) const {
    return R_WI(t).transpose() * (acceleration(t) + Vec3(0, 0, kFlightGravityMps2));
  }
  /// Noise-free raw IMU sample at t (IMU frame).
  ImuSample imuSample(double t) const { return {t, accel_I(t), gyro_I(t)}; }
};

/// Smooth texture on the plane z = 0 (sum of sinusoids, wavelengths 6-40 cm), grey levels 0-255.
inline double flightTexture(double X, double Y) {
  static const double k[6][3] = {{2 * M_PI / 0.40, 0.3, 0.0},  {2 * M_PI / 0.23, 1.9, 1.3},
                                  {2 * M_PI / 0.15, 0.8, 2.1}, {2 * M_PI / 0.11, 2.6, 0.4},
                                  {2 * M_PI / 0.08, 4.0, 5.0}, {2 * M_PI / 0.06, 5.3, 3.3}};
  double v = 128.0;
  for (const auto& c : k) v += 20.0 * std::sin(c[0] * (std::cos(c[1]) * X + std::sin(c[1]) * Y) + c[2]);
  return std::min(255.0, std::max(0.0, v));
}

/// Renders the level plane seen by a pinhole camera with pose (R_WC, p_WC), 2x2 supersampled.
/// Row v of the camera's view (through its lens distortion, if any).
inline void renderLevelPlaneRow(const CameraModel& cam, const Mat3& R_WC, const Vec3& p_WC, int v, uint8_t* row) {
  for (int u = 0; u < cam.K.width; ++u) {
    double sum = 0.0;
    for (int s = 0; s < 4; ++s) {
      const double uu = u - 0.25 + 0.5 * (s & 1), vv = v - 0.25 + 0.5 * (s >> 1);
      Vec2 xn((uu - cam.K.cx) / cam.K.fx, (vv - cam.K.cy) / cam.K.fy);
      if (cam.distortion != DistortionModel::kNone) cam.undistort(Vec2(xn), &xn);
      const Vec3 ray = R_WC * Vec3(xn.x(), xn.y(), 1.0);
      const double lambda = -p_WC.z() / ray.z();
      const Vec3 X = p_WC + lambda * ray;
      sum += flightTexture(X.x(), X.y());
    }
    row[u] = static_cast<uint8_t>(std::lround(sum / 4.0));
  }
}

inline void renderLevelPlane(const CameraModel& cam, const Mat3& R_WC, const Vec3& p_WC, cv::Mat* out) {
  out->create(cam.K.height, cam.K.width, CV_8UC1);
  for (int v = 0; v < cam.K.height; ++v) renderLevelPlaneRow(cam, R_WC, p_WC, v, out->ptr<uint8_t>(v));
}

/// A downward camera (quarter of the MYNT EYE resolution at scale 1, no distortion) rotated 90 deg about its
/// axis relative to the IMU (IMU x forward, y left, z up), a few cm away. `scale` multiplies the resolution.
inline CameraModel syntheticCamera(double scale = 1.0) {
  CameraModel cam;
  cam.K.width = static_cast<int>(std::lround(188 * scale));
  cam.K.height = static_cast<int>(std::lround(120 * scale));
  cam.K.fx = 91.2 * scale;
  cam.K.fy = 91.2 * scale;
  cam.K.cx = (94.5 + 0.5) * scale - 0.5;
  cam.K.cy = (61.0 + 0.5) * scale - 0.5;
  cam.distortion = DistortionModel::kNone;
  Mat3 R_CI;
  R_CI << 0, -1, 0,  //
      -1, 0, 0,      //
      0, 0, -1;
  const Vec3 r_I(0.03, 0.0, -0.02);  // camera centre in the IMU frame, m
  cam.T_cam_imu.linear() = R_CI;
  cam.T_cam_imu.translation() = -R_CI * r_I;
  return cam;
}

/// The camera's view of the plane at time t of the flight.
inline void renderFlightImage(const SyntheticFlight& f, const CameraModel& cam, double t, cv::Mat* out) {
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();
  const Mat3 R_WI = f.R_WI(t);
  renderLevelPlane(cam, R_WI * R_IC, f.position(t) + R_WI * r_I, out);
}

/// The view of a rolling-shutter camera: row v is captured at t + line_delay_s (v - (rows - 1) / 2), i.e. the
/// stamp t is the middle row's time; each row is rendered with the pose of its own time.
inline void renderFlightImageRollingShutter(const SyntheticFlight& f, const CameraModel& cam, double t,
                                            double line_delay_s, cv::Mat* out) {
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();
  out->create(cam.K.height, cam.K.width, CV_8UC1);
  for (int v = 0; v < cam.K.height; ++v) {
    const double tv = t + line_delay_s * (v - 0.5 * (cam.K.height - 1));
    const Mat3 R_WI = f.R_WI(tv);
    renderLevelPlaneRow(cam, R_WI * R_IC, f.position(tv) + R_WI * r_I, v, out->ptr<uint8_t>(v));
  }
}

struct FlightTruth {
  double d_m;  ///< camera-to-plane distance, m
  Vec3 v_C;    ///< camera velocity in C, m/s
};

inline FlightTruth flightTruth(const SyntheticFlight& f, const CameraModel& cam, double t) {
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();
  const Mat3 R_WI = f.R_WI(t);
  const Mat3 R_WC = R_WI * R_IC;
  const Vec3 p_WC = f.position(t) + R_WI * r_I;
  const Vec3 v_WC = f.velocity(t) + (R_WI * f.gyro_I(t)).cross(R_WI * r_I);
  return {p_WC.z(), R_WC.transpose() * v_WC};
}

}  // namespace test_util
}  // namespace diekf
