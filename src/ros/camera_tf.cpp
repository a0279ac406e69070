#include "diekf/ros/camera_tf.h"

#include <algorithm>

#include <geometry_msgs/TransformStamped.h>
#include <tf2/exceptions.h>

#include "diekf/ros/conversions.h"

namespace diekf_ros {

namespace {

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace

std::vector<std::string> frameAncestors(const tf2::BufferCore& buffer, const std::string& frame) {
  std::vector<std::string> chain = {frame};
  std::string parent;
  while (chain.size() < 100 && buffer._frameExists(chain.back()) &&
         buffer._getParent(chain.back(), ros::Time(0), parent) && !parent.empty()) {
    if (contains(chain, parent)) break;  // a cycle (two publishers disagree): stop
    chain.push_back(parent);
  }
  return chain;
}

CameraTfPlan planCameraTf(const tf2::BufferCore& buffer, const std::string& root_mode, const std::string& base_frame,
                          const std::string& odom_frame, const std::string& camera_frame,
                          const Eigen::Isometry3d& T_base_cam, bool waited_enough) {
  CameraTfPlan plan;
  const auto direct = [&](const std::string& why) {
    plan.kind = CameraTfPlan::Kind::kDirect;
    plan.parent = base_frame;
    plan.child = camera_frame;
    plan.T_parent_child = T_base_cam;
    plan.why = why;
    return plan;
  };
  if (root_mode.empty() || root_mode == camera_frame) {
    return direct("camera_tf_root is '" + root_mode + "': " + base_frame + " -> " + camera_frame +
                  " from the calibration");
  }
  const std::vector<std::string> chain = frameAncestors(buffer, camera_frame);
  if (contains(chain, base_frame) || (!odom_frame.empty() && contains(chain, odom_frame))) {
    plan.kind = CameraTfPlan::Kind::kAlreadyConnected;
    plan.why = camera_frame + " is already connected to " + base_frame + " in TF (through " + chain.back() +
               "): no static transform published";
    return plan;
  }
  std::string root;
  if (root_mode == "auto") {
    if (chain.size() < 2) {
      if (waited_enough) {
        return direct("nothing publishes a parent of " + camera_frame + " (no camera driver TF): " + base_frame +
                      " -> " + camera_frame + " from the calibration");
      }
      plan.why = "waiting for the camera driver's TF (a parent of " + camera_frame + ")";
      return plan;
    }
    root = chain.back();
  } else {
    root = root_mode;
    const auto it = std::find(chain.begin(), chain.end(), root);
    if (it == chain.end()) {
      plan.why = "waiting for " + root + " -> " + camera_frame + " in TF (camera_tf_root)";
      return plan;
    }
    if (it + 1 != chain.end()) {
      plan.kind = CameraTfPlan::Kind::kError;
      plan.why = "camera_tf_root " + root + " already has the parent " + *(it + 1) + " in TF: attaching " +
                 base_frame + " to it would give it two parents (set camera_tf_root to auto or to the tree's root " +
                 chain.back() + ")";
      return plan;
    }
  }
  try {
    const Eigen::Isometry3d T_root_cam = isometryFromMsg(buffer.lookupTransform(root, camera_frame, ros::Time(0)).transform);
    plan.kind = CameraTfPlan::Kind::kAttachToRoot;
    plan.parent = base_frame;
    plan.child = root;
    plan.T_parent_child = T_base_cam * T_root_cam.inverse();
    plan.why = base_frame + " -> " + root + " (root of the camera driver's tree, which holds " + camera_frame +
               ") = calibration * TF " + root + " -> " + camera_frame + " inverted";
  } catch (const tf2::TransformException& e) {
    plan.kind = CameraTfPlan::Kind::kWait;
    plan.why = std::string("cannot look up ") + root + " -> " + camera_frame + ": " + e.what();
  }
  return plan;
}

const char* toString(CameraTfPlan::Kind kind) {
  switch (kind) {
    case CameraTfPlan::Kind::kWait:
      return "waiting";
    case CameraTfPlan::Kind::kDirect:
      return "direct";
    case CameraTfPlan::Kind::kAttachToRoot:
      return "attached to the camera driver's tree";
    case CameraTfPlan::Kind::kAlreadyConnected:
      return "already connected";
    case CameraTfPlan::Kind::kError:
    default:
      return "error";
  }
}

}  // namespace diekf_ros
