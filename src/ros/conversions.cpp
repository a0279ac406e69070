#include "diekf/ros/conversions.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include <sensor_msgs/image_encodings.h>
#include <tf2_eigen/tf2_eigen.h>

namespace diekf_ros {

namespace enc = sensor_msgs::image_encodings;

namespace {

geometry_msgs::Vector3 toVector3(const Vec3& v) {
  geometry_msgs::Vector3 m;
  return tf2::toMsg(v, m);
}

geometry_msgs::Point toPoint(const Vec3& v) { return tf2::toMsg(v); }

template <typename Array>
void copyCovariance(const Mat6& C, Array* out) {
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) (*out)[6 * r + c] = C(r, c);
}

}  // namespace

Eigen::Isometry3d isometryFromMsg(const geometry_msgs::Transform& t) {
  Vec3 p;
  tf2::fromMsg(t.translation, p);
  Eigen::Quaterniond q;
  tf2::fromMsg(t.rotation, q);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = p;
  T.linear() = q.normalized().toRotationMatrix();
  return T;
}

geometry_msgs::TransformStamped transformToMsg(const Eigen::Isometry3d& T_parent_child, const ros::Time& stamp,
                                               const std::string& parent, const std::string& child) {
  geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_parent_child);
  t.header.stamp = stamp;
  t.header.frame_id = parent;
  t.child_frame_id = child;
  return t;
}

bool imageView(const sensor_msgs::ImageConstPtr& msg, cv_bridge::CvImageConstPtr* view, diekf::ChannelOrder* order,
               std::string* error) {
  int type = -1;
  if (!msg || !diekf::describeImageBuffer(msg->encoding, msg->width, msg->height, msg->step, msg->is_bigendian != 0,
                                          msg->data.size(), &type, order, error)) {
    if (!msg) *error = "null image message";
    return false;
  }
  try {
    *view = cv_bridge::toCvShare(msg);  // same encoding: shares the message's buffer
  } catch (const std::exception& e) {
    *error = std::string("cannot wrap the image: ") + e.what();
    return false;
  }
  if ((*view)->image.type() != type || (*view)->image.data != msg->data.data()) {
    *error = "cv_bridge did not share the image buffer as " + msg->encoding;
    return false;
  }
  return true;
}

bool imageToMono8(const sensor_msgs::Image& msg, cv::Mat* mono8, std::string* error) {
  int type = -1;
  diekf::ChannelOrder order;
  if (!diekf::describeImageBuffer(msg.encoding, msg.width, msg.height, msg.step, msg.is_bigendian != 0,
                                  msg.data.size(), &type, &order, error)) {
    return false;
  }
  // Wraps the message buffer without copying; the result is an owned grey copy.
  const cv::Mat view(static_cast<int>(msg.height), static_cast<int>(msg.width), type,
                     const_cast<uint8_t*>(msg.data.data()), msg.step);
  cv::Mat out;
  if (!diekf::toGrey8(view, order, &out)) {
    *error = "cannot convert " + msg.encoding + " to grey";
    return false;
  }
  *mono8 = out;
  return true;
}

bool imuFromMsg(const sensor_msgs::Imu& msg, diekf::ImuSample* sample) {
  diekf::ImuSample s;
  s.t_s = msg.header.stamp.toSec();
  tf2::fromMsg(msg.linear_acceleration, s.accel_mps2);
  tf2::fromMsg(msg.angular_velocity, s.gyro_radps);
  if (!std::isfinite(s.t_s) || !s.accel_mps2.allFinite() || !s.gyro_radps.allFinite()) return false;
  *sample = s;
  return true;
}

bool clockJumpNeedsRestart(double previous_now_s, double now_s, double newest_stamp_s, double threshold_s) {
  if (!(previous_now_s - now_s > threshold_s) || !(now_s > 0.0)) return false;
  return newest_stamp_s > now_s + threshold_s;
}

uint8_t statusToMsg(diekf::FilterStatus status) {
  switch (status) {
    case diekf::FilterStatus::kTracking:
      return diekf::PlanarState::STATUS_TRACKING;
    case diekf::FilterStatus::kReset:
      return diekf::PlanarState::STATUS_RESET;
    case diekf::FilterStatus::kDegraded:
      return diekf::PlanarState::STATUS_DEGRADED;
    case diekf::FilterStatus::kInitializing:
    default:
      return diekf::PlanarState::STATUS_INITIALIZING;
  }
}

