#include "diekf/ros/estimator_nodelet.h"

#include <cmath>
#include <exception>
#include <map>
#include <sstream>
#include <utility>

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Path.h>
#include <pluginlib/class_list_macros.hpp>
#include <sensor_msgs/image_encodings.h>

#include "diekf/PlanarState.h"
#include "diekf/fixed_pattern.h"
#include "diekf/imu_filter.h"
#include "diekf/param_source.h"
#include "diekf/ros/camera_info_calibration.h"
#include "diekf/ros/conversions.h"
#include "diekf/ros/driver_settings.h"
#include "diekf/ros/ros_param_source.h"
#include "diekf/stamp_check.h"

namespace diekf_ros {

namespace {

constexpr double kWarnPeriodS = 5.0;  // ROS_WARN_THROTTLE period, s

/// Appends `item` to a bounded queue, dropping the oldest entries beyond `max_size`; true if any was dropped.
template <typename Queue, typename Item>
bool pushDroppingOldest(Queue* queue, const Item& item, int max_size) {
  queue->push_back(item);
  bool dropped = false;
  while (static_cast<int>(queue->size()) > max_size) {
    queue->pop_front();
    dropped = true;
  }
  return dropped;
}

}  // namespace

template <EstimatorNodelet::Input kInput>
bool EstimatorNodelet::admitStamp(double t_s) {
  constexpr bool kImu = kInput == Input::kImu;
  const char* const name = kImu ? "IMU" : "image";
  double& last_s = kImu ? last_imu_stamp_s_ : last_image_stamp_s_;
  if (last_s >= 0.0) {
    const double dt = t_s - last_s;
    const diekf::StampStep step = diekf::classifyStampStep(last_s, t_s, params_.input.time_jump_reset_s);
    if (step == diekf::StampStep::kJumpBack) {
      NODELET_WARN("diekf: %s time jumped back by %.3f s (bag loop or clock reset): restarting the filter", name, -dt);
      requestRestart(std::string(name) + " time jumped backwards", true);
      (kImu ? last_image_stamp_s_ : last_imu_stamp_s_) = -1.0;  // the other input's stamps start again too
      if (settings_.imu_rate_measure_s > 0.0) startImuRateMeasurement();  // a restarted driver may run at another rate
    } else if (step != diekf::StampStep::kForward) {
      NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: %s %s (stamp %.6f s, previous %.6f s) dropped",
                            step == diekf::StampStep::kDuplicate ? "duplicated" : "out-of-order",
                            kImu ? "IMU message" : "image", t_s, last_s);
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++(kImu ? imu_dropped_ : images_dropped_);
      return false;
    } else if (dt > (kImu ? params_.max_imu_gap_s : 3.0 / settings_.expected_image_rate_hz)) {
      NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: %s gap of %.3f s before stamp %.6f s", name, dt, t_s);
    }
  }
  last_s = t_s;
  return true;
}

template <typename Queue, typename Item>
bool EstimatorNodelet::enqueue(Queue* queue, const Item& item, int max_size, uint64_t* received, uint64_t* dropped) {
  bool overflow = false;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    overflow = pushDroppingOldest(queue, item, max_size);
  }
  queue_cv_.notify_one();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++*received;
  if (overflow) ++*dropped;
  return overflow;
}

EstimatorNodelet::~EstimatorNodelet() {
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    stop_ = true;
  }
  queue_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void EstimatorNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh_, pnh_, getName());
  updater_->setHardwareID("diekf");
  updater_->add("filter", this, &EstimatorNodelet::filterDiagnostics);

  try {
    loadSettings();
    // The calibration: the Kalibr camchain when given (first choice), else camera_info and TF once they arrive
    // (tryCalibrationFromCameraInfo).
    if (!settings_.camchain_file.empty()) {
      camera_ = std::make_unique<diekf::CameraModel>(
          diekf::CameraModel::fromKalibrYaml(settings_.camchain_file, settings_.camera_name));
      calibration_source_ = "Kalibr camchain " + settings_.camchain_file + " (" + settings_.camera_name + ")";
    }
    // Estimator keys from the private namespace (config/estimator.yaml); the Kalibr IMU file, when given, is the
    // calibration of this very sensor and overrides the noise densities and rate.
    // Keys of the namespace that neither the estimator nor the nodelet reads (typos) are warned about.
    const auto warn = [this](const std::string& warning) { NODELET_WARN("diekf: %s", warning.c_str()); };
    diekf::loadEstimatorParams(RosParamSource(pnh_), &params_, warn, nodeletParamKeys());
    if (!settings_.imu_file.empty()) diekf::loadKalibrImuYaml(settings_.imu_file, &params_.imu);
    configured_params_ = params_;
    if (camera_) buildFilter();
  } catch (const std::exception& e) {
    init_error_ = e.what();
    NODELET_FATAL("diekf: cannot start: %s", e.what());
    diagnostic_timer_ = nh_.createWallTimer(ros::WallDuration(settings_.diagnostic_period_s),
                                            [this](const ros::WallTimerEvent&) { updater_->update(); });
    return;
  }
  {
    std::ostringstream os;
    os << "IMU at imu/input_rate_hz " << params_.imu.input_rate_hz << " Hz (not measured): "
       << (diekf::vibrationNotchesOn(params_.imu) ? "vibration notches, " : "") << "order-"
       << diekf::effectiveLowpassOrder(params_.imu) << " low-pass at "
       << params_.imu.lowpass_cutoff_hz << " Hz, decimation " << params_.imu.decimation_factor;
    imu_design_ = os.str();
  }

  setUpOutputs();
  ready_ = true;
  if (camera_) {
    startProcessing();
  } else {
    NODELET_INFO("diekf: no camchain_file: the calibration comes from camera_info on %s and the IMU -> camera "
                 "transform from TF", settings_.camera_info_topic.c_str());
    calibration_timer_ = nh_.createWallTimer(ros::WallDuration(0.2), [this](const ros::WallTimerEvent&) {
      tryCalibrationFromCameraInfo();
    });
  }
  try {
    setUpInputs();
  } catch (const std::exception& e) {  // e.g. the requested image_transport plugin is not installed
    ready_ = false;
    init_error_ = std::string("cannot subscribe to the inputs: ") + e.what();
    NODELET_FATAL("diekf: %s", init_error_.c_str());
    return;
  }
  NODELET_INFO("diekf: %s: image %s, IMU %s, mode %s", getName().c_str(), settings_.image_topic.c_str(),
               settings_.imu_topic.c_str(), diekf::toString(params_.mode));
}

