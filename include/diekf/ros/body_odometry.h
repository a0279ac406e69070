// Camera-frame filter state -> body-frame (base_link = IMU frame) quantities and a dead-reckoned pose of
// base_link in odom, for the ROS outputs. ROS-free (Eigen only) so it can be unit-tested without a master.
//
// odom (REP-105): z up, origin at the start point projected onto the plane, x/y/yaw start at zero.
//  - z      = height of base_link above the plane along gravity (from d, mu, g and the lever arm),
//  - roll/pitch from the estimated gravity direction,
//  - yaw    integrated from the bias-corrected gyro (unobservable: drifts),
//  - x/y    dead-reckoned from the estimated velocity (unobservable: drifts).
// Between images the pose can also be propagated at IMU rate with the bias-corrected accelerometer.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "diekf/state.h"
#include "diekf/types.h"

namespace diekf_ros {

using diekf::ErrorCov;
using diekf::Mat3;
using diekf::Vec3;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Row14 = Eigen::Matrix<double, 1, diekf::kErrorDim>;

/// Height along gravity of a point given in C (metres, camera coordinates), h(P) = (d - mu.P) / (mu.g), and its
/// Jacobian w.r.t. the 14-D error state. The camera's own height is point = 0.
double heightAbovePlane(const diekf::State& x, const Vec3& point_C_m, Row14* jacobian = nullptr);

/// Covariance (m^2/s^2) of the camera velocity v = vartheta / alpha in C, first order from the filter covariance.
Mat3 velocityCovariance(const diekf::State& x, const ErrorCov& P);

/// Pose, twist and covariances of base_link in odom. Covariance order (ROS): x, y, z, roll, pitch, yaw.
struct BodyPose {
  double t_s = 0.0;                                              ///< stamp, s (IMU clock)
  Vec3 position_m = Vec3::Zero();                                ///< base_link origin in odom, m
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  ///< R_odom_base
  Vec3 linear_velocity_mps = Vec3::Zero();                       ///< base_link velocity in base_link, m/s
  Vec3 angular_velocity_radps = Vec3::Zero();                    ///< bias-corrected rate in base_link, rad/s
  Mat6 pose_covariance = Mat6::Identity();                       ///< m^2 and rad^2
  Mat6 twist_covariance = Mat6::Identity();                      ///< (m/s)^2 and (rad/s)^2
  bool allFinite() const;
};

class BodyOdometry {
 public:
  /// T_cam_imu (p_C = T_cam_imu p_I), gyro white-noise density (rad/s/sqrt(Hz)) and raw IMU rate (Hz) for the
  /// angular-velocity covariance, gravity magnitude (m/s^2) for the IMU-rate propagation.
  BodyOdometry(const Eigen::Isometry3d& T_cam_imu, double gyro_noise_density, double imu_rate_hz,
               double gravity_mps2);

  /// Raw IMU sample in base_link (specific force m/s^2, rate rad/s). Integrates the orientation and, once a
  /// frame has been seen, propagates position/velocity at IMU rate. Returns false for a non-increasing stamp.
  bool addImu(double t_s, const Vec3& accel_mps2, const Vec3& gyro_radps);

  /// Filter output at an image: re-levels roll/pitch from gravity, keeps the integrated yaw, dead-reckons x/y
  /// with the trapezoidal rule and sets z from the height. Returns the frame-rate pose.
  const BodyPose& addFrame(double t_s, const diekf::State& x, const ErrorCov& P);

  /// Pose propagated to the last IMU sample (valid after the first frame).
  const BodyPose& imuRatePose() const { return imu_pose_; }
  const BodyPose& framePose() const { return frame_pose_; }
  bool hasFrame() const { return has_frame_; }

  /// Forget velocity and stamp continuity (after a filter reset or a time jump). Keeps x, y and yaw so odom stays
  /// continuous.
  void restart();

  /// Frames further apart than this (s) are not integrated across (gap or reset).
  double max_integration_gap_s = 1.0;

 private:
  Mat3 R_IC_;
  Vec3 t_CI_;
  Vec3 lever_I_m_;  ///< camera origin -> IMU origin, in I
  double gyro_psd_;              ///< gyro white-noise PSD, rad^2/s
  double gyro_var_per_sample_;   ///< variance of one raw gyro sample, rad^2/s^2
  double gravity_mps2_;

  Eigen::Quaterniond q_odom_base_ = Eigen::Quaterniond::Identity();
  double t_imu_s_ = -1.0;
  Vec3 gyro_bias_I_ = Vec3::Zero();
  Vec3 accel_bias_I_ = Vec3::Zero();
  Vec3 gyro_sum_ = Vec3::Zero();
  int gyro_count_ = 0;
  Vec3 last_gyro_I_ = Vec3::Zero();

  bool has_frame_ = false;
  BodyPose frame_pose_;
  BodyPose imu_pose_;
  Vec3 frame_velocity_odom_ = Vec3::Zero();
  Vec3 imu_velocity_odom_ = Vec3::Zero();
  double var_x_m2_ = 0.0, var_y_m2_ = 0.0, var_yaw_rad2_ = 0.0;
};

}  // namespace diekf_ros
