// The calibration from a camera driver's sensor_msgs/CameraInfo and the TF extrinsics, for when no Kalibr camchain
// is given (the camchain stays the first choice; docs/ros.md, "Calibration").
#pragma once

#include <string>

#include <Eigen/Geometry>
#include <sensor_msgs/CameraInfo.h>

#include "diekf/camera_model.h"

namespace diekf_ros {

/// CameraModel of the raw (unrectified) image from a CameraInfo: K (no skew), size, and the distortion:
///  - plumb_bob: D = [k1 k2 p1 p2 (k3)] -> radtan, k3 in radial_extra;
///  - rational_polynomial: D = [k1 k2 p1 p2 k3 k4 k5 k6] (further thin-prism/tilt terms must be zero);
///  - equidistant, fisheye, KANNALA_BRANDT (the MYNT EYE driver's name): D = [k1 k2 k3 k4] (a 5th entry must
///    be zero) -> equidistant;
///  - "" or none: D empty or all zero.
/// T_cam_imu: p_C = T_cam_imu p_I (from TF: the transform from the IMU's frame into the camera's). Throws
/// std::runtime_error naming the field (and `topic`) when the message cannot be used: unknown model, wrong D
/// length, skew, binning or a region of interest, non-positive focal lengths.
diekf::CameraModel cameraModelFromCameraInfo(const sensor_msgs::CameraInfo& info, const Eigen::Isometry3d& T_cam_imu,
                                             const std::string& topic);

}  // namespace diekf_ros