void EstimatorNodelet::buildFilter() {
  estimator_ = std::make_unique<diekf::Estimator>(*camera_, params_);
  predictor_ = std::make_unique<diekf::StatePredictor>(*camera_, params_);
  odometry_ = std::make_unique<BodyOdometry>(camera_->T_cam_imu, params_.imu.gyro_noise_density,
                                             params_.imu.input_rate_hz, params_.imu.gravity_mps2, T_base_imu_);
  odometry_->max_integration_gap_s = std::max(1.0, 5.0 / settings_.expected_image_rate_hz);
  odometry_->odom_z_step_m = settings_.odom_z_step_m;
  field_of_view_rad_ = 2.0 * std::atan2(0.5 * camera_->K.width, camera_->K.fx);
}

void EstimatorNodelet::startProcessing() {
  NODELET_INFO("diekf: camera %dx%d from the %s", camera_->K.width, camera_->K.height, calibration_source_.c_str());
  if (settings_.imu_rate_measure_s > 0.0) startImuRateMeasurement();
  worker_ = std::thread(&EstimatorNodelet::workerLoop, this);
  if (settings_.publish_static_tf) {
    updateCameraTf();
    if (camera_tf_plan_.kind == CameraTfPlan::Kind::kWait) {
      camera_tf_timer_ = nh_.createWallTimer(ros::WallDuration(0.2), [this](const ros::WallTimerEvent&) {
        updateCameraTf();
      });
    }
  }
  calibrated_ = true;
}

void EstimatorNodelet::tryCalibrationFromCameraInfo() {
  if (!ready_ || calibrated_) {
    calibration_timer_.stop();
    return;
  }
  std::string waiting;
  if (!latest_camera_info_) {
    waiting = "waiting for camera_info on " + settings_.camera_info_topic + " (no camchain_file)";
  } else if (settings_.imu_frame.empty() && imu_frame_id_.empty()) {
    waiting = "waiting for an IMU message on " + settings_.imu_topic + " (its frame_id for the extrinsics)";
  }
  const std::string camera_frame = latest_camera_info_ && !latest_camera_info_->header.frame_id.empty()
                                       ? latest_camera_info_->header.frame_id
                                       : settings_.camera_frame;
  const std::string imu_frame = settings_.imu_frame.empty() ? imu_frame_id_ : settings_.imu_frame;
  geometry_msgs::TransformStamped T;
  if (waiting.empty()) {
    try {
      T = tf_buffer_->lookupTransform(camera_frame, imu_frame, ros::Time(0));
    } catch (const tf2::TransformException& e) {
      waiting = "waiting for the IMU -> camera transform " + camera_frame + " <- " + imu_frame + " in TF: " + e.what();
    }
  }
  if (!waiting.empty()) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: %s", waiting.c_str());
    std::lock_guard<std::mutex> lock(stats_mutex_);
    calibration_source_ = waiting;
    return;
  }
  const Eigen::Isometry3d T_cam_imu = isometryFromMsg(T.transform);
  try {
    camera_ = std::make_unique<diekf::CameraModel>(
        cameraModelFromCameraInfo(*latest_camera_info_, T_cam_imu, settings_.camera_info_topic));
    buildFilter();
  } catch (const std::exception& e) {
    camera_.reset();
    ready_ = false;
    init_error_ = std::string("cannot use the calibration from camera_info: ") + e.what();
    NODELET_FATAL("diekf: %s", init_error_.c_str());
    calibration_timer_.stop();
    return;
  }
  calibration_timer_.stop();
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    calibration_source_ = "camera_info on " + settings_.camera_info_topic + " (" +
                          latest_camera_info_->distortion_model + ") and TF " + camera_frame + " <- " + imu_frame;
  }
  startProcessing();
}

/// The nodelet's own keys in its private namespace (loadSettings, config/mynteye.yaml), plus those that
/// image_transport and diagnostic_updater read there.
std::vector<std::string> EstimatorNodelet::nodeletParamKeys() {
  return {"camchain_file", "camera_name", "imu_file", "image_topic", "imu_topic", "camera_info_topic",
          "image_transport", "odom_frame", "base_frame", "camera_frame", "publish_tf", "publish_static_tf",
          "camera_tf_root", "camera_tf_wait_s", "imu_frame", "driver_node",
          "publish_odometry_imu_rate", "odometry_imu_rate_raw", "odom_z_step_m", "imu_pose_in_base",
          "image_queue_size", "imu_queue_size", "expected_imu_rate_hz",
          "expected_image_rate_hz", "imu_rate_measure_s", "rate_tolerance", "late_image_warn_s",
          "residual_image_gain", "path_max_poses", "gravity_arrow_m", "plane_marker_size_m", "diagnostic_period_s",
          "diagnostic_period"};
}