bool fillPlanarState(const diekf::FrameResult& r, const std_msgs::Header& header, diekf::PlanarState* msg) {
  const diekf::State& x = r.state;
  const ErrorCov& P = r.covariance;
  if (!x.allFinite() || !P.allFinite()) return false;
  Row14 J_h;
  const double h = heightAbovePlane(x, Vec3::Zero(), &J_h);
  const Vec3 sigma_v = diekf::sigmaVelocity_mps(x, P);
  diekf::PlanarState m;
  m.header = header;
  m.distance = x.distance_m();
  m.height = h;
  m.velocity = toVector3(x.velocity_mps());
  m.normal = toVector3(x.mu.vector());
  m.gravity = toVector3(x.g.vector());
  m.inverse_distance = x.alpha;
  m.velocity_over_distance = toVector3(x.vartheta);
  m.accel_bias = toVector3(x.b_a);
  m.gyro_bias = toVector3(x.b_w);
  for (int i = 0; i < diekf::kMotionDim; ++i)
    for (int j = 0; j < diekf::kMotionDim; ++j) m.covariance[diekf::kMotionDim * i + j] = P(i, j);
  m.time_offset = x.t_d_s;
  m.sigma_time_offset = std::sqrt(std::max(P(diekf::ErrIdx::kTd, diekf::ErrIdx::kTd), 0.0));
  m.readout_time = x.readout_s;
  m.sigma_readout_time = std::sqrt(std::max(P(diekf::ErrIdx::kRo, diekf::ErrIdx::kRo), 0.0));
  m.focal_scale = x.focal_scale;
  m.sigma_focal_scale = std::sqrt(std::max(P(diekf::ErrIdx::kFs, diekf::ErrIdx::kFs), 0.0));
  m.sigma_distance = diekf::sigmaDistance_m(x, P);
  m.sigma_height = std::sqrt(std::max((J_h * P * J_h.transpose())(0, 0), 0.0));
  m.sigma_velocity = toVector3(sigma_v);
  m.sigma_normal = std::sqrt(std::max(P.block<2, 2>(diekf::ErrIdx::kMu, diekf::ErrIdx::kMu).trace(), 0.0));
  m.sigma_gravity = std::sqrt(std::max(P.block<2, 2>(diekf::ErrIdx::kG, diekf::ErrIdx::kG).trace(), 0.0));
  m.passes = r.passes;
  m.update_ms = r.update_ms;
  m.photometric_rms = r.photometric_rms;
  m.valid_ratio = r.valid_ratio;
  m.fixed_pattern_fraction = r.fixed_pattern_fraction;
  m.fixed_pattern_contrast_share = r.fixed_pattern_contrast_share;
  m.vignetting_corner = r.vignetting_corner;
  m.status = statusToMsg(r.status);
  m.status_text = r.message;
  const bool finite = std::isfinite(m.distance) && std::isfinite(m.height) && sigma_v.allFinite() &&
                      std::isfinite(m.sigma_distance) && std::isfinite(m.sigma_height) &&
                      std::isfinite(m.sigma_normal) && std::isfinite(m.sigma_gravity) &&
                      x.velocity_mps().allFinite() && std::isfinite(m.update_ms) &&
                      std::isfinite(m.photometric_rms) && std::isfinite(m.valid_ratio);
  if (!finite) return false;
  *msg = m;
  return true;
}

bool fillOdometry(const BodyPose& pose, const std::string& odom_frame, const std::string& base_frame,
                  nav_msgs::Odometry* msg) {
  if (!pose.allFinite()) return false;
  nav_msgs::Odometry m;
  m.header.stamp = ros::Time(pose.t_s);
  m.header.frame_id = odom_frame;
  m.child_frame_id = base_frame;
  m.pose.pose.position = toPoint(pose.position_m);
  m.pose.pose.orientation = tf2::toMsg(pose.orientation);
  copyCovariance(pose.pose_covariance, &m.pose.covariance);
  m.twist.twist.linear = toVector3(pose.linear_velocity_mps);
  m.twist.twist.angular = toVector3(pose.angular_velocity_radps);
  copyCovariance(pose.twist_covariance, &m.twist.covariance);
  *msg = m;
  return true;
}

bool fillRange(const diekf::FrameResult& r, const std_msgs::Header& header, double field_of_view_rad,
               double min_range_m, double max_range_m, sensor_msgs::Range* msg) {
  if (!r.state.allFinite()) return false;
  const double h = heightAbovePlane(r.state, Vec3::Zero());
  if (!std::isfinite(h)) return false;
  sensor_msgs::Range m;
  m.header = header;
  m.radiation_type = sensor_msgs::Range::INFRARED;  // closest of the two types for an optical sensor
  m.field_of_view = static_cast<float>(field_of_view_rad);
  m.min_range = static_cast<float>(min_range_m);
  m.max_range = static_cast<float>(max_range_m);
  m.range = static_cast<float>(h);
  *msg = m;
  return true;
}

