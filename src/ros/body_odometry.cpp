#include "diekf/ros/body_odometry.h"

#include <algorithm>
#include <cmath>

namespace diekf_ros {

using diekf::ErrIdx;

double heightAbovePlane(const diekf::State& x, const Vec3& point_C_m, Row14* jacobian) {
  const Vec3 mu = x.mu.vector();
  const Vec3 g = x.g.vector();
  const double d = 1.0 / x.alpha;
  const double c = mu.dot(g);
  const double num = d - mu.dot(point_C_m);
  if (jacobian) {
    jacobian->setZero();
    (*jacobian)(ErrIdx::kAlpha) = -1.0 / (x.alpha * x.alpha * c);
    const diekf::Mat32 M_mu = x.mu.M();
    const diekf::Mat32 M_g = x.g.M();
    jacobian->segment<2>(ErrIdx::kMu) =
        (-(point_C_m.transpose() * M_mu) * c - num * (g.transpose() * M_mu)) / (c * c);
    jacobian->segment<2>(ErrIdx::kG) = -num * (mu.transpose() * M_g) / (c * c);
  }
  return num / c;
}

bool BodyPose::allFinite() const {
  return std::isfinite(t_s) && position_m.allFinite() && orientation.coeffs().allFinite() &&
         linear_velocity_mps.allFinite() && angular_velocity_radps.allFinite() && pose_covariance.allFinite() &&
         twist_covariance.allFinite();
}

BodyOdometry::BodyOdometry(const Eigen::Isometry3d& T_cam_imu, double gyro_noise_density, double imu_rate_hz,
                           double gravity_mps2, const Eigen::Isometry3d& T_base_imu)
    : R_IC_(T_cam_imu.linear().transpose()),
      t_CI_(T_cam_imu.translation()),
      lever_I_m_(R_IC_ * t_CI_),
      R_BI_(T_base_imu.linear()),
      base_I_m_(-T_base_imu.linear().transpose() * T_base_imu.translation()),
      gyro_psd_(gyro_noise_density * gyro_noise_density),
      gyro_var_per_sample_(gyro_psd_ * imu_rate_hz),
      gravity_mps2_(gravity_mps2) {}

bool BodyOdometry::addImu(double t_s, const Vec3& /*accel_mps2*/, const Vec3& gyro_radps) {
  if (t_imu_s_ >= 0.0 && t_s <= t_imu_s_) return false;
  const double dt = t_imu_s_ < 0.0 ? 0.0 : t_s - t_imu_s_;
  t_imu_s_ = t_s;
  const Vec3 w = gyro_radps - gyro_bias_I_;
  last_gyro_I_ = w;
  gyro_sum_ += w;
  ++gyro_count_;
  // Larger gaps are not integrated (sensor dropout): orientation simply holds.
  if (dt <= 0.0 || dt > 0.1) return true;
  q_odom_imu_ = (q_odom_imu_ * Eigen::Quaterniond(Eigen::AngleAxisd(diekf::expSO3(w * dt)))).normalized();
  return true;
}

BodyOdometry::Kinematics BodyOdometry::kinematics(const diekf::State& x, const ErrorCov& P,
                                                  const Eigen::Quaterniond& q_yaw, const Vec3& w_I) const {
  Kinematics k;
  // Orientation: the yaw (ZYX) of q_yaw, roll and pitch from the up direction seen in the IMU frame.
  const Vec3 up_I = -(R_IC_ * x.g.vector());
  const double pitch = std::atan2(-up_I.x(), std::hypot(up_I.y(), up_I.z()));
  const double roll = std::atan2(up_I.y(), up_I.z());
  const Eigen::Quaterniond& q = q_yaw;
  const double yaw = std::atan2(2.0 * (q.w() * q.z() + q.x() * q.y()), 1.0 - 2.0 * (q.y() * q.y() + q.z() * q.z()));
  k.q_odom_imu = Eigen::AngleAxisd(yaw, Vec3::UnitZ()) * Eigen::AngleAxisd(pitch, Vec3::UnitY()) *
                 Eigen::AngleAxisd(roll, Vec3::UnitX());
  const Mat3 R_OI = k.q_odom_imu.toRotationMatrix();
  // IMU velocity: camera velocity plus the rigid-body lever-arm term.
  k.v_imu_I = R_IC_ * x.velocity_mps() + w_I.cross(lever_I_m_);
  k.v_imu_odom = R_OI * k.v_imu_I;
  k.cov_v_I = R_IC_ * velocityCovariance(x, P) * R_IC_.transpose();
  k.cov_v_odom = R_OI * k.cov_v_I * R_OI.transpose();
  k.P_bw_I = R_IC_ * P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw) * R_IC_.transpose();
  k.h_m = heightAbovePlane(x, t_CI_, &k.J_h);
  return k;
}