void EstimatorNodelet::loadSettings() {
  NodeletSettings& s = settings_;
  pnh_.param("camchain_file", s.camchain_file, s.camchain_file);
  pnh_.param("imu_frame", s.imu_frame, s.imu_frame);
  pnh_.param("driver_node", s.driver_node, s.driver_node);
  pnh_.param("camera_name", s.camera_name, s.camera_name);
  pnh_.param("imu_file", s.imu_file, s.imu_file);
  pnh_.param("image_topic", s.image_topic, s.image_topic);
  pnh_.param("imu_topic", s.imu_topic, s.imu_topic);
  pnh_.param("camera_info_topic", s.camera_info_topic, s.camera_info_topic);
  pnh_.param("odom_frame", s.odom_frame, s.odom_frame);
  pnh_.param("base_frame", s.base_frame, s.base_frame);
  pnh_.param("camera_frame", s.camera_frame, s.camera_frame);
  pnh_.param("publish_tf", s.publish_tf, s.publish_tf);
  pnh_.param("publish_static_tf", s.publish_static_tf, s.publish_static_tf);
  pnh_.param("camera_tf_root", s.camera_tf_root, s.camera_tf_root);
  pnh_.param("camera_tf_wait_s", s.camera_tf_wait_s, s.camera_tf_wait_s);
  pnh_.param("publish_odometry_imu_rate", s.publish_odometry_imu_rate, s.publish_odometry_imu_rate);
  pnh_.param("odometry_imu_rate_raw", s.odometry_imu_rate_raw, s.odometry_imu_rate_raw);
  pnh_.param("odom_z_step_m", s.odom_z_step_m, s.odom_z_step_m);
  if (pnh_.hasParam("imu_pose_in_base") && !pnh_.getParam("imu_pose_in_base", s.imu_pose_in_base)) {
    throw std::runtime_error("parameter " + pnh_.resolveName("imu_pose_in_base") +
                             " must be a list of 6 numbers [x, y, z, roll, pitch, yaw] (m, rad)");
  }
  pnh_.param("image_queue_size", s.image_queue_size, s.image_queue_size);
  pnh_.param("imu_queue_size", s.imu_queue_size, s.imu_queue_size);
  pnh_.param("expected_imu_rate_hz", s.expected_imu_rate_hz, s.expected_imu_rate_hz);
  pnh_.param("expected_image_rate_hz", s.expected_image_rate_hz, s.expected_image_rate_hz);
  pnh_.param("imu_rate_measure_s", s.imu_rate_measure_s, s.imu_rate_measure_s);
  pnh_.param("rate_tolerance", s.rate_tolerance, s.rate_tolerance);
  pnh_.param("late_image_warn_s", s.late_image_warn_s, s.late_image_warn_s);
  pnh_.param("residual_image_gain", s.residual_image_gain, s.residual_image_gain);
  pnh_.param("path_max_poses", s.path_max_poses, s.path_max_poses);
  pnh_.param("gravity_arrow_m", s.gravity_arrow_m, s.gravity_arrow_m);
  pnh_.param("plane_marker_size_m", s.plane_marker_size_m, s.plane_marker_size_m);
  pnh_.param("diagnostic_period_s", s.diagnostic_period_s, s.diagnostic_period_s);
  auto require = [this](bool ok, const char* key, const char* what) {
    if (!ok) throw std::runtime_error("parameter " + pnh_.resolveName(key) + " must be " + what);
  };
  require(s.image_queue_size >= 1, "image_queue_size", ">= 1");
  require(s.imu_queue_size >= 10, "imu_queue_size", ">= 10");
  require(s.expected_imu_rate_hz > 0.0, "expected_imu_rate_hz", "> 0");
  require(s.expected_image_rate_hz > 0.0, "expected_image_rate_hz", "> 0");
  require(s.imu_rate_measure_s >= 0.0 && s.imu_rate_measure_s <= 30.0, "imu_rate_measure_s", "in [0, 30] s");
  require(s.rate_tolerance > 0.0 && s.rate_tolerance < 1.0, "rate_tolerance", "in (0, 1)");
  require(s.diagnostic_period_s > 0.0, "diagnostic_period_s", "> 0");
  require(s.path_max_poses >= 0, "path_max_poses", ">= 0");
  require(s.camera_tf_wait_s >= 0.0, "camera_tf_wait_s", ">= 0");
  require(s.odom_z_step_m >= 0.0, "odom_z_step_m", ">= 0");
  require(s.imu_pose_in_base.size() == 6, "imu_pose_in_base", "a list of 6 numbers [x, y, z, roll, pitch, yaw] (m, rad)");
  for (double v : s.imu_pose_in_base) require(std::isfinite(v), "imu_pose_in_base", "finite");
  T_base_imu_ = Eigen::Isometry3d::Identity();
  T_base_imu_.translation() = Eigen::Vector3d(s.imu_pose_in_base[0], s.imu_pose_in_base[1], s.imu_pose_in_base[2]);
  T_base_imu_.linear() = (Eigen::AngleAxisd(s.imu_pose_in_base[5], Eigen::Vector3d::UnitZ()) *
                          Eigen::AngleAxisd(s.imu_pose_in_base[4], Eigen::Vector3d::UnitY()) *
                          Eigen::AngleAxisd(s.imu_pose_in_base[3], Eigen::Vector3d::UnitX()))
                             .toRotationMatrix();
  require(!s.odom_frame.empty() && !s.base_frame.empty() && !s.camera_frame.empty(), "odom_frame",
          "non-empty (as base_frame and camera_frame)");
  require(!s.camchain_file.empty() || !s.camera_info_topic.empty(), "camera_info_topic",
          "set when camchain_file is empty (the calibration then comes from camera_info)");
}

void EstimatorNodelet::setUpOutputs() {
  state_pub_ = pnh_.advertise<diekf::PlanarState>("state", 10);
  odom_pub_ = pnh_.advertise<nav_msgs::Odometry>("odometry", 10);
  twist_pub_ = pnh_.advertise<geometry_msgs::TwistWithCovarianceStamped>("twist", 10);
  range_pub_ = pnh_.advertise<sensor_msgs::Range>("height", 10);
  down_range_pub_ = pnh_.advertise<sensor_msgs::Range>("range", 10);
  path_pub_ = pnh_.advertise<nav_msgs::Path>("path", 1);
  markers_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("markers", 1);
  if (settings_.publish_odometry_imu_rate) {
    odom_imu_pub_ = pnh_.advertise<nav_msgs::Odometry>("odometry_imu_rate", 50);
  }
  pit_ = std::make_unique<image_transport::ImageTransport>(pnh_);
  residual_pub_ = pit_->advertise("residual_image", 1);
  reset_srv_ = pnh_.advertiseService("reset", &EstimatorNodelet::resetService, this);

  if (settings_.publish_tf) tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
  if (settings_.publish_static_tf) static_tf_broadcaster_ = std::make_unique<tf2_ros::StaticTransformBroadcaster>();
  // TF is read for the camera's place in the tree (camera_tf_root) and, without a camchain, for the extrinsics.
  if ((settings_.publish_static_tf && !settings_.camera_tf_root.empty()) || !camera_) {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>();
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_);
  }

  const double tol = settings_.rate_tolerance;
  imu_rate_min_hz_ = settings_.expected_imu_rate_hz * (1.0 - tol);
  imu_rate_max_hz_ = settings_.expected_imu_rate_hz * (1.0 + tol);
  image_rate_min_hz_ = settings_.expected_image_rate_hz * (1.0 - tol);
  image_rate_max_hz_ = settings_.expected_image_rate_hz * (1.0 + tol);
  imu_rate_diag_ = std::make_unique<diagnostic_updater::HeaderlessTopicDiagnostic>(
      "imu input " + settings_.imu_topic, *updater_,
      diagnostic_updater::FrequencyStatusParam(&imu_rate_min_hz_, &imu_rate_max_hz_, 0.0, 5));
  image_rate_diag_ = std::make_unique<diagnostic_updater::HeaderlessTopicDiagnostic>(
      "image input " + settings_.image_topic, *updater_,
      diagnostic_updater::FrequencyStatusParam(&image_rate_min_hz_, &image_rate_max_hz_, 0.0, 5));
  diagnostic_timer_ = nh_.createWallTimer(ros::WallDuration(settings_.diagnostic_period_s),
                                          [this](const ros::WallTimerEvent&) { updater_->update(); });
}