bool fillDownRange(const diekf::FrameResult& r, const std_msgs::Header& header, const Vec3& down_C,
                   double field_of_view_rad, double min_range_m, double max_range_m, sensor_msgs::Range* msg) {
  if (!r.state.allFinite()) return false;
  const double c = r.state.mu.vector().dot(down_C);  // cosine between the axis and the normal to the plane
  if (!(c > std::cos(80.0 * M_PI / 180.0))) return false;
  const double range = r.state.distance_m() / c;
  if (!std::isfinite(range)) return false;
  sensor_msgs::Range m;
  m.header = header;
  m.radiation_type = sensor_msgs::Range::INFRARED;
  m.field_of_view = static_cast<float>(field_of_view_rad);
  m.min_range = static_cast<float>(min_range_m);
  m.max_range = static_cast<float>(max_range_m);
  m.range = static_cast<float>(range);
  *msg = m;
  return true;
}

bool cameraInfoAgrees(const sensor_msgs::CameraInfo& info, const diekf::CameraModel& camera, std::string* why) {
  std::ostringstream out;
  const diekf::PinholeK& K = camera.K;
  if (static_cast<int>(info.width) != K.width || static_cast<int>(info.height) != K.height) {
    out << "size " << info.width << "x" << info.height << " vs calibration " << K.width << "x" << K.height << "; ";
  } else {
    const double k_info[4] = {info.K[0], info.K[4], info.K[2], info.K[5]};
    const double k_cal[4] = {K.fx, K.fy, K.cx, K.cy};
    const char* names[4] = {"fx", "fy", "cx", "cy"};
    for (int i = 0; i < 4; ++i) {
      if (std::abs(k_info[i] - k_cal[i]) > 0.01 * std::abs(k_cal[i]) + 1e-9) {
        out << names[i] << " " << k_info[i] << " vs " << k_cal[i] << "; ";
      }
    }
  }
  const bool info_equidistant = info.distortion_model == "equidistant" || info.distortion_model == "fisheye";
  const bool info_radtan = info.distortion_model == "plumb_bob" || info.distortion_model == "rational_polynomial";
  const bool cal_equidistant = camera.distortion == diekf::DistortionModel::kEquidistant;
  const bool cal_radtan = camera.distortion == diekf::DistortionModel::kRadTan;
  if ((info_equidistant && !cal_equidistant) || (info_radtan && !cal_radtan && !info.D.empty() &&
                                                 camera.distortion != diekf::DistortionModel::kNone)) {
    out << "distortion model '" << info.distortion_model << "' differs from the calibration's; ";
  } else if ((info_equidistant || info_radtan) && info.D.size() >= 4) {
    for (int i = 0; i < 4; ++i) {
      if (std::abs(info.D[i] - camera.distortion_coeffs[i]) > 1e-3) {
        out << "D[" << i << "] " << info.D[i] << " vs " << camera.distortion_coeffs[i] << "; ";
      }
    }
  }
  *why = out.str();
  return why->empty();
}

cv::Mat residualToMono8(const cv::Mat& residual, double gain_levels_per_unit) {
  cv::Mat out;
  if (residual.empty()) return out;
  cv::Mat r32;
  residual.convertTo(r32, CV_32F);
  cv::patchNaNs(r32, 0.0);
  r32.convertTo(out, CV_8U, gain_levels_per_unit, 128.0);  // saturate_cast clips to 0..255
  return out;
}

cv::Mat residualPicture(const cv::Mat& residual, const cv::Mat& outlier_weights, double gain_levels_per_unit) {
  const cv::Mat grey = residualToMono8(residual, gain_levels_per_unit);
  cv::Mat out;
  if (grey.empty()) return out;
  cv::cvtColor(grey, out, cv::COLOR_GRAY2BGR);
  if (outlier_weights.type() != CV_32FC1 || outlier_weights.size() != grey.size()) return out;
  for (int y = 0; y < out.rows; ++y) {
    const float* w = outlier_weights.ptr<float>(y);
    cv::Vec3b* px = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < out.cols; ++x) {
      const float removed = std::isfinite(w[x]) ? std::clamp(1.0f - w[x], 0.0f, 1.0f) : 1.0f;
      const float keep = 1.0f - removed;
      px[x][0] = cv::saturate_cast<uint8_t>(keep * px[x][0]);
      px[x][1] = cv::saturate_cast<uint8_t>(keep * px[x][1]);
      px[x][2] = cv::saturate_cast<uint8_t>(keep * px[x][2] + removed * 255.0f);
    }
  }
  return out;
}

