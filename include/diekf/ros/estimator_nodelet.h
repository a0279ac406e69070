// diekf/EstimatorNodelet: ROS front end of the estimator. onInit only wires things up; the image update runs on
// a worker thread that owns the diekf::Estimator, so the IMU callback only stamps, checks and queues.
#pragma once

#include <atomic>
#include <condition_variable>
#include <array>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <tf2_ros/transform_broadcaster.h>

#include "diekf/camera_model.h"
#include "diekf/estimator.h"
#include "diekf/imu_rate.h"
#include "diekf/params.h"
#include "diekf/state_predictor.h"
#include "diekf/ros/body_odometry.h"
#include "diekf/ros/camera_tf.h"

namespace diekf_ros {

/// Everything the nodelet reads from its private namespace besides the estimator's own keys (config/mynteye.yaml
/// documents each one).
struct NodeletSettings {
  std::string camchain_file;                  ///< Kalibr camchain YAML ("": camera_info + TF)
  std::string camera_name = "cam0";           ///< camera entry in the camchain
  std::string imu_file;                       ///< Kalibr IMU YAML with noise densities (optional)
  std::string image_topic = "/mynteye/left/image_raw";
  std::string imu_topic = "/mynteye/imu/data_raw";
  std::string camera_info_topic = "/mynteye/left/camera_info";  ///< "" disables the check
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string camera_frame = "mynteye_left_frame";
  std::string imu_frame;                      ///< IMU frame for the TF extrinsics without camchain ("": messages')
  std::string driver_node = "/mynteye/mynteye_wrapper_node";  ///< camera driver's node (its parameters); "" = none
  bool publish_tf = true;                     ///< odom -> base_link
  bool publish_static_tf = true;              ///< base_link -> camera (or the camera driver's root) from the extrinsics
  std::string camera_tf_root = "auto";        ///< where base_link attaches: auto, "" (the camera frame), a frame
  double camera_tf_wait_s = 2.0;              ///< auto: ROS time after the first image before publishing directly, s
  bool publish_odometry_imu_rate = false;     ///< ~odometry_imu_rate, predicted from the filter state
  bool odometry_imu_rate_raw = false;         ///< at every raw IMU sample instead of every filtered one
  double odom_z_step_m = 0.1;                 ///< height jump between frames taken as a ground step, m (0 = off)
  std::vector<double> imu_pose_in_base = std::vector<double>(6, 0.0);  ///< x y z (m) roll pitch yaw (rad) of the IMU
  int image_queue_size = 4;                   ///< images waiting for the worker before the oldest is dropped
  int imu_queue_size = 2000;                  ///< IMU samples waiting for the worker (4 s at 500 Hz)
  double expected_imu_rate_hz = 500.0;        ///< for the /diagnostics rate check until the rate is measured, Hz
  double imu_rate_measure_s = 0.5;            ///< IMU stamps measured at start-up for the rate, s (0: imu/input_rate_hz)
  double expected_image_rate_hz = 30.0;       ///< for the /diagnostics rate check, Hz
  double rate_tolerance = 0.3;                ///< accepted relative deviation of the input rates
  double late_image_warn_s = 0.25;            ///< warn when an image is older than the newest IMU by more, s
  double residual_image_gain = 64.0;          ///< grey levels per normalised-intensity unit in ~residual_image
  int path_max_poses = 3000;                  ///< poses kept in ~path
  double gravity_arrow_m = 0.5;               ///< length of the gravity arrow marker, m
  double plane_marker_size_m = 2.0;           ///< side of the plane marker, m
  double diagnostic_period_s = 1.0;           ///< /diagnostics period, s
};

class EstimatorNodelet : public nodelet::Nodelet {
 public:
  EstimatorNodelet() = default;
  ~EstimatorNodelet() override;

 private:
  void onInit() override;
  void loadSettings();
  static std::vector<std::string> nodeletParamKeys();
  void setUpOutputs();
  /// Estimator, odometry and field of view for camera_ and params_.
  void buildFilter();
  /// Once camera_ exists: IMU rate measurement, worker thread, camera TF; then inputs are processed.
  void startProcessing();
  /// Without camchain: the calibration from the latest camera_info and the IMU -> camera transform in TF.
  void tryCalibrationFromCameraInfo();
  /// Reads the camera driver's settings that matter (its IR projector) and warns (callback thread).
  void checkDriverSettings();
  void setUpInputs();