void EstimatorNodelet::setUpInputs() {
  imu_sub_ = nh_.subscribe(settings_.imu_topic, 1000, &EstimatorNodelet::imuCallback, this,
                           ros::TransportHints().tcpNoDelay());
  it_ = std::make_unique<image_transport::ImageTransport>(nh_);
  // The transport ("raw", "compressed", ...) comes from the private parameter ~image_transport.
  image_sub_ = it_->subscribe(settings_.image_topic, 5, &EstimatorNodelet::imageCallback, this,
                              image_transport::TransportHints("raw", ros::TransportHints(), pnh_));
  if (!settings_.camera_info_topic.empty()) {
    camera_info_sub_ = nh_.subscribe(settings_.camera_info_topic, 1, &EstimatorNodelet::cameraInfoCallback, this);
  }
}

void EstimatorNodelet::updateCameraTf() {
  if (camera_tf_plan_.kind != CameraTfPlan::Kind::kWait) return;
  const bool waited = !first_image_ros_time_.isZero() &&
                      (ros::Time::now() - first_image_ros_time_).toSec() >= settings_.camera_tf_wait_s;
  static const tf2::BufferCore kEmpty;
  const CameraTfPlan plan =
      planCameraTf(tf_buffer_ ? static_cast<const tf2::BufferCore&>(*tf_buffer_) : kEmpty, settings_.camera_tf_root,
                   settings_.base_frame, settings_.odom_frame, settings_.camera_frame,
                   T_base_imu_ * camera_->T_cam_imu.inverse(), waited);
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    camera_tf_plan_ = plan;
  }
  switch (plan.kind) {
    case CameraTfPlan::Kind::kWait:
      if (settings_.camera_tf_root != "auto") NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: TF: %s", plan.why.c_str());
      return;
    case CameraTfPlan::Kind::kDirect:
    case CameraTfPlan::Kind::kAttachToRoot:
      static_tf_broadcaster_->sendTransform(transformToMsg(plan.T_parent_child, ros::Time::now(), plan.parent,
                                                            plan.child));
      NODELET_INFO("diekf: TF: publishing %s -> %s: %s", plan.parent.c_str(), plan.child.c_str(), plan.why.c_str());
      break;
    case CameraTfPlan::Kind::kAlreadyConnected:
      NODELET_INFO("diekf: TF: %s", plan.why.c_str());
      break;
    case CameraTfPlan::Kind::kError:
      NODELET_ERROR("diekf: TF: %s; no static transform published", plan.why.c_str());
      break;
  }
  camera_tf_timer_.stop();
  tf_listener_.reset();  // nothing else reads TF
  tf_buffer_.reset();
}

// ------------------------------------------------------------------------------------------------------------
// Callbacks: check stamps, queue for the worker, never touch the estimator.
// ------------------------------------------------------------------------------------------------------------

void EstimatorNodelet::checkClock() {
  // ROS time going backwards (rosbag play --loop with use_sim_time, a restarted simulator, a wall-clock step):
  // restart once, unless the message stamps have already done so (they then agree with the new clock).
  const double now_s = ros::Time::now().toSec();
  const double jump_s = last_ros_now_s_ - now_s;
  const double newest_stamp_s = std::max(last_imu_stamp_s_, last_image_stamp_s_);
  const bool restart = clockJumpNeedsRestart(last_ros_now_s_, now_s, newest_stamp_s, params_.input.time_jump_reset_s);
  last_ros_now_s_ = now_s;
  if (restart) {
    NODELET_WARN("diekf: ROS time jumped back by %.3f s (bag loop / simulated clock reset): restarting the filter",
                 jump_s);
    requestRestart("ROS time jumped backwards", true);
    last_imu_stamp_s_ = -1.0;
    last_image_stamp_s_ = -1.0;
    if (settings_.imu_rate_measure_s > 0.0) startImuRateMeasurement();
  }
}

void EstimatorNodelet::imuCallback(const sensor_msgs::ImuConstPtr& msg) {
  if (!ready_) return;
  if (!calibrated_) {  // the calibration from camera_info and TF is still missing
    if (imu_frame_id_.empty()) imu_frame_id_ = msg->header.frame_id;
    return;
  }
  checkClock();
  diekf::ImuSample sample;
  if (!imuFromMsg(*msg, &sample)) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: non-finite IMU message dropped");
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++imu_dropped_;
    return;
  }
  imu_rate_diag_->tick();
  const double t = sample.t_s;
  if (!admitStamp<Input::kImu>(t)) return;
  if (measuring_imu_rate_) {
    // Held back until the rate is known (the preprocessing is designed for it), then handed over at once.
    imu_rate_buffer_.push_back(sample);
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++imu_received_;
    }
    if (imu_rate_meter_.add(t)) finishImuRateMeasurement();
    return;
  }
  if (enqueue(&imu_queue_, sample, settings_.imu_queue_size, &imu_received_, &imu_dropped_))
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: IMU queue full (worker not keeping up): oldest sample dropped");
}