visualization_msgs::MarkerArray makeMarkers(const diekf::FrameResult& r, const std_msgs::Header& header,
                                            double gravity_arrow_m, double plane_size_m) {
  visualization_msgs::MarkerArray out;
  if (!r.state.allFinite()) return out;
  const Vec3 mu = r.state.mu.vector();
  const Vec3 g = r.state.g.vector();
  const double d = r.state.distance_m();
  const double h = r.state.height_m();
  const Vec3 v = r.state.velocity_mps();
  const bool plane_ok = std::isfinite(d) && d > 0.0;
  auto marker = [&](const char* ns, int id, int type, float red, float green, float blue, float alpha) {
    visualization_msgs::Marker m;
    m.header = header;
    m.ns = ns;  // one namespace per item: each can be switched off in rviz's MarkerArray display
    m.id = id;
    m.type = type;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.color.r = red;
    m.color.g = green;
    m.color.b = blue;
    m.color.a = alpha;
    return m;
  };
  // Shaft diameter in m (head diameter 2x, head length 3x). Near level flight the normal and gravity arrows
  // overlap: gravity is the thicker one, so both stay visible (red for gravity_arrow_m, then blue down to the plane).
  auto arrow = [&](const char* ns, int id, const Vec3& tip, double shaft_m, float red, float green, float blue) {
    visualization_msgs::Marker m = marker(ns, id, visualization_msgs::Marker::ARROW, red, green, blue, 1.0f);
    m.points.push_back(toPoint(Vec3::Zero()));
    m.points.push_back(toPoint(tip));
    m.scale.x = shaft_m;
    m.scale.y = 2.0 * shaft_m;
    m.scale.z = 3.0 * shaft_m;
    return m;
  };
  if (plane_ok) out.markers.push_back(arrow("normal", 0, mu * d, 0.015, 0.1f, 0.4f, 1.0f));  // camera -> plane, d
  out.markers.push_back(arrow("gravity", 1, g * gravity_arrow_m, 0.028, 1.0f, 0.2f, 0.2f));
  if (v.allFinite()) out.markers.push_back(arrow("velocity", 2, v, 0.02, 0.2f, 1.0f, 0.2f));  // 1 s of motion
  if (plane_ok) {
    visualization_msgs::Marker plane = marker("plane", 3, visualization_msgs::Marker::CUBE, 0.8f, 0.8f, 0.5f, 0.5f);
    plane.pose.position = toPoint(mu * d);
    const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), mu);
    plane.pose.orientation.w = q.w();
    plane.pose.orientation.x = q.x();
    plane.pose.orientation.y = q.y();
    plane.pose.orientation.z = q.z();
    plane.scale.x = plane_size_m;
    plane.scale.y = plane_size_m;
    plane.scale.z = 0.002;
    out.markers.push_back(plane);
  }
  // Height: a thin line from the camera along gravity to the plane (length h; it ends on the plane since
  // mu . (h g) = d), and a label with the filter's height (and its 1-sigma), distance, speed and status above the
  // camera.
  if (plane_ok && std::isfinite(h) && h > 0.0) {
    visualization_msgs::Marker line =
        marker("height", 4, visualization_msgs::Marker::LINE_LIST, 0.0f, 1.0f, 1.0f, 1.0f);
    line.points.push_back(toPoint(Vec3::Zero()));
    line.points.push_back(toPoint(g * h));
    line.scale.x = 0.006;  // line width, m
    out.markers.push_back(line);
    visualization_msgs::Marker text =
        marker("label", 5, visualization_msgs::Marker::TEXT_VIEW_FACING, 1.0f, 1.0f, 1.0f, 1.0f);
    text.pose.position = toPoint(-0.12 * g);  // above the camera
    text.scale.z = 0.05;                      // letter height, m
    Row14 J_h;
    heightAbovePlane(r.state, Vec3::Zero(), &J_h);
    const double sigma_h = std::sqrt(std::max((J_h * r.covariance * J_h.transpose())(0, 0), 0.0));
    char buffer[128];
    std::snprintf(buffer, sizeof(buffer), "h %.2f +- %.2f m  d %.2f m  |v| %.2f m/s  %s", h, sigma_h, d, v.norm(),
                  diekf::toString(r.status));
    text.text = buffer;
    out.markers.push_back(text);
  }
  return out;
}

}  // namespace diekf_ros
