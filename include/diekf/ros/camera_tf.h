// Where the static transform between base_link and the camera goes in the TF tree (docs/ros.md, "TF tree").
//
// A camera driver usually publishes its own small tree: the MYNT EYE S wrapper publishes mynteye_link ->
// mynteye_left_frame (identity) and mynteye_left_frame -> its right, rectified, depth and IMU frames. Publishing
// base_link -> mynteye_left_frame next to it would give the camera frame two parents, so diekf attaches base_link
// to the root of the driver's tree instead: base_link -> mynteye_link = T_base_cam * T_root_cam^-1, with T_base_cam
// from the calibration and T_root_cam read from TF. Only when nothing publishes a parent of the camera frame (a
// bag without the driver's /tf_static) does diekf publish base_link -> camera itself.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <tf2/buffer_core.h>

namespace diekf_ros {

/// What to publish (or not) to connect base_frame to camera_frame.
struct CameraTfPlan {
  enum class Kind {
    kWait,              ///< not decided yet (TF incomplete); try again later
    kDirect,            ///< publish base_frame -> camera_frame
    kAttachToRoot,      ///< publish base_frame -> `child` (the root of the camera driver's tree)
    kAlreadyConnected,  ///< base_frame and camera_frame are already connected by someone else: publish nothing
    kError,             ///< cannot be done as configured (e.g. the chosen frame already has a parent)
  };
  Kind kind = Kind::kWait;
  std::string parent, child;                                       ///< of the transform to publish
  Eigen::Isometry3d T_parent_child = Eigen::Isometry3d::Identity();  ///< p_parent = T p_child
  std::string why;                                                 ///< human-readable reason (logs, diagnostics)
};

/// `frame` and its ancestors in `buffer`, the frame first and the root last (latest transforms). Stops at a cycle.
std::vector<std::string> frameAncestors(const tf2::BufferCore& buffer, const std::string& frame);

/// Decides the static transform that connects base_frame to camera_frame.
///  root_mode "": always base_frame -> camera_frame (no camera driver TF).
///  root_mode "auto": attach base_frame to the root of the tree that holds camera_frame once TF shows a parent
///    of camera_frame; base_frame -> camera_frame when nothing has published one by the time `waited_enough`
///    is true; nothing when base_frame (or odom_frame) is already an ancestor of camera_frame.
///  root_mode FRAME: attach base_frame to FRAME (waiting for FRAME -> camera_frame in TF); an error when FRAME
///    already has a parent.
/// T_base_cam: pose of the camera in base_frame (p_base = T_base_cam p_cam) from the calibration.
CameraTfPlan planCameraTf(const tf2::BufferCore& buffer, const std::string& root_mode, const std::string& base_frame,
                          const std::string& odom_frame, const std::string& camera_frame,
                          const Eigen::Isometry3d& T_base_cam, bool waited_enough);

const char* toString(CameraTfPlan::Kind kind);

}  // namespace diekf_ros