void EstimatorNodelet::imageCallback(const sensor_msgs::ImageConstPtr& msg) {
  if (!ready_ || !calibrated_) return;
  checkClock();
  if (first_image_ros_time_.isZero()) {
    first_image_ros_time_ = ros::Time::now();
    checkDriverSettings();  // the driver runs now: its parameters are set
  }
  image_rate_diag_->tick();
  const double t = msg->header.stamp.toSec();
  if (!admitStamp<Input::kImage>(t)) return;
  if (measuring_imu_rate_ || !ready_) {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++images_received_;
    ++images_skipped_measuring_;
    return;
  }
  const double t_imu_clock = t + camera_->timeshift_cam_imu_s;
  if (last_imu_stamp_s_ >= 0.0 && t_imu_clock < last_imu_stamp_s_ - settings_.late_image_warn_s) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: late image: %.3f s older than the newest IMU sample",
                          last_imu_stamp_s_ - t_imu_clock);
  }
  if (enqueue(&image_queue_, msg, settings_.image_queue_size, &images_received_, &images_dropped_))
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: image queue full (update slower than the camera): oldest dropped");
}

void EstimatorNodelet::cameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg) {
  if (settings_.camchain_file.empty()) {  // camera_info is the calibration (tryCalibrationFromCameraInfo)
    if (!calibrated_) latest_camera_info_ = msg;
    return;
  }
  if (camera_info_checked_) return;
  camera_info_checked_ = true;
  std::string why;
  if (cameraInfoAgrees(*msg, *camera_, &why)) {
    NODELET_INFO("diekf: camera_info agrees with the calibration %s", settings_.camchain_file.c_str());
  } else {
    NODELET_WARN("diekf: camera_info on %s disagrees with the calibration %s (the calibration is used): %s",
                 settings_.camera_info_topic.c_str(), settings_.camchain_file.c_str(), why.c_str());
    std::lock_guard<std::mutex> lock(stats_mutex_);
    camera_info_mismatch_ = why;
  }
}

void EstimatorNodelet::startImuRateMeasurement() {
  measuring_imu_rate_ = true;
  imu_rate_meter_ = diekf::RateMeter(settings_.imu_rate_measure_s, 20);
  imu_rate_buffer_.clear();
}

bool EstimatorNodelet::finishImuRateMeasurement() {
  measuring_imu_rate_ = false;
  const double rate_hz = imu_rate_meter_.rateHz();
  std::string summary;
  diekf::ImuParams imu;
  try {
    imu = diekf::designImuPreprocessing(configured_params_.imu, rate_hz, &summary);
  } catch (const std::invalid_argument& e) {
    init_error_ = std::string("cannot preprocess the IMU: ") + e.what();
    ready_ = false;
    imu_rate_buffer_.clear();
    NODELET_FATAL("diekf: %s", init_error_.c_str());
    return false;
  }
  NODELET_INFO("diekf: %s (median of %d intervals)", summary.c_str(), imu_rate_meter_.intervals());
  imu_rate_min_hz_ = rate_hz * (1.0 - settings_.rate_tolerance);
  imu_rate_max_hz_ = rate_hz * (1.0 + settings_.rate_tolerance);
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    pending_imu_params_ = imu;
    imu_design_pending_ = true;
    imu_queue_.insert(imu_queue_.end(), imu_rate_buffer_.begin(), imu_rate_buffer_.end());
  }
  imu_rate_buffer_.clear();
  queue_cv_.notify_one();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  measured_imu_rate_hz_ = rate_hz;
  imu_design_ = summary;
  return true;
}

void EstimatorNodelet::checkDriverSettings() {
  if (settings_.driver_node.empty()) return;
  std::map<std::string, int> found;
  for (const char* key : kIrControlKeys) {
    int value = 0;
    if (nh_.getParam(settings_.driver_node + "/" + key, value)) found[key] = value;
  }
  std::string text;
  if (irProjectorMayBeOn(found, settings_.driver_node, &text)) {
    NODELET_WARN("diekf: %s", text.c_str());
  } else {
    NODELET_INFO("diekf: %s", text.c_str());
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ir_projector_ = text;
}

bool EstimatorNodelet::resetService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  if (!ready_) {
    res.success = false;
    res.message = "not running: " + init_error_;
    return true;
  }
  requestRestart("reset requested through the service", false);
  res.success = true;
  res.message = "filter reset; the next image becomes the reference";
  return true;
}

void EstimatorNodelet::requestRestart(const std::string& reason, bool rebuild) {
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    restart_requested_ = true;
    restart_rebuild_ = restart_rebuild_ || rebuild;
    restart_reason_ = reason;
    if (rebuild) {  // stamps before the jump are useless now
      imu_queue_.clear();
      image_queue_.clear();
    }
  }
  queue_cv_.notify_one();
}

// ------------------------------------------------------------------------------------------------------------
// Worker thread.
// ------------------------------------------------------------------------------------------------------------

void EstimatorNodelet::workerLoop() {
  std::deque<diekf::ImuSample> imu;
  while (true) {
    sensor_msgs::ImageConstPtr image;
    bool restart = false, rebuild = false, design = false;
    diekf::ImuParams design_params;
    std::string reason;
    {
      std::unique_lock<std::mutex> lock(queue_mutex_);
      queue_cv_.wait(lock, [this] {
        return stop_ || restart_requested_ || imu_design_pending_ || !imu_queue_.empty() || !image_queue_.empty();
      });
      if (stop_) return;
      std::swap(restart, restart_requested_);
      std::swap(rebuild, restart_rebuild_);
      std::swap(reason, restart_reason_);
      if (imu_design_pending_) {
        design = true;
        design_params = pending_imu_params_;
        imu_design_pending_ = false;
      }
      // Stamp order: the IMU samples up to the oldest waiting image, then that image. Without an image, all IMU
      // samples (the estimator keeps enough IMU history for an image that arrives after its samples).
      if (!image_queue_.empty()) {
        image = image_queue_.front();
        image_queue_.pop_front();
        const double t_img = image->header.stamp.toSec() + camera_->timeshift_cam_imu_s;
        while (!imu_queue_.empty() && imu_queue_.front().t_s <= t_img) {
          imu.push_back(imu_queue_.front());
          imu_queue_.pop_front();
        }
      } else {
        imu.insert(imu.end(), imu_queue_.begin(), imu_queue_.end());
        imu_queue_.clear();
      }
    }
    try {
      if (restart) restartFilter(reason, rebuild);
      if (design) applyImuDesign(design_params);
      for (const diekf::ImuSample& s : imu) forwardImu(s);
      imu.clear();
      if (image) forwardImage(image);
      drainResults();
    } catch (const std::exception& e) {
      // Never let the worker die: start the filter afresh and go on with the next inputs.
      imu.clear();
      NODELET_ERROR_THROTTLE(kWarnPeriodS, "diekf: error in the worker thread: %s: restarting the filter", e.what());
      try {
        restartFilter(std::string("internal error: ") + e.what(), true);
      } catch (const std::exception& e2) {
        NODELET_ERROR_THROTTLE(kWarnPeriodS, "diekf: cannot restart the filter: %s", e2.what());
      }
    }
  }
}

