// Camera-frame filter state -> body-frame (base_link) quantities and a pose of base_link in odom, for the ROS
// outputs. ROS-free (Eigen only) so it can be unit-tested without a master.
//
// base_link is the IMU frame unless T_base_imu says otherwise (the IMU's pose in base_link, e.g. from the robot
// description). odom (REP-105): z up, origin at the start point projected onto the plane, x/y/yaw start at zero.
//  - z      = height of base_link above the plane along gravity (from d, mu, g and the lever arm), plus an offset
//             that keeps z continuous across filter restarts and steps of the ground (docs/ros.md, "Odometry");
//  - roll/pitch from the estimated gravity direction,
//  - yaw    integrated from the bias-corrected gyro (unobservable: drifts),
//  - x/y    integrated from the estimated velocity (unobservable: drift).
// Between images the pose comes from the filter's predicted state (diekf::StatePredictor): predictedPose().
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

/// Covariance (m^2/s^2) of the camera velocity v = vartheta / alpha in C: the core's (diekf/state.h).
using diekf::velocityCovariance;

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
  /// angular-velocity covariance, gravity magnitude (m/s^2), T_base_imu (p_base = T_base_imu p_I; identity:
  /// base_link is the IMU frame).
  BodyOdometry(const Eigen::Isometry3d& T_cam_imu, double gyro_noise_density, double imu_rate_hz,
               double gravity_mps2, const Eigen::Isometry3d& T_base_imu = Eigen::Isometry3d::Identity());

  /// Raw IMU sample in the IMU frame (specific force m/s^2, rate rad/s). Integrates the orientation (yaw) with the
  /// bias-corrected gyro. Returns false for a non-increasing stamp.
  bool addImu(double t_s, const Vec3& accel_mps2, const Vec3& gyro_radps);

  /// Filter output at an image: re-levels roll/pitch from gravity, keeps the integrated yaw, integrates x/y with
  /// the trapezoidal rule and sets z from the height (plus the continuity offset). `height_usable`: the filter has
  /// converged (tracking or degraded); while it is not, after a restart, z holds its last value and is rebased on
  /// the new height when it is usable again. Returns the frame-rate pose of base_link.
  const BodyPose& addFrame(double t_s, const diekf::State& x, const ErrorCov& P, bool height_usable = true);

  /// The pose of base_link at t_s (at or after the last frame) from the filter's state predicted to t_s
  /// (diekf::StatePredictor): the same quantities and covariances as addFrame, x/y integrated from the last
  /// frame with the predicted velocity, the latest integrated yaw and gyro rate. Does not change the odometry.
  BodyPose predictedPose(double t_s, const diekf::State& x, const ErrorCov& P) const;

  const BodyPose& framePose() const { return frame_pose_; }
  bool hasFrame() const { return has_frame_; }

  /// Forget velocity and stamp continuity (after a filter reset or a time jump). Keeps x, y, yaw and z so odom
  /// stays continuous (z is rebased at the next usable height).
  void restart();

  /// Frames further apart than this (s) are not integrated across (gap or reset).
  double max_integration_gap_s = 1.0;
  /// A change of the height between two frames that differs from the vertical motion by more than this (m) is a
  /// step of the ground (an edge, a box): absorbed into z's offset instead of moving odom. 0 = off.
  double odom_z_step_m = 0.1;
  /// Offset added to the height to give odom z (m): changes at restarts and ground steps.
  double zOffset() const { return z_offset_m_; }
  /// Ground steps absorbed so far.
  int groundSteps() const { return ground_steps_; }

 private:
  /// What addFrame and predictedPose compute alike from a state, for the IMU frame: levelled orientation (yaw of
  /// q_yaw), body and odom velocity, their covariances, height of the IMU origin and its Jacobian.
  struct Kinematics {
    Eigen::Quaterniond q_odom_imu;
    Vec3 v_imu_I, v_imu_odom;
    Mat3 cov_v_I, cov_v_odom, P_bw_I;
    double h_m;
    Row14 J_h;
  };
  Kinematics kinematics(const diekf::State& x, const ErrorCov& P, const Eigen::Quaterniond& q_yaw,
                        const Vec3& w_I) const;
  /// Pose of base_link from the pose of the IMU frame (same stamp, covariances rotated where they are in the body).
  BodyPose toBase(const BodyPose& imu) const;

  Mat3 R_IC_;
  Vec3 t_CI_;
  Vec3 lever_I_m_;  ///< camera origin -> IMU origin, in I
  Mat3 R_BI_;       ///< base_link <- IMU rotation
  Vec3 base_I_m_;   ///< base_link origin in I, m
  double gyro_psd_;              ///< gyro white-noise PSD, rad^2/s
  double gyro_var_per_sample_;   ///< variance of one raw gyro sample, rad^2/s^2
  double gravity_mps2_;

  Eigen::Quaterniond q_odom_imu_ = Eigen::Quaterniond::Identity();  ///< integrated at IMU rate
  double t_imu_s_ = -1.0;
  Vec3 gyro_bias_I_ = Vec3::Zero();
  Vec3 gyro_sum_ = Vec3::Zero();
  int gyro_count_ = 0;
  Vec3 last_gyro_I_ = Vec3::Zero();

  bool has_frame_ = false;
  BodyPose frame_imu_;   ///< the IMU frame's pose at the last frame
  BodyPose frame_pose_;  ///< base_link's
  Vec3 frame_velocity_odom_ = Vec3::Zero();
  double var_x_m2_ = 0.0, var_y_m2_ = 0.0, var_yaw_rad2_ = 0.0;
  // z continuity (heights of the IMU origin).
  double z_offset_m_ = 0.0;
  bool height_usable_ = false;     ///< the last frame's height was usable
  bool z_hold_valid_ = false;      ///< z_hold_m_ holds the last usable z
  bool rebase_pending_ = false;    ///< rebase z on the next usable height
  double z_hold_m_ = 0.0, z_hold_var_m2_ = 0.0;
  bool has_prev_height_ = false;
  double prev_h_m_ = 0.0, prev_vz_mps_ = 0.0, prev_t_s_ = 0.0;
  int ground_steps_ = 0;
};

}  // namespace diekf_ros