  // Callbacks (nodelet's single-threaded queue: never run concurrently with each other).
  void imuCallback(const sensor_msgs::ImuConstPtr& msg);
  void imageCallback(const sensor_msgs::ImageConstPtr& msg);
  /// The two inputs whose stamps admitStamp checks.
  enum class Input { kImu, kImage };
  /// A new message's stamp against the last of its input (diekf::classifyStampStep, input/time_jump_reset_s): a
  /// jump back restarts the filter (the other input's stamps start again, the IMU's rate is measured again); a
  /// duplicated or out-of-order message is counted as dropped and refused (false); a gap is reported (IMU:
  /// max_imu_gap_s, images: three frame periods). One instantiation per input, so each keeps its own warning
  /// throttles.
  template <Input kInput>
  bool admitStamp(double t_s);
  /// Hands `item` to the worker: appended to `queue` (queue_mutex_; the oldest dropped beyond max_size), the
  /// worker woken, counted in `received` and, when the queue overflowed, in `dropped` (stats_mutex_). True on
  /// overflow (the caller warns).
  template <typename Queue, typename Item>
  bool enqueue(Queue* queue, const Item& item, int max_size, uint64_t* received, uint64_t* dropped);
  void cameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg);
  /// Restarts the filter when ROS time (sim time) jumps backwards ahead of the message stamps.
  void checkClock();
  bool resetService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  void filterDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);
  /// Connects base_link to the camera frame in TF (camera_tf.h), once TF and the first image allow it.
  void updateCameraTf();

  // Worker thread: owns estimator_ and odometry_.
  void workerLoop();
  void forwardImu(const diekf::ImuSample& sample);
  void forwardImage(const sensor_msgs::ImageConstPtr& msg);
  void drainResults();
  void publishResult(const diekf::FrameResult& result);
  void restartFilter(const std::string& reason, bool rebuild);
  void requestRestart(const std::string& reason, bool rebuild);
  /// (Re)starts the measurement of the IMU rate from the stamps (callback thread).
  void startImuRateMeasurement();
  /// Callback thread: the rate is measured; designs the IMU preprocessing for it and hands it to the worker with
  /// the samples held back meanwhile. False (and the nodelet stopped) when the configuration cannot work.
  bool finishImuRateMeasurement();
  /// Worker thread: rebuilds the estimator and the odometry for new IMU preprocessing parameters.
  void applyImuDesign(const diekf::ImuParams& imu);

  NodeletSettings settings_;
  ros::NodeHandle nh_, pnh_;
  bool ready_ = false;
  std::string init_error_;

  std::unique_ptr<diekf::CameraModel> camera_;
  diekf::EstimatorParams params_;
  std::unique_ptr<diekf::Estimator> estimator_;
  std::unique_ptr<BodyOdometry> odometry_;
  std::unique_ptr<diekf::StatePredictor> predictor_;  ///< worker thread: the filter state between images
  Eigen::Isometry3d T_base_imu_ = Eigen::Isometry3d::Identity();  ///< pose of the IMU in base_link

  // Inputs handed from the callbacks to the worker.
  std::mutex queue_mutex_;
  std::condition_variable queue_cv_;
  std::deque<diekf::ImuSample> imu_queue_;
  std::deque<sensor_msgs::ImageConstPtr> image_queue_;
  bool stop_ = false;
  bool restart_requested_ = false;
  bool restart_rebuild_ = false;
  bool imu_design_pending_ = false;   ///< pending_imu_params_ waits for the worker (queue_mutex_)
  diekf::ImuParams pending_imu_params_;
  std::string restart_reason_;
  std::thread worker_;

  // Input bookkeeping (callback thread only).
  double last_imu_stamp_s_ = -1.0;
  double last_image_stamp_s_ = -1.0;
  double last_ros_now_s_ = 0.0;  ///< ros::Time::now() at the previous callback, s
  bool camera_info_checked_ = false;
  // IMU rate measurement (callback thread).
  diekf::RateMeter imu_rate_meter_;
  bool measuring_imu_rate_ = false;
  std::vector<diekf::ImuSample> imu_rate_buffer_;  ///< samples held back while measuring
  diekf::EstimatorParams configured_params_;       ///< as loaded (params_ gets the designed IMU preprocessing)

  // Counters and the filter snapshot for /diagnostics (stats_mutex_).
  std::mutex stats_mutex_;
  uint64_t imu_received_ = 0, images_received_ = 0, frames_published_ = 0;
  uint64_t imu_dropped_ = 0, images_dropped_ = 0, frames_skipped_nonfinite_ = 0, restarts_ = 0;
  diekf::FilterStatus last_status_ = diekf::FilterStatus::kInitializing;
  int estimator_resets_ = 0;           ///< the estimator's own restarts (FrameResult::resets)
  std::string last_reset_reason_;      ///< why the filter last restarted (estimator or nodelet)
  std::string camera_info_mismatch_;   ///< what camera_info disagreed on (empty: agrees or not seen)
  std::string last_message_;
  double measured_imu_rate_hz_ = 0.0;          ///< 0: not measured (yet)
  std::string imu_design_;                     ///< the IMU preprocessing in use, one line
  uint64_t images_skipped_measuring_ = 0;      ///< images dropped while the IMU rate was being measured
  double last_update_ms_ = 0.0, update_ms_sum_ = 0.0, update_ms_max_ = 0.0;
  double last_nis_ = 0.0, last_noise_sigma_ = 0.0, last_noise_correlation_ = 0.0, last_outlier_fraction_ = 0.0;
  double last_noise_floor_sigma_ = 0.0;  // FrameResult::noise_floor_sigma of the last update
  double last_stamp_jitter_s_ = 0.0;     // FrameResult::stamp_jitter_s of the last image
  std::array<double, 2> last_imu_notch_hz_{};  // FrameResult::imu_notch_hz of the last image
  double last_relief_pct_ = 0.0;  // FrameResult::relief_sigma of the last applied update, %
  double last_brightness_gain_ = 1.0, last_brightness_offset_ = 0.0;  ///< the pair's (photometric/brightness_model)
  double last_row_banding_pct_ = 0.0;  ///< FrameResult::row_banding, %
  std::uint64_t light_changes_ = 0;    ///< pairs with FrameResult::light_change since start
  bool last_row_gains_ = false;        ///< FrameResult::row_gains
  double last_fixed_pattern_fraction_ = 0.0;
  double last_fixed_pattern_contrast_share_ = 0.0;
  int last_dot_removal_px_ = 0;
  double last_dot_fill_pct_ = 0.0;
  double last_dot_gain_pct_ = 0.0;
  double last_projector_dot_share_ = -1.0;
  bool fixed_pattern_active_ = false;
  double last_vignetting_corner_ = 1.0;
  double last_time_offset_ms_ = 0.0, last_sigma_time_offset_ms_ = 0.0;
  double last_focal_scale_pct_ = 0.0, last_sigma_focal_scale_pct_ = 0.0;  // focal length correction, %
  std::uint64_t gated_updates_ = 0;
  uint64_t update_count_ = 0;
  double last_distance_m_ = 0.0, last_height_m_ = 0.0;

  // Outputs.
  ros::Publisher state_pub_, odom_pub_, odom_imu_pub_, twist_pub_, range_pub_, down_range_pub_, path_pub_,
      markers_pub_;
  std::unique_ptr<image_transport::ImageTransport> it_, pit_;
  image_transport::Publisher residual_pub_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber imu_sub_, camera_info_sub_;
  ros::ServiceServer reset_srv_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;
  std::unique_ptr<tf2_ros::StaticTransformBroadcaster> static_tf_broadcaster_;
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  ros::WallTimer camera_tf_timer_;
  ros::WallTimer calibration_timer_;
  std::atomic<bool> calibrated_{false};           ///< camera_ and the filter exist; inputs are processed
  sensor_msgs::CameraInfoConstPtr latest_camera_info_;  ///< callback thread
  std::string imu_frame_id_;                      ///< frame_id of the first IMU message (callback thread)
  std::string calibration_source_;                ///< where the calibration came from (stats_mutex_)
  std::string ir_projector_;                      ///< the driver's IR projector setting (stats_mutex_)
  ros::Time first_image_ros_time_;     ///< ROS time of the first image callback (zero before)
  CameraTfPlan camera_tf_plan_;        ///< the decision (stats_mutex_ for diagnostics)
  std::deque<geometry_msgs::PoseStamped> path_;  ///< worker thread only
  cv::Mat rgb_grey_;                             ///< worker thread: grey of an rgb8/rgba8 image

  // Diagnostics.
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  double imu_rate_min_hz_ = 0.0, imu_rate_max_hz_ = 0.0, image_rate_min_hz_ = 0.0, image_rate_max_hz_ = 0.0;
  std::unique_ptr<diagnostic_updater::HeaderlessTopicDiagnostic> imu_rate_diag_, image_rate_diag_;
  ros::WallTimer diagnostic_timer_;
  double field_of_view_rad_ = 1.0;
};

}  // namespace diekf_ros