void EstimatorNodelet::restartFilter(const std::string& reason, bool rebuild) {
  if (rebuild) {
    estimator_ = std::make_unique<diekf::Estimator>(*camera_, params_);
  } else {
    estimator_->reset(reason);
  }
  odometry_->restart();
  predictor_->reset(rebuild);
  NODELET_INFO("diekf: filter restarted: %s", reason.c_str());
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++restarts_;
  last_reset_reason_ = reason;
  last_status_ = diekf::FilterStatus::kReset;
  last_message_ = reason;
}

void EstimatorNodelet::applyImuDesign(const diekf::ImuParams& imu) {
  params_.imu = imu;
  estimator_ = std::make_unique<diekf::Estimator>(*camera_, params_);
  predictor_ = std::make_unique<diekf::StatePredictor>(*camera_, params_);
  odometry_ = std::make_unique<BodyOdometry>(camera_->T_cam_imu, params_.imu.gyro_noise_density,
                                             params_.imu.input_rate_hz, params_.imu.gravity_mps2, T_base_imu_);
  odometry_->max_integration_gap_s = std::max(1.0, 5.0 / settings_.expected_image_rate_hz);
  odometry_->odom_z_step_m = settings_.odom_z_step_m;
}

void EstimatorNodelet::forwardImu(const diekf::ImuSample& s) {
  if (!estimator_->addImu(s)) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: estimator rejected the IMU sample at %.6f s: %s", s.t_s,
                          estimator_->takeWarning().c_str());
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++imu_dropped_;
    return;
  }
  odometry_->addImu(s.t_s, s.accel_mps2, s.gyro_radps);
  const bool filtered = predictor_->addImu(s);
  // ~odometry_imu_rate: the last posterior predicted to this sample's stamp by the filter's own prediction
  // (diekf::StatePredictor), at every filtered sample (100 Hz) or every raw one.
  if (settings_.publish_odometry_imu_rate && odometry_->hasFrame() && (filtered || settings_.odometry_imu_rate_raw)) {
    diekf::State x;
    diekf::ErrorCov P;
    nav_msgs::Odometry odom;
    if (predictor_->predict(s.t_s, &x, &P) && x.allFinite() && P.allFinite() &&
        fillOdometry(odometry_->predictedPose(s.t_s, x, P), settings_.odom_frame, settings_.base_frame, &odom)) {
      odom_imu_pub_.publish(odom);
    }
  }
}

void EstimatorNodelet::forwardImage(const sensor_msgs::ImageConstPtr& msg) {
  // The message's own pixels (zero-copy); Estimator::addImage resamples them to the working size at once (colour
  // converted to grey first, diekf::toGrey8) and keeps only that. Colour in RGB order is converted here, the estimator taking colour as BGR.
  cv_bridge::CvImageConstPtr shared;
  diekf::ChannelOrder order = diekf::ChannelOrder::kBgr;
  std::string error;
  bool ok = imageView(msg, &shared, &order, &error);
  cv::Mat pixels;
  if (ok) {
    pixels = shared->image;
    if (order == diekf::ChannelOrder::kRgb && pixels.channels() > 1) {
      ok = diekf::toGrey8(pixels, order, &rgb_grey_);
      pixels = rgb_grey_;
    }
  }
  if (ok && (pixels.cols != camera_->K.width || pixels.rows != camera_->K.height)) {
    ok = false;
    error = "image is " + std::to_string(pixels.cols) + "x" + std::to_string(pixels.rows) +
            " but the calibration is " + std::to_string(camera_->K.width) + "x" + std::to_string(camera_->K.height);
  }
  if (ok && !estimator_->addImage(msg->header.stamp.toSec(), pixels)) {
    ok = false;
    error = "estimator rejected it: " + estimator_->takeWarning();
  }
  if (!ok) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: image at %.6f s dropped: %s", msg->header.stamp.toSec(),
                          error.c_str());
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++images_dropped_;
  }
}

void EstimatorNodelet::drainResults() {
  diekf::FrameResult result;
  while (estimator_->popResult(&result)) publishResult(result);
  const std::string warning = estimator_->takeWarning();
  if (!warning.empty()) NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: %s", warning.c_str());
}

