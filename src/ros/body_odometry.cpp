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

Mat3 velocityCovariance(const diekf::State& x, const ErrorCov& P) {
  Eigen::Matrix<double, 3, 4> J;
  J.col(0) = -x.vartheta / (x.alpha * x.alpha);
  J.rightCols<3>() = Mat3::Identity() / x.alpha;
  const Eigen::Matrix4d P_av = P.block<4, 4>(ErrIdx::kAlpha, ErrIdx::kAlpha);
  return J * P_av * J.transpose();
}

bool BodyPose::allFinite() const {
  return std::isfinite(t_s) && position_m.allFinite() && orientation.coeffs().allFinite() &&
         linear_velocity_mps.allFinite() && angular_velocity_radps.allFinite() && pose_covariance.allFinite() &&
         twist_covariance.allFinite();
}

BodyOdometry::BodyOdometry(const Eigen::Isometry3d& T_cam_imu, double gyro_noise_density, double imu_rate_hz,
                           double gravity_mps2)
    : R_IC_(T_cam_imu.linear().transpose()),
      t_CI_(T_cam_imu.translation()),
      lever_I_m_(R_IC_ * t_CI_),
      gyro_psd_(gyro_noise_density * gyro_noise_density),
      gyro_var_per_sample_(gyro_psd_ * imu_rate_hz),
      gravity_mps2_(gravity_mps2) {}

bool BodyOdometry::addImu(double t_s, const Vec3& accel_mps2, const Vec3& gyro_radps) {
  if (t_imu_s_ >= 0.0 && t_s <= t_imu_s_) return false;
  const double dt = t_imu_s_ < 0.0 ? 0.0 : t_s - t_imu_s_;
  t_imu_s_ = t_s;
  const Vec3 w = gyro_radps - gyro_bias_I_;
  last_gyro_I_ = w;
  gyro_sum_ += w;
  ++gyro_count_;
  // Larger gaps are not integrated (sensor dropout): orientation simply holds.
  if (dt <= 0.0 || dt > 0.1) return true;
  q_odom_base_ = (q_odom_base_ * Eigen::Quaterniond(Eigen::AngleAxisd(diekf::expSO3(w * dt)))).normalized();
  if (has_frame_) {
    const Vec3 a_odom = q_odom_base_ * (accel_mps2 - accel_bias_I_) - Vec3(0.0, 0.0, gravity_mps2_);
    imu_velocity_odom_ += a_odom * dt;
    imu_pose_.position_m += imu_velocity_odom_ * dt;
    imu_pose_.orientation = q_odom_base_;
    imu_pose_.linear_velocity_mps = q_odom_base_.conjugate() * imu_velocity_odom_;
    imu_pose_.angular_velocity_radps = w;
    imu_pose_.t_s = t_s;
  }
  return true;
}

const BodyPose& BodyOdometry::addFrame(double t_s, const diekf::State& x, const ErrorCov& P) {
  gyro_bias_I_ = R_IC_ * x.b_w;
  accel_bias_I_ = R_IC_ * x.b_a;
  const Vec3 w_mean = gyro_count_ > 0 ? Vec3(gyro_sum_ / gyro_count_) : last_gyro_I_;
  const double gyro_var = gyro_var_per_sample_ / std::max(gyro_count_, 1);
  gyro_sum_.setZero();
  gyro_count_ = 0;

  // Orientation: integrated yaw (ZYX), roll and pitch from the up direction seen in base_link.
  const Vec3 up_I = -(R_IC_ * x.g.vector());
  const double pitch = std::atan2(-up_I.x(), std::hypot(up_I.y(), up_I.z()));
  const double roll = std::atan2(up_I.y(), up_I.z());
  const Eigen::Quaterniond& q = q_odom_base_;
  const double yaw = std::atan2(2.0 * (q.w() * q.z() + q.x() * q.y()), 1.0 - 2.0 * (q.y() * q.y() + q.z() * q.z()));
  q_odom_base_ = Eigen::AngleAxisd(yaw, Vec3::UnitZ()) * Eigen::AngleAxisd(pitch, Vec3::UnitY()) *
                 Eigen::AngleAxisd(roll, Vec3::UnitX());
  const Mat3 R_OB = q_odom_base_.toRotationMatrix();

  // Body velocity: camera velocity plus the rigid-body lever-arm term.
  const Vec3 v_body = R_IC_ * x.velocity_mps() + w_mean.cross(lever_I_m_);
  const Vec3 v_odom = R_OB * v_body;
  const Mat3 cov_v_body = R_IC_ * velocityCovariance(x, P) * R_IC_.transpose();
  const Mat3 cov_v_odom = R_OB * cov_v_body * R_OB.transpose();
  const Mat3 P_bw_I = R_IC_ * P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw) * R_IC_.transpose();

  const double dt = t_s - frame_pose_.t_s;
  if (has_frame_ && dt > 0.0 && dt <= max_integration_gap_s) {
    frame_pose_.position_m.head<2>() += 0.5 * (frame_velocity_odom_ + v_odom).head<2>() * dt;
    var_x_m2_ += cov_v_odom(0, 0) * dt * dt;
    var_y_m2_ += cov_v_odom(1, 1) * dt * dt;
    // Gyro white noise integrates to PSD * dt; an unknown bias error to sigma_b^2 * dt^2.
    var_yaw_rad2_ += gyro_psd_ * dt + P_bw_I(2, 2) * dt * dt;
  }
  Row14 J_h;
  frame_pose_.position_m.z() = heightAbovePlane(x, t_CI_, &J_h);
  frame_velocity_odom_ = v_odom;

  frame_pose_.t_s = t_s;
  frame_pose_.orientation = q_odom_base_;
  frame_pose_.linear_velocity_mps = v_body;
  frame_pose_.angular_velocity_radps = w_mean;
  Mat6& Cp = frame_pose_.pose_covariance;
  Cp.setZero();
  Cp(0, 0) = var_x_m2_;
  Cp(1, 1) = var_y_m2_;
  Cp(2, 2) = (J_h * P * J_h.transpose())(0, 0);
  const double var_tilt = 0.5 * P.block<2, 2>(ErrIdx::kG, ErrIdx::kG).trace();
  Cp(3, 3) = var_tilt;
  Cp(4, 4) = var_tilt;
  Cp(5, 5) = var_yaw_rad2_;
  Mat6& Ct = frame_pose_.twist_covariance;
  Ct.setZero();
  Ct.topLeftCorner<3, 3>() = cov_v_body;
  Ct.bottomRightCorner<3, 3>() = P_bw_I + Mat3::Identity() * gyro_var;

  imu_pose_ = frame_pose_;
  imu_velocity_odom_ = v_odom;
  has_frame_ = true;
  return frame_pose_;
}

void BodyOdometry::restart() {
  has_frame_ = false;
  t_imu_s_ = -1.0;
  gyro_sum_.setZero();
  gyro_count_ = 0;
}

}  // namespace diekf_ros
