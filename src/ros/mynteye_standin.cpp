// diekf/MyntEyeStandin: a stand-in for the MYNT EYE S ROS wrapper's nodelet (mynteye/ROSWrapperNodelet of the
// public slightech/MYNT-EYE-S-SDK, folder wrappers/ros), fed from a recorded or simulated bag instead of the
// device. It reproduces what a node next to the driver can observe (docs/ros.md, "The MYNT EYE S driver and its
// stand-in"):
//  - the private parameters it reads (topic names, frame ids, gravity, the device options standard/... and
//    standard2/...), with the wrapper's defaults where the launch file leaves a parameter unset;
//  - its topics, in the namespace of the nodelet: left/right images through image_transport camera publishers
//    (image + camera_info), the grey left/right_mono images of the S2 models, imu/data_raw and
//    temperature/data_raw;
//  - encodings: mono8 on the S1030 ("standard"), bgr8 images and a mono8 left_mono on the S2 ("standard2");
//  - the IMU message layout: frame imu_frame_id, orientation and every covariance zero, the device's readings
//    in g and deg/s scaled by the `gravity` parameter and pi/180;
//  - stamps: the device clock mapped onto ROS time at start-up; the first 10 images and 50 IMU samples dropped;
//    images and IMU published only while subscribed; the IMU at the device's standard/imu_frequency (the recording
//    resampled on a regular grid, averaged over one period as the sensor's own low-pass would);
//  - its static TF: base_frame_id -> left (identity), left -> right, left_rect, disparity, depth, points and the
//    IMU frame, right -> right_rect, disparity -> disparity_norm;
//  - the way it runs: onInit() never returns, it loops publishing until shutdown (so the process or manager that
//    loads it cannot serve another load request afterwards).
// Not reproduced: the get_info service (its message type lives in the driver's package), the camera mesh marker,
// rectified, disparity, depth and point-cloud streams (advertised, never published).
//
// Stand-in parameters (private, under standin/): bag (required), model (standard | standard2), camchain (Kalibr
// camchain of the bag: T_cam_imu for the left -> IMU transform, and camera_info when the bag has none),
// true_gravity_mps2 (the gravity the bag's specific force was made with, 9.81), wait_for_subscribers (start the
// recording when both the left image and the IMU are subscribed, true), baseline_m (0.12).
#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <geometry_msgs/TransformStamped.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/Temperature.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_ros/static_transform_broadcaster.h>

#include "diekf/camera_model.h"

namespace diekf_ros {

namespace {

constexpr int kSkippedImages = 10;      // the wrapper drops the first 10 images of a stream
constexpr int kSkippedImuSamples = 50;  // and the first 50 IMU samples

geometry_msgs::TransformStamped makeTransform(const std::string& parent, const std::string& child,
                                              const Eigen::Isometry3d& T_parent_child, const ros::Time& stamp) {
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = parent;
  t.child_frame_id = child;
  t.transform.translation.x = T_parent_child.translation().x();
  t.transform.translation.y = T_parent_child.translation().y();
  t.transform.translation.z = T_parent_child.translation().z();
  const Eigen::Quaterniond q(T_parent_child.linear());
  t.transform.rotation.x = q.x();
  t.transform.rotation.y = q.y();
  t.transform.rotation.z = q.z();
  t.transform.rotation.w = q.w();
  return t;
}

sensor_msgs::CameraInfo cameraInfoFrom(const diekf::CameraModel& cam) {
  sensor_msgs::CameraInfo m;
  m.width = static_cast<uint32_t>(cam.K.width);
  m.height = static_cast<uint32_t>(cam.K.height);
  const diekf::Vec4& d = cam.distortion_coeffs;
  if (cam.distortion == diekf::DistortionModel::kEquidistant) {
    m.distortion_model = "KANNALA_BRANDT";  // the wrapper's name for its equidistant (fisheye) calibration
    m.D = {d[0], d[1], d[2], d[3], 0.0};
  } else {
    m.distortion_model = "plumb_bob";
    m.D = {d[0], d[1], d[2], d[3], 0.0};
  }
  m.K = {cam.K.fx, 0.0, cam.K.cx, 0.0, cam.K.fy, cam.K.cy, 0.0, 0.0, 1.0};
  m.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  m.P = {cam.K.fx, 0.0, cam.K.cx, 0.0, 0.0, cam.K.fy, cam.K.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return m;
}

}  // namespace

class MyntEyeStandin : public nodelet::Nodelet {
 private:
  void onInit() override;
  void readParams();
  void advertise();
  void publishStaticTransforms();
  void stream();
  void publishImage(const sensor_msgs::Image& recorded, const ros::Time& stamp);
  /// A recorded IMU sample: published as it is at the recording's rate, or resampled to standard/imu_frequency.
  void addImu(const sensor_msgs::Imu& recorded);
  /// Publishes one device sample (m/s^2 and rad/s in the IMU frame) taken at device time t_s.
  void publishImu(double t_s, const Eigen::Vector3d& accel, const Eigen::Vector3d& gyro);
  ros::Time toRosTime(double device_s) const { return ros_t0_ + ros::Duration(device_s - device_t0_); }