void EstimatorNodelet::publishResult(const diekf::FrameResult& r) {
  if (!(std::isfinite(r.t_s) && r.t_s >= 0.0)) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: estimate with an invalid stamp (%f s) not published", r.t_s);
    return;
  }
  std_msgs::Header header;
  header.stamp = ros::Time(r.t_s);
  header.frame_id = settings_.camera_frame;

  diekf::PlanarState state;
  if (!r.state.allFinite() || !r.covariance.allFinite() || !fillPlanarState(r, header, &state)) {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: non-finite estimate at %.6f s: nothing published for it", r.t_s);
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++frames_skipped_nonfinite_;
    return;
  }
  state_pub_.publish(state);

  sensor_msgs::Range range;
  if (fillRange(r, header, field_of_view_rad_, params_.divergence.min_distance_m,
                params_.divergence.max_distance_m, &range)) {
    range_pub_.publish(range);
  }
  // base_link's -z axis in C, for what a downward rangefinder would read (flight controllers' distance sensor).
  const Vec3 down_C = camera_->R_CI() * T_base_imu_.linear().transpose() * Vec3(0.0, 0.0, -1.0);
  sensor_msgs::Range down_range;
  if (fillDownRange(r, header, down_C, field_of_view_rad_, params_.divergence.min_distance_m,
                    params_.divergence.max_distance_m, &down_range)) {
    down_range_pub_.publish(down_range);
  }

  // After the estimator's own divergence reset the velocity starts again from its prior: do not integrate
  // across (x, y and yaw stay where they were).
  if (r.status == diekf::FilterStatus::kReset) odometry_->restart();
  predictor_->setPosterior(r.t_s, r.state, r.covariance);
  const bool height_usable = r.status == diekf::FilterStatus::kTracking || r.status == diekf::FilterStatus::kDegraded;
  const BodyPose& pose = odometry_->addFrame(r.t_s, r.state, r.covariance, height_usable);
  nav_msgs::Odometry odom;
  if (fillOdometry(pose, settings_.odom_frame, settings_.base_frame, &odom)) {
    odom_pub_.publish(odom);
    geometry_msgs::TwistWithCovarianceStamped twist;
    twist.header.stamp = odom.header.stamp;
    twist.header.frame_id = settings_.base_frame;
    twist.twist = odom.twist;
    twist_pub_.publish(twist);
    if (tf_broadcaster_) {
      geometry_msgs::TransformStamped t;
      t.header = odom.header;
      t.child_frame_id = settings_.base_frame;
      t.transform.translation.x = odom.pose.pose.position.x;
      t.transform.translation.y = odom.pose.pose.position.y;
      t.transform.translation.z = odom.pose.pose.position.z;
      t.transform.rotation = odom.pose.pose.orientation;
      tf_broadcaster_->sendTransform(t);
    }
    if (settings_.path_max_poses > 0) {
      geometry_msgs::PoseStamped p;
      p.header = odom.header;
      p.pose = odom.pose.pose;
      path_.push_back(p);
      while (static_cast<int>(path_.size()) > settings_.path_max_poses) path_.pop_front();
      if (path_pub_.getNumSubscribers() > 0) {
        nav_msgs::Path path;
        path.header = odom.header;
        path.poses.assign(path_.begin(), path_.end());
        path_pub_.publish(path);
      }
    }
  } else {
    NODELET_WARN_THROTTLE(kWarnPeriodS, "diekf: non-finite odometry at %.6f s not published", r.t_s);
  }

  if (markers_pub_.getNumSubscribers() > 0) {
    markers_pub_.publish(makeMarkers(r, header, settings_.gravity_arrow_m, settings_.plane_marker_size_m));
  }
  if (residual_pub_.getNumSubscribers() > 0) {
    const cv::Mat picture = residualPicture(estimator_->lastResidualImage(), estimator_->lastOutlierWeights(),
                                            settings_.residual_image_gain);
    if (!picture.empty()) {
      residual_pub_.publish(cv_bridge::CvImage(header, sensor_msgs::image_encodings::BGR8, picture).toImageMsg());
    }
  }

  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++frames_published_;
  estimator_resets_ = r.resets;
  if (!r.last_reset_reason.empty()) last_reset_reason_ = r.last_reset_reason;
  last_status_ = r.status;
  last_message_ = r.message;
  last_distance_m_ = state.distance;
  last_height_m_ = state.height;
  last_time_offset_ms_ = 1e3 * state.time_offset;
  last_sigma_time_offset_ms_ = 1e3 * state.sigma_time_offset;
  last_focal_scale_pct_ = 1e2 * state.focal_scale;
  last_sigma_focal_scale_pct_ = 1e2 * state.sigma_focal_scale;
  if (r.update_applied) {
    last_update_ms_ = r.update_ms;
    last_nis_ = r.nis;
    last_noise_sigma_ = r.noise_sigma;
    last_noise_correlation_ = r.noise_correlation;
    last_noise_floor_sigma_ = r.noise_floor_sigma;
    last_stamp_jitter_s_ = r.stamp_jitter_s;
    last_imu_notch_hz_ = r.imu_notch_hz;
    if (r.gate_inflation > 1.0) ++gated_updates_;
    last_outlier_fraction_ = r.outlier_fraction;
    last_relief_pct_ = 1e2 * r.relief_sigma;
    last_brightness_gain_ = r.brightness_gain;
    last_brightness_offset_ = r.brightness_offset;
    last_row_banding_pct_ = 1e2 * r.row_banding;
    last_row_gains_ = r.row_gains;
    if (r.light_change) ++light_changes_;
    last_fixed_pattern_fraction_ = r.fixed_pattern_fraction;
    last_fixed_pattern_contrast_share_ = r.fixed_pattern_contrast_share;
    last_dot_removal_px_ = r.dot_removal_px;
    last_dot_fill_pct_ = r.dot_fill_pct;
    last_dot_gain_pct_ = r.dot_gain_pct;
    last_projector_dot_share_ = r.projector_dot_share;
    fixed_pattern_active_ = r.fixed_pattern_active;
    last_vignetting_corner_ = r.vignetting_corner;
    update_ms_sum_ += r.update_ms;
    update_ms_max_ = std::max(update_ms_max_, r.update_ms);
    ++update_count_;
  }
}

// ------------------------------------------------------------------------------------------------------------
// Diagnostics.
// ------------------------------------------------------------------------------------------------------------

