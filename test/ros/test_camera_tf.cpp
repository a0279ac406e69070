// Where base_link -> camera goes in the TF tree (diekf/ros/camera_tf.h), on a tf2 buffer filled by hand with the
// MYNT EYE S driver's static tree (mynteye_link -> mynteye_left_frame -> right, IMU, ... frames).
#include <string>

#include <geometry_msgs/TransformStamped.h>
#include <gtest/gtest.h>
#include <tf2/buffer_core.h>

#include "diekf/ros/camera_tf.h"

namespace {

using diekf_ros::CameraTfPlan;
using diekf_ros::planCameraTf;

Eigen::Isometry3d pose(double rx, double ry, double rz, double x, double y, double z) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(rz, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rx, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

void add(tf2::BufferCore* buffer, const std::string& parent, const std::string& child, const Eigen::Isometry3d& T,
         bool is_static = true) {
  geometry_msgs::TransformStamped t;
  t.header.stamp = ros::Time(100.0);
  t.header.frame_id = parent;
  t.child_frame_id = child;
  t.transform.translation.x = T.translation().x();
  t.transform.translation.y = T.translation().y();
  t.transform.translation.z = T.translation().z();
  const Eigen::Quaterniond q(T.linear());
  t.transform.rotation.w = q.w();
  t.transform.rotation.x = q.x();
  t.transform.rotation.y = q.y();
  t.transform.rotation.z = q.z();
  ASSERT_TRUE(buffer->setTransform(t, "test", is_static));
}

// The driver's tree; mynteye_link -> left is not the identity here, so that the composition is checked.
void addDriverTree(tf2::BufferCore* buffer, const Eigen::Isometry3d& T_link_left) {
  add(buffer, "mynteye_link", "mynteye_left_frame", T_link_left);
  add(buffer, "mynteye_left_frame", "mynteye_right_frame", pose(0, 0, 0, 0.12, 0, 0));
  add(buffer, "mynteye_left_frame", "camera_imu_frame", pose(0.01, 0.02, 1.57, 0.02, -0.03, -0.01));
  add(buffer, "mynteye_right_frame", "mynteye_right_rect_frame", Eigen::Isometry3d::Identity());
}

const Eigen::Isometry3d kTBaseCam = pose(3.1, 0.02, -1.55, 0.035, -0.02, -0.012);

TEST(CameraTf, NoDriverTreePublishesBaseToCameraAfterTheWait) {
  tf2::BufferCore buffer;
  CameraTfPlan p = planCameraTf(buffer, "auto", "base_link", "odom", "mynteye_left_frame", kTBaseCam, false);
  EXPECT_EQ(p.kind, CameraTfPlan::Kind::kWait) << p.why;
  p = planCameraTf(buffer, "auto", "base_link", "odom", "mynteye_left_frame", kTBaseCam, true);
  ASSERT_EQ(p.kind, CameraTfPlan::Kind::kDirect) << p.why;
  EXPECT_EQ(p.parent, "base_link");
  EXPECT_EQ(p.child, "mynteye_left_frame");
  EXPECT_TRUE(p.T_parent_child.isApprox(kTBaseCam, 1e-12));
  // "" never waits.
  p = planCameraTf(buffer, "", "base_link", "odom", "mynteye_left_frame", kTBaseCam, false);
  EXPECT_EQ(p.kind, CameraTfPlan::Kind::kDirect) << p.why;
}

TEST(CameraTf, AttachesBaseLinkToTheDriversRoot) {
  tf2::BufferCore buffer;
  const Eigen::Isometry3d T_link_left = pose(0.1, -0.2, 0.3, 0.01, 0.02, 0.03);
  addDriverTree(&buffer, T_link_left);
  add(&buffer, "odom", "base_link", pose(0, 0, 0.5, 1, 2, 0.8), false);  // our own odometry does not matter
  for (const std::string mode : {"auto", "mynteye_link"}) {
    const CameraTfPlan p = planCameraTf(buffer, mode, "base_link", "odom", "mynteye_left_frame", kTBaseCam, false);
    ASSERT_EQ(p.kind, CameraTfPlan::Kind::kAttachToRoot) << mode << ": " << p.why;
    EXPECT_EQ(p.parent, "base_link");
    EXPECT_EQ(p.child, "mynteye_link");
    // base -> link -> left must equal the calibration's base -> camera.
    EXPECT_TRUE((p.T_parent_child * T_link_left).isApprox(kTBaseCam, 1e-9)) << mode;
  }
  // The ancestors of the right camera's rectified frame end at the driver's root.
  const std::vector<std::string> chain = diekf_ros::frameAncestors(buffer, "mynteye_right_rect_frame");
  ASSERT_EQ(chain.size(), 4u);
  EXPECT_EQ(chain.back(), "mynteye_link");
}

TEST(CameraTf, AFrameThatAlreadyHasAParentIsRefused) {
  tf2::BufferCore buffer;
  addDriverTree(&buffer, Eigen::Isometry3d::Identity());
  // Asking to attach to the camera frame's parent's child (the left frame has the parent mynteye_link).
  const CameraTfPlan p =
      planCameraTf(buffer, "mynteye_right_frame", "base_link", "odom", "mynteye_right_rect_frame", kTBaseCam, true);
  EXPECT_EQ(p.kind, CameraTfPlan::Kind::kError) << p.why;
  EXPECT_NE(p.why.find("mynteye_link"), std::string::npos) << "names the tree's root: " << p.why;
  // An explicit frame that is not in TF yet: wait (also when the auto wait is over).
  const CameraTfPlan q = planCameraTf(buffer, "other_link", "base_link", "odom", "mynteye_left_frame", kTBaseCam, true);
  EXPECT_EQ(q.kind, CameraTfPlan::Kind::kWait) << q.why;
}

TEST(CameraTf, NothingWhenBaseLinkIsAlreadyConnected) {
  // A robot description that already holds base_link -> mynteye_link (robot_state_publisher).
  tf2::BufferCore buffer;
  addDriverTree(&buffer, Eigen::Isometry3d::Identity());
  add(&buffer, "base_link", "mynteye_link", pose(0, 0, 0, 0, 0, -0.05));
  add(&buffer, "odom", "base_link", Eigen::Isometry3d::Identity(), false);
  const CameraTfPlan p = planCameraTf(buffer, "auto", "base_link", "odom", "mynteye_left_frame", kTBaseCam, false);
  EXPECT_EQ(p.kind, CameraTfPlan::Kind::kAlreadyConnected) << p.why;
}

}  // namespace