  ros::NodeHandle nh_, pnh_;
  // Driver parameters (the wrapper's names and defaults).
  std::map<std::string, std::string> topics_;  // stream name -> topic
  std::map<std::string, std::string> frames_;  // stream name -> frame id
  std::string base_frame_id_, imu_frame_id_, temperature_frame_id_;
  double gravity_ = 9.8;
  std::string model_ = "standard";
  int imu_frequency_hz_ = -1, frame_rate_hz_ = -1, ir_control_ = -1;
  // Stand-in parameters.
  std::string bag_path_, camchain_path_;
  double true_gravity_mps2_ = 9.81;
  double baseline_m_ = 0.12;
  bool wait_for_subscribers_ = true;
  std::unique_ptr<diekf::CameraModel> camchain_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  std::map<std::string, image_transport::CameraPublisher> camera_pubs_;
  std::map<std::string, image_transport::Publisher> mono_pubs_;
  ros::Publisher imu_pub_, temperature_pub_, points_pub_;
  tf2_ros::StaticTransformBroadcaster static_tf_;
  sensor_msgs::CameraInfo info_;
  bool have_info_ = false;
  int images_seen_ = 0, imu_seen_ = 0;
  uint32_t image_seq_ = 0, imu_seq_ = 0;
  double last_image_device_s_ = -1.0;
  double device_t0_ = -1.0;  ///< device (recording) time of the first message, s
  ros::Time ros_t0_;         ///< ROS time it is mapped onto
  struct ImuRecord {
    double t_s;
    Eigen::Vector3d accel, gyro;
  };
  std::deque<ImuRecord> imu_history_;  ///< recorded samples around the next device sample (resampling)
  double next_imu_t_s_ = -1.0;         ///< device time of the next resampled sample, s
};

void MyntEyeStandin::onInit() {
  nh_ = getMTNodeHandle();
  pnh_ = getMTPrivateNodeHandle();
  readParams();
  advertise();
  publishStaticTransforms();
  // Like the wrapper: onInit() does not return while ROS runs.
  stream();
  NODELET_INFO("mynteye stand-in: leaving onInit");
}

void MyntEyeStandin::readParams() {
  // Topic and frame parameters of the wrapper; a missing parameter keeps the wrapper's built-in default (the
  // stream name as topic, camera_<stream>_frame as frame).
  const std::vector<std::string> streams = {"left", "right", "left_rect", "right_rect", "disparity",
                                            "disparity_norm", "depth", "points"};
  for (const std::string& s : streams) {
    topics_[s] = s;
    pnh_.getParam(s + "_topic", topics_[s]);
    frames_[s] = "camera_" + s + "_frame";
    pnh_.getParam(s + "_frame_id", frames_[s]);
  }
  for (const std::string& s : {std::string("left_mono"), std::string("right_mono")}) {
    topics_[s] = s;
    pnh_.getParam(s + "_topic", topics_[s]);
  }
  topics_["imu"] = "imu";
  pnh_.getParam("imu_topic", topics_["imu"]);
  topics_["temperature"] = "temperature";
  pnh_.getParam("temperature_topic", topics_["temperature"]);
  base_frame_id_ = "camera_link";
  pnh_.getParam("base_frame_id", base_frame_id_);
  imu_frame_id_ = "camera_imu_frame";
  pnh_.getParam("imu_frame_id", imu_frame_id_);
  temperature_frame_id_ = "camera_temperature_frame";
  pnh_.getParam("temperature_frame_id", temperature_frame_id_);
  pnh_.getParam("gravity", gravity_);

  pnh_.param<std::string>("standin/model", model_, model_);
  if (model_ != "standard" && model_ != "standard2") {
    NODELET_FATAL("mynteye stand-in: parameter %s must be standard (S1030) or standard2 (S2), got '%s'",
                  pnh_.resolveName("standin/model").c_str(), model_.c_str());
    model_ = "standard";
  }
  // Device options (-1: leave the device's setting).
  const std::string opt = model_ == "standard" ? "standard/" : "standard2/";
  pnh_.getParam(opt + "ir_control", ir_control_);
  if (model_ == "standard") {
    pnh_.getParam("standard/imu_frequency", imu_frequency_hz_);
    pnh_.getParam("standard/frame_rate", frame_rate_hz_);
    const std::vector<int> rates = {100, 200, 250, 333, 500};
    if (imu_frequency_hz_ != -1 && std::find(rates.begin(), rates.end(), imu_frequency_hz_) == rates.end()) {
      NODELET_WARN("mynteye stand-in: standard/imu_frequency %d is not one of the device's 100, 200, 250, 333, 500",
                   imu_frequency_hz_);
    }
  }
  if (ir_control_ > 0) {
    NODELET_INFO("mynteye stand-in: %sir_control %d (the IR projector would be on; the recording has no pattern)",
                 opt.c_str(), ir_control_);
  }

  if (!pnh_.getParam("standin/bag", bag_path_) || bag_path_.empty()) {
    NODELET_FATAL("mynteye stand-in: parameter %s (the bag to play) is required",
                  pnh_.resolveName("standin/bag").c_str());
  }
  pnh_.getParam("standin/camchain", camchain_path_);
  pnh_.getParam("standin/true_gravity_mps2", true_gravity_mps2_);
  pnh_.getParam("standin/wait_for_subscribers", wait_for_subscribers_);
  pnh_.getParam("standin/baseline_m", baseline_m_);
  if (!camchain_path_.empty()) {
    try {
      camchain_ = std::make_unique<diekf::CameraModel>(diekf::CameraModel::fromKalibrYaml(camchain_path_, "cam0"));
    } catch (const std::exception& e) {
      NODELET_ERROR("mynteye stand-in: cannot read %s: %s", pnh_.resolveName("standin/camchain").c_str(), e.what());
    }
  }
  if (camchain_) {
    info_ = cameraInfoFrom(*camchain_);
    have_info_ = true;
  }
}

void MyntEyeStandin::advertise() {
  it_ = std::make_unique<image_transport::ImageTransport>(nh_);
  for (const char* s : {"left", "right", "left_rect", "right_rect", "disparity", "disparity_norm", "depth"}) {
    camera_pubs_[s] = it_->advertiseCamera(topics_[s], 1);
  }
  points_pub_ = nh_.advertise<sensor_msgs::Image>(topics_["points"], 1);  // never published (type irrelevant)
  if (model_ == "standard2") {
    mono_pubs_["left"] = it_->advertise(topics_["left_mono"], 1);
    mono_pubs_["right"] = it_->advertise(topics_["right_mono"], 1);
  }
  imu_pub_ = nh_.advertise<sensor_msgs::Imu>(topics_["imu"], 100);
  temperature_pub_ = nh_.advertise<sensor_msgs::Temperature>(topics_["temperature"], 100);
}

void MyntEyeStandin::publishStaticTransforms() {
  const ros::Time now = ros::Time::now();
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_left_right = I;
  T_left_right.translation() = Eigen::Vector3d(baseline_m_, 0.0, 0.0);
  // The wrapper's left -> IMU transform comes from the device's stored IMU extrinsics; here from the camchain
  // (p_left = T_cam_imu p_imu), identity without one (an uncalibrated device).
  const Eigen::Isometry3d T_left_imu = camchain_ ? camchain_->T_cam_imu : I;
  std::vector<geometry_msgs::TransformStamped> tfs = {
      makeTransform(base_frame_id_, frames_["left"], I, now),
      makeTransform(frames_["left"], frames_["right"], T_left_right, now),
      makeTransform(frames_["left"], frames_["left_rect"], I, now),
      makeTransform(frames_["right"], frames_["right_rect"], I, now),
      makeTransform(frames_["left"], frames_["disparity"], I, now),
      makeTransform(frames_["disparity"], frames_["disparity_norm"], I, now),
      makeTransform(frames_["left"], frames_["depth"], I, now),
      makeTransform(frames_["left"], frames_["points"], I, now),
      makeTransform(frames_["left"], imu_frame_id_, T_left_imu, now)};
  static_tf_.sendTransform(tfs);
}

void MyntEyeStandin::stream() {
  if (bag_path_.empty()) {
    while (pnh_.ok()) ros::WallDuration(0.1).sleep();
    return;
  }
  rosbag::Bag bag;
  try {
    bag.open(bag_path_, rosbag::bagmode::Read);
  } catch (const std::exception& e) {
    NODELET_FATAL("mynteye stand-in: cannot open %s: %s", bag_path_.c_str(), e.what());
    while (pnh_.ok()) ros::WallDuration(0.1).sleep();
    return;
  }
  // The recording's own topics (those diekf_simulate and the wrapper's defaults use).
  const std::string rec_image = "/mynteye/left/image_raw", rec_imu = "/mynteye/imu/data_raw",
                    rec_info = "/mynteye/left/camera_info";
  if (!have_info_) {
    rosbag::View infos(bag, rosbag::TopicQuery(std::vector<std::string>{rec_info}));
    for (const rosbag::MessageInstance& m : infos) {
      if (auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
        info_ = *info;
        have_info_ = true;
        break;
      }
    }
  }

  if (wait_for_subscribers_) {
    NODELET_INFO("mynteye stand-in: waiting for subscribers of %s and %s", camera_pubs_["left"].getTopic().c_str(),
                 imu_pub_.getTopic().c_str());
    const auto image_subscribers = [this] {
      return camera_pubs_["left"].getNumSubscribers() +
             (mono_pubs_.count("left") ? mono_pubs_["left"].getNumSubscribers() : 0u);
    };
    while (pnh_.ok() && (image_subscribers() == 0 || imu_pub_.getNumSubscribers() == 0)) {
      ros::WallDuration(0.05).sleep();
    }
    ros::WallDuration(0.5).sleep();  // let the other connections (camera_info) settle
  }
  rosbag::View view(bag, rosbag::TopicQuery(std::vector<std::string>{rec_image, rec_imu}));
  if (view.size() == 0) {
    NODELET_FATAL("mynteye stand-in: %s has neither %s nor %s", bag_path_.c_str(), rec_image.c_str(), rec_imu.c_str());
  }
  // Device clock: the recording's stamps; ROS stamp = ROS time at the first message + device time elapsed.
  const ros::WallTime wall_t0 = ros::WallTime::now();
  NODELET_INFO("mynteye stand-in: playing %s (%u messages) as the %s device", bag_path_.c_str(), view.size(),
               model_.c_str());
  for (const rosbag::MessageInstance& m : view) {
    if (!pnh_.ok()) break;
    const bool is_image = m.getTopic() == rec_image;
    ros::Time recorded;
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::ImuConstPtr imu;
    if (is_image) {
      image = m.instantiate<sensor_msgs::Image>();
      if (!image) continue;
      recorded = image->header.stamp;
    } else {
      imu = m.instantiate<sensor_msgs::Imu>();
      if (!imu) continue;
      recorded = imu->header.stamp;
    }
    const double device_s = recorded.toSec();
    if (device_t0_ < 0.0) {
      device_t0_ = device_s;
      ros_t0_ = ros::Time::now();
    }
    const double elapsed_s = device_s - device_t0_;
    // Real-time pacing on the wall clock (the device does not wait).
    const ros::WallTime due = wall_t0 + ros::WallDuration(elapsed_s);
    const ros::WallTime now = ros::WallTime::now();
    if (due > now) (due - now).sleep();
    if (is_image) {
      publishImage(*image, toRosTime(device_s));
    } else {
      addImu(*imu);
    }
  }
  NODELET_INFO("mynteye stand-in: end of %s after %.1f s; no more data", bag_path_.c_str(),
               (ros::WallTime::now() - wall_t0).toSec());
  bag.close();
  while (pnh_.ok()) ros::WallDuration(0.1).sleep();
}

void MyntEyeStandin::publishImage(const sensor_msgs::Image& recorded, const ros::Time& stamp) {
  const double device_s = recorded.header.stamp.toSec();
  if (frame_rate_hz_ > 0 && last_image_device_s_ >= 0.0 &&
      device_s - last_image_device_s_ < 1.0 / frame_rate_hz_ - 0.25 / 60.0) {
    return;  // the device runs at standard/frame_rate: fewer frames than recorded
  }
  last_image_device_s_ = device_s;
  if (++images_seen_ <= kSkippedImages) return;
  if (recorded.encoding != sensor_msgs::image_encodings::MONO8) {
    NODELET_WARN_THROTTLE(5.0, "mynteye stand-in: recorded image is %s, mono8 expected: skipped",
                          recorded.encoding.c_str());
    return;
  }
  ++image_seq_;
  const bool left_subscribed = camera_pubs_["left"].getNumSubscribers() > 0;
  const bool right_subscribed = camera_pubs_["right"].getNumSubscribers() > 0;
  const bool mono_subscribed = mono_pubs_.count("left") && mono_pubs_["left"].getNumSubscribers() > 0;
  if (!left_subscribed && !right_subscribed && !mono_subscribed) return;

  std_msgs::Header header;
  header.seq = image_seq_;
  header.stamp = stamp;
  header.frame_id = frames_["left"];
  sensor_msgs::ImagePtr grey = boost::make_shared<sensor_msgs::Image>(recorded);
  grey->header = header;
  sensor_msgs::ImagePtr out = grey;
  if (model_ == "standard2") {  // colour sensor: bgr8 on image_raw, grey on image_mono
    out = boost::make_shared<sensor_msgs::Image>();
    out->header = header;
    out->width = recorded.width;
    out->height = recorded.height;
    out->encoding = sensor_msgs::image_encodings::BGR8;
    out->step = 3 * recorded.width;
    out->data.resize(static_cast<size_t>(out->step) * out->height);
    for (uint32_t r = 0; r < recorded.height; ++r) {
      for (uint32_t c = 0; c < recorded.width; ++c) {
        const uint8_t v = recorded.data[static_cast<size_t>(r) * recorded.step + c];
        uint8_t* px = &out->data[static_cast<size_t>(r) * out->step + 3 * c];
        px[0] = px[1] = px[2] = v;
      }
    }
  }
  auto info = boost::make_shared<sensor_msgs::CameraInfo>(info_);
  info->header = header;
  if (!have_info_) {
    info->width = recorded.width;
    info->height = recorded.height;
  }
  if (left_subscribed) camera_pubs_["left"].publish(out, info);
  if (mono_subscribed) mono_pubs_["left"].publish(grey);
  if (right_subscribed) {  // no right image in the recording: the left one again, in the right frame
    auto right = boost::make_shared<sensor_msgs::Image>(*out);
    right->header.frame_id = frames_["right"];
    auto right_info = boost::make_shared<sensor_msgs::CameraInfo>(*info);
    right_info->header.frame_id = frames_["right"];
    camera_pubs_["right"].publish(right, right_info);
  }
}

void MyntEyeStandin::addImu(const sensor_msgs::Imu& recorded) {
  const ImuRecord r{recorded.header.stamp.toSec(),
                    Eigen::Vector3d(recorded.linear_acceleration.x, recorded.linear_acceleration.y,
                                    recorded.linear_acceleration.z),
                    Eigen::Vector3d(recorded.angular_velocity.x, recorded.angular_velocity.y,
                                    recorded.angular_velocity.z)};
  if (!imu_history_.empty() && r.t_s <= imu_history_.back().t_s) return;
  if (imu_frequency_hz_ <= 0) {  // the device's rate is the recording's
    publishImu(r.t_s, r.accel, r.gyro);
    return;
  }
  // The device at standard/imu_frequency: samples on its own regular grid, each the mean of the signal over one
  // output period centred on its stamp (the sensor's internal averaging low-pass; without it, vibration in the
  // recording would alias), from the recording linearly interpolated.
  const double T = 1.0 / imu_frequency_hz_;
  imu_history_.push_back(r);
  if (next_imu_t_s_ < 0.0) next_imu_t_s_ = r.t_s + 0.5 * T;
  while (imu_history_.back().t_s >= next_imu_t_s_ + 0.5 * T) {
    const double a = next_imu_t_s_ - 0.5 * T, b = next_imu_t_s_ + 0.5 * T;
    Eigen::Vector3d acc = Eigen::Vector3d::Zero(), gyr = Eigen::Vector3d::Zero();
    for (size_t i = 0; i + 1 < imu_history_.size(); ++i) {  // trapezoids of the interpolation over [a, b]
      const ImuRecord& p = imu_history_[i];
      const ImuRecord& q = imu_history_[i + 1];
      const double lo = std::max(a, p.t_s), hi = std::min(b, q.t_s);
      if (hi <= lo) continue;
      const auto at = [&](double t, const Eigen::Vector3d& vp, const Eigen::Vector3d& vq) {
        return (vp + (vq - vp) * ((t - p.t_s) / (q.t_s - p.t_s))).eval();
      };
      acc += 0.5 * (hi - lo) * (at(lo, p.accel, q.accel) + at(hi, p.accel, q.accel));
      gyr += 0.5 * (hi - lo) * (at(lo, p.gyro, q.gyro) + at(hi, p.gyro, q.gyro));
    }
    publishImu(next_imu_t_s_, acc / T, gyr / T);
    next_imu_t_s_ += T;
    while (imu_history_.size() > 2 && imu_history_[1].t_s <= next_imu_t_s_ - 0.5 * T) imu_history_.pop_front();
  }
}

void MyntEyeStandin::publishImu(double t_s, const Eigen::Vector3d& accel, const Eigen::Vector3d& gyro) {
  if (++imu_seen_ <= kSkippedImuSamples) return;
  const ros::Time stamp = toRosTime(t_s);
  ++imu_seq_;
  if (imu_pub_.getNumSubscribers() == 0 && temperature_pub_.getNumSubscribers() == 0) return;
  // The device reports float readings in g and deg/s; the wrapper multiplies by its `gravity` parameter and pi/180.
  const float ax = static_cast<float>(accel.x() / true_gravity_mps2_);
  const float ay = static_cast<float>(accel.y() / true_gravity_mps2_);
  const float az = static_cast<float>(accel.z() / true_gravity_mps2_);
  const float gx = static_cast<float>(gyro.x() * 180.0 / M_PI);
  const float gy = static_cast<float>(gyro.y() * 180.0 / M_PI);
  const float gz = static_cast<float>(gyro.z() * 180.0 / M_PI);
  if (imu_pub_.getNumSubscribers() > 0) {
    auto msg = boost::make_shared<sensor_msgs::Imu>();  // orientation and all covariances stay zero
    msg->header.seq = imu_seq_;
    msg->header.stamp = stamp;
    msg->header.frame_id = imu_frame_id_;
    msg->orientation.w = 0.0;
    msg->linear_acceleration.x = ax * gravity_;
    msg->linear_acceleration.y = ay * gravity_;
    msg->linear_acceleration.z = az * gravity_;
    msg->angular_velocity.x = gx * M_PI / 180.0;
    msg->angular_velocity.y = gy * M_PI / 180.0;
    msg->angular_velocity.z = gz * M_PI / 180.0;
    imu_pub_.publish(msg);
  }
  if (temperature_pub_.getNumSubscribers() > 0) {
    auto t = boost::make_shared<sensor_msgs::Temperature>();
    t->header.seq = imu_seq_;
    t->header.stamp = stamp;
    t->header.frame_id = temperature_frame_id_;
    t->temperature = 35.0;  // deg C, a plausible board temperature
    t->variance = 0.0;
    temperature_pub_.publish(t);
  }
}

}  // namespace diekf_ros

PLUGINLIB_EXPORT_CLASS(diekf_ros::MyntEyeStandin, nodelet::Nodelet)