void EstimatorNodelet::filterDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  using diagnostic_msgs::DiagnosticStatus;
  if (!ready_) {
    stat.summary(DiagnosticStatus::ERROR, "not running: " + init_error_);
    return;
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  if (!calibrated_) {
    stat.summary(DiagnosticStatus::WARN, calibration_source_.empty() ? "waiting for the calibration"
                                                                     : calibration_source_);
  } else if (measuring_imu_rate_) {
    stat.summaryf(DiagnosticStatus::WARN, "measuring the IMU rate from the stamps of %s (%d intervals so far)",
                  settings_.imu_topic.c_str(), imu_rate_meter_.intervals());
  } else if (imu_received_ == 0) {
    stat.summary(DiagnosticStatus::WARN, "waiting for IMU messages on " + settings_.imu_topic);
  } else if (images_received_ == 0) {
    stat.summary(DiagnosticStatus::WARN, "waiting for images on " + settings_.image_topic);
  } else if (frames_published_ == 0) {
    stat.summary(DiagnosticStatus::WARN, "waiting for the first estimate (IMU must cover the image stamps)");
  } else if (last_status_ == diekf::FilterStatus::kTracking &&
             diekf::patternReported(params_.fixed_pattern, last_fixed_pattern_fraction_,
                                    last_fixed_pattern_contrast_share_)) {
    // A strong camera-fixed pattern (docs/noise_model.md section 11): tracking, but the user should know.
    stat.summaryf(DiagnosticStatus::WARN,
                  "tracking; a camera-fixed pattern covers %.0f %% of the image, %.0f %% of its contrast (IR "
                  "projector on? the drone's shadow, lens dirt)",
                  100.0 * last_fixed_pattern_fraction_, 100.0 * last_fixed_pattern_contrast_share_);
  } else if (last_status_ == diekf::FilterStatus::kTracking) {
    stat.summary(DiagnosticStatus::OK, "tracking");
  } else {
    stat.summaryf(DiagnosticStatus::WARN, "%s%s%s", diekf::toString(last_status_), last_message_.empty() ? "" : ": ",
                  last_message_.c_str());
  }
  stat.add("status", diekf::toString(last_status_));
  stat.add("reason", last_message_);
  stat.add("frames published", frames_published_);
  stat.add("IMU messages received", imu_received_);
  stat.add("images received", images_received_);
  stat.add("IMU messages dropped", imu_dropped_);
  stat.add("images dropped", images_dropped_);
  stat.add("frames skipped (non-finite)", frames_skipped_nonfinite_);
  stat.add("filter restarts", restarts_);
  stat.add("estimator resets (divergence and input faults)", estimator_resets_);
  stat.add("last reset reason", last_reset_reason_);
  if (!camera_info_mismatch_.empty()) stat.add("camera_info disagrees with the calibration", camera_info_mismatch_);
  stat.add("last update time (ms)", last_update_ms_);
  stat.add("last NIS (chi-square 8 dof: mean 8, 99.9 % below 26.1)", last_nis_);
  stat.add("photometric noise sigma (normalised intensity)", last_noise_sigma_);
  stat.add("pixels per independent measurement", last_noise_correlation_);
  stat.add("sensor noise part of the residual sigma (normalised intensity)", last_noise_floor_sigma_);
  stat.add("image stamp jitter about the frame clock (ms)", 1e3 * last_stamp_jitter_s_);
  stat.add("outlier weight removed (share of the image)", last_outlier_fraction_);
  stat.add("scene relief about the plane (distance 1-sigma added, %)", last_relief_pct_);
  if (params_.photometric.brightness_model != diekf::BrightnessModel::kNormalised) {
    stat.add("brightness model of the pair", diekf::toString(params_.photometric.brightness_model));
    stat.add("last pair's brightness gain", last_brightness_gain_);
    stat.add("last pair's brightness offset (normalised intensity)", last_brightness_offset_);
  }
  stat.add("bands of the rows (light flicker under a rolling shutter; smoothed RMS of the row gains, %)",
           last_row_banding_pct_);
  stat.add("row gains estimated", last_row_gains_ ? "yes" : "no");
  stat.add("pairs with a change of the light or exposure (compared standardised; since start)", light_changes_);
  stat.add("camera-fixed pattern learned", fixed_pattern_active_ ? "yes" : "not yet (start-up)");
  stat.add("lens vignetting divided out, at the image's farthest corner (1 = none)", last_vignetting_corner_);
  stat.add("strong camera-fixed pattern (share of the image; projector, shadow, dirt)", last_fixed_pattern_fraction_);
  stat.add("camera-fixed pattern's share of the image contrast", last_fixed_pattern_contrast_share_);
  stat.add("projector dot removal (opening of the raw images, px; 0 = off)", last_dot_removal_px_);
  stat.add("projector dots filled (share of the raw image, %; 0 = off)", last_dot_fill_pct_);
  stat.add("projector dots divided by their learned gain (share of the raw image, %; 0 = not yet or off)",
           last_dot_gain_pct_);
  stat.add("projector dots: share of fixed bright specks at the raw-image test (-1 = running or off)",
           last_projector_dot_share_);
  stat.add("gated updates", gated_updates_);
  stat.add("mean update time (ms)", update_count_ > 0 ? update_ms_sum_ / update_count_ : 0.0);
  stat.add("max update time (ms)", update_ms_max_);
  stat.add("calibration", calibration_source_);
  stat.add("camera driver IR projector", ir_projector_);
  stat.add("IMU rate (Hz, measured; 0 = not measured)", measured_imu_rate_hz_);
  stat.add("IMU preprocessing", imu_design_);
  {
    std::ostringstream notches;
    for (double f : last_imu_notch_hz_)
      if (f > 0.0) notches << (notches.tellp() > 0 ? ", " : "") << f;
    stat.add("IMU vibration notches (Hz; folded propeller tones, imu/aliased_notch)",
             notches.tellp() > 0 ? notches.str() : std::string("none"));
  }
  stat.add("images skipped while measuring the IMU rate", images_skipped_measuring_);
  stat.add("TF base_link to camera", std::string(toString(camera_tf_plan_.kind)) + ": " + camera_tf_plan_.why);
  stat.add("distance (m)", last_distance_m_);
  stat.add("height (m)", last_height_m_);
  stat.add("camera-IMU time offset on top of the calibration's (ms)", last_time_offset_ms_);
  stat.add("camera-IMU time offset 1-sigma (ms)", last_sigma_time_offset_ms_);
  stat.add("focal length correction (%)", last_focal_scale_pct_);
  stat.add("focal length correction 1-sigma (%)", last_sigma_focal_scale_pct_);
}

}  // namespace diekf_ros

PLUGINLIB_EXPORT_CLASS(diekf_ros::EstimatorNodelet, nodelet::Nodelet)