BodyPose BodyOdometry::toBase(const BodyPose& imu) const {
  BodyPose b = imu;
  const Mat3 R_OI = imu.orientation.toRotationMatrix();
  b.orientation = Eigen::Quaterniond(R_OI * R_BI_.transpose()).normalized();
  b.position_m = imu.position_m + R_OI * base_I_m_;
  // Velocity of base_link's origin, in base_link: v_I + w x r, rotated.
  b.linear_velocity_mps = R_BI_ * (imu.linear_velocity_mps + imu.angular_velocity_radps.cross(base_I_m_));
  b.angular_velocity_radps = R_BI_ * imu.angular_velocity_radps;
  b.twist_covariance.topLeftCorner<3, 3>() = R_BI_ * imu.twist_covariance.topLeftCorner<3, 3>() * R_BI_.transpose();
  b.twist_covariance.bottomRightCorner<3, 3>() =
      R_BI_ * imu.twist_covariance.bottomRightCorner<3, 3>() * R_BI_.transpose();
  return b;  // the pose covariance is about odom's axes: the same for both frames (to first order)
}

const BodyPose& BodyOdometry::addFrame(double t_s, const diekf::State& x, const ErrorCov& P, bool height_usable) {
  gyro_bias_I_ = R_IC_ * x.b_w;
  const Vec3 w_mean = gyro_count_ > 0 ? Vec3(gyro_sum_ / gyro_count_) : last_gyro_I_;
  const double gyro_var = gyro_var_per_sample_ / std::max(gyro_count_, 1);
  gyro_sum_.setZero();
  gyro_count_ = 0;

  const Kinematics k = kinematics(x, P, q_odom_imu_, w_mean);
  q_odom_imu_ = k.q_odom_imu;

  const double dt = t_s - frame_imu_.t_s;
  const bool continuous = has_frame_ && dt > 0.0 && dt <= max_integration_gap_s;
  if (continuous) {
    frame_imu_.position_m.head<2>() += 0.5 * (frame_velocity_odom_ + k.v_imu_odom).head<2>() * dt;
    var_x_m2_ += k.cov_v_odom(0, 0) * dt * dt;
    var_y_m2_ += k.cov_v_odom(1, 1) * dt * dt;
    // Gyro white noise integrates to PSD * dt; an unknown bias error to sigma_b^2 * dt^2.
    var_yaw_rad2_ += gyro_psd_ * dt + k.P_bw_I(2, 2) * dt * dt;
  }

  // z: the height plus an offset that keeps it continuous across restarts and steps of the ground.
  const double var_h = (k.J_h * P * k.J_h.transpose())(0, 0);
  double z = k.h_m + z_offset_m_, var_z = var_h;
  if (!height_usable) {
    if (z_hold_valid_) {  // a restarted filter re-converging: hold z, rebase when the height is usable again
      z = z_hold_m_;
      if (continuous) z_hold_var_m2_ += 0.01 * dt;  // (0.1 m)^2 per second of unknown vertical motion
      var_z = z_hold_var_m2_;
      rebase_pending_ = true;
    }
    has_prev_height_ = false;
  } else {
    if (rebase_pending_) {
      z_offset_m_ = z_hold_m_ - k.h_m;
      rebase_pending_ = false;
    } else if (has_prev_height_ && continuous && odom_z_step_m > 0.0) {
      // The height changed by more than the vertical motion explains: the ground stepped under the robot.
      const double jump = (k.h_m - prev_h_m_) - 0.5 * (prev_vz_mps_ + k.v_imu_odom.z()) * (t_s - prev_t_s_);
      if (std::abs(jump) > odom_z_step_m) {
        z_offset_m_ -= jump;
        ++ground_steps_;
      }
    }
    z = k.h_m + z_offset_m_;
    z_hold_m_ = z;
    z_hold_var_m2_ = var_h;
    z_hold_valid_ = true;
    has_prev_height_ = true;
    prev_h_m_ = k.h_m;
    prev_vz_mps_ = k.v_imu_odom.z();
    prev_t_s_ = t_s;
  }
  height_usable_ = height_usable;
  frame_imu_.position_m.z() = z;
  frame_velocity_odom_ = k.v_imu_odom;

  frame_imu_.t_s = t_s;
  frame_imu_.orientation = q_odom_imu_;
  frame_imu_.linear_velocity_mps = k.v_imu_I;
  frame_imu_.angular_velocity_radps = w_mean;
  Mat6& Cp = frame_imu_.pose_covariance;
  Cp.setZero();
  Cp(0, 0) = var_x_m2_;
  Cp(1, 1) = var_y_m2_;
  Cp(2, 2) = var_z;
  const double var_tilt = 0.5 * P.block<2, 2>(ErrIdx::kG, ErrIdx::kG).trace();
  Cp(3, 3) = var_tilt;
  Cp(4, 4) = var_tilt;
  Cp(5, 5) = var_yaw_rad2_;
  Mat6& Ct = frame_imu_.twist_covariance;
  Ct.setZero();
  Ct.topLeftCorner<3, 3>() = k.cov_v_I;
  Ct.bottomRightCorner<3, 3>() = k.P_bw_I + Mat3::Identity() * gyro_var;

  has_frame_ = true;
  frame_pose_ = toBase(frame_imu_);
  return frame_pose_;
}

