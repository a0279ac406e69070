// Message <-> core conversions of the ROS layer (no estimation logic here).
#pragma once

#include <string>

#include <Eigen/Geometry>
#include <geometry_msgs/Transform.h>
#include <geometry_msgs/TransformStamped.h>
#include <geometry_msgs/TwistWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>
#include <cv_bridge/cv_bridge.h>
#include <opencv2/core.hpp>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/Range.h>
#include <visualization_msgs/MarkerArray.h>

#include "diekf/PlanarState.h"
#include "diekf/camera_model.h"
#include "diekf/estimator.h"
#include "diekf/grey_image.h"
#include "diekf/ros/body_odometry.h"

namespace diekf_ros {

/// A TF transform as an isometry (tf2_eigen's message conversions; the quaternion normalised: TF's are only
/// nearly unit).
Eigen::Isometry3d isometryFromMsg(const geometry_msgs::Transform& t);
/// An isometry as the stamped TF transform parent -> child (tf2::eigenToTransform).
geometry_msgs::TransformStamped transformToMsg(const Eigen::Isometry3d& T_parent_child, const ros::Time& stamp,
                                               const std::string& parent, const std::string& child);

/// The image message's own pixels without a copy (cv_bridge::toCvShare; *view keeps the message alive), after
/// checking its fields (diekf::describeImageBuffer): mono8, mono16, bgr8, rgb8, bgra8, rgba8 (also 8UC1 and 16UC1);
/// `order` is the channel order of a colour image. False and why for any other encoding or a malformed message.
bool imageView(const sensor_msgs::ImageConstPtr& msg, cv_bridge::CvImageConstPtr* view, diekf::ChannelOrder* order,
               std::string* error);

/// Grey 8-bit copy of an image in the encodings of imageView (diekf::toGrey8: 16-bit scaled by 1/256).
bool imageToMono8(const sensor_msgs::Image& msg, cv::Mat* mono8, std::string* error);

/// IMU message -> core sample (stamp in s, base_link frame). False if any value is non-finite.
bool imuFromMsg(const sensor_msgs::Imu& msg, diekf::ImuSample* sample);

/// Whether ROS time going from previous_now_s to now_s (a jump back by more than threshold_s, e.g. a looping
/// `rosbag play --clock`) must restart the filter: only when the newest accepted message stamp is still ahead of
/// the new clock by more than threshold_s (otherwise the stamps have already jumped and restarted it). All in s.
bool clockJumpNeedsRestart(double previous_now_s, double now_s, double newest_stamp_s, double threshold_s);

uint8_t statusToMsg(diekf::FilterStatus status);

/// Full filter output (camera frame C). False (message untouched) if any value would be non-finite.
bool fillPlanarState(const diekf::FrameResult& result, const std_msgs::Header& header, diekf::PlanarState* msg);

/// Odometry of base_link in odom with body-frame twist. False if any value would be non-finite.
bool fillOdometry(const BodyPose& pose, const std::string& odom_frame, const std::string& base_frame,
                  nav_msgs::Odometry* msg);

/// Camera height along gravity as a range reading in the camera frame (what flight controllers consume).
/// field_of_view_rad, min/max range in m. False if non-finite.
bool fillRange(const diekf::FrameResult& result, const std_msgs::Header& header, double field_of_view_rad,
               double min_range_m, double max_range_m, sensor_msgs::Range* msg);

/// Distance from the camera to the plane along base_link's -z axis (`down_C`: that axis in C, unit), what a
/// downward rangefinder on the camera measures (flight controllers compensate its tilt themselves). In the header's
/// frame, the other fields as fillRange. False if non-finite or the axis is more than 80 deg off the plane normal.
bool fillDownRange(const diekf::FrameResult& result, const std_msgs::Header& header, const Vec3& down_C,
                   double field_of_view_rad, double min_range_m, double max_range_m, sensor_msgs::Range* msg);

/// Checks a CameraInfo against the calibration: size, K (1 % relative) and distortion (1e-3 absolute, when the
/// model matches). Returns true if they agree; otherwise `why` lists the differences.
bool cameraInfoAgrees(const sensor_msgs::CameraInfo& info, const diekf::CameraModel& camera, std::string* why);

/// Photometric residual (CV_32FC1, normalised intensity) -> mono8 picture, 128 = zero residual,
/// `gain_levels_per_unit` grey levels per normalised intensity unit, clipped to 0..255.
cv::Mat residualToMono8(const cv::Mat& residual, double gain_levels_per_unit);

/// The same as a bgr8 picture with the outlier weights drawn on it (CV_32FC1 in [0, 1], the residual's size; empty:
/// none): each pixel is tinted red by the share of its weight removed, 1 - w (docs/noise_model.md section 10).
cv::Mat residualPicture(const cv::Mat& residual, const cv::Mat& outlier_weights, double gain_levels_per_unit);

/// rviz markers in the header's frame (the camera frame), one namespace each: `normal` arrow (camera -> plane,
/// length d, blue), `gravity` arrow (length gravity_arrow_m, red), `velocity` arrow (1 s of motion, green), `plane`
/// (thin square of side plane_size_m on the estimated plane), `height` (cyan line from the camera along gravity to
/// the plane, length h) and `label` (text above the camera: h and its 1-sigma, d, speed, filter status). Empty if non-finite.
visualization_msgs::MarkerArray makeMarkers(const diekf::FrameResult& result, const std_msgs::Header& header,
                                            double gravity_arrow_m, double plane_size_m);

}  // namespace diekf_ros