BodyPose BodyOdometry::predictedPose(double t_s, const diekf::State& x, const ErrorCov& P) const {
  const Vec3 w = last_gyro_I_;
  const Kinematics k = kinematics(x, P, q_odom_imu_, w);
  BodyPose p = frame_imu_;
  const double dt = std::max(0.0, t_s - frame_imu_.t_s);
  p.t_s = t_s;
  if (has_frame_ && dt <= max_integration_gap_s) {
    p.position_m.head<2>() += 0.5 * (frame_velocity_odom_ + k.v_imu_odom).head<2>() * dt;
    p.pose_covariance(0, 0) += k.cov_v_odom(0, 0) * dt * dt;
    p.pose_covariance(1, 1) += k.cov_v_odom(1, 1) * dt * dt;
    p.pose_covariance(5, 5) += gyro_psd_ * dt + k.P_bw_I(2, 2) * dt * dt;
  }
  if (height_usable_ && !rebase_pending_) {
    p.position_m.z() = k.h_m + z_offset_m_;
    p.pose_covariance(2, 2) = (k.J_h * P * k.J_h.transpose())(0, 0);
  }  // else: z held, as at the last frame
  p.orientation = k.q_odom_imu;
  p.linear_velocity_mps = k.v_imu_I;
  p.angular_velocity_radps = w;
  const double var_tilt = 0.5 * P.block<2, 2>(ErrIdx::kG, ErrIdx::kG).trace();
  p.pose_covariance(3, 3) = var_tilt;
  p.pose_covariance(4, 4) = var_tilt;
  p.twist_covariance.setZero();
  p.twist_covariance.topLeftCorner<3, 3>() = k.cov_v_I;
  p.twist_covariance.bottomRightCorner<3, 3>() = k.P_bw_I + Mat3::Identity() * gyro_var_per_sample_;
  return toBase(p);
}

void BodyOdometry::restart() {
  has_frame_ = false;
  t_imu_s_ = -1.0;
  gyro_sum_.setZero();
  gyro_count_ = 0;
  has_prev_height_ = false;
  if (z_hold_valid_) rebase_pending_ = true;
}

}  // namespace diekf_ros
