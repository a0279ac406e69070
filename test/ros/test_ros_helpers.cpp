// Unit tests of the ROS layer's helpers: body-frame odometry, height Jacobian, image and message conversions.
#include <cmath>
#include <limits>
#include <map>
#include <string>

#include <gtest/gtest.h>
#include <boost/make_shared.hpp>
#include <sensor_msgs/image_encodings.h>

#include "diekf/ros/body_odometry.h"
#include "diekf/ros/conversions.h"

namespace {

using diekf::State;
using diekf::Vec3;
using diekf_ros::BodyOdometry;

// Camera looking straight down from a z-up body: camera x = body x, camera y = -body y, camera z = -body z;
// the IMU origin sits 5 cm along the optical axis from the camera (t_CI = (0, 0, 0.05) m).
Eigen::Isometry3d downwardExtrinsics() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  T.translation() = Vec3(0.0, 0.0, 0.05);
  return T;
}

State hoverState(double d_m, const Vec3& v_C_mps, const Vec3& g_C) {
  State x;
  x.alpha = 1.0 / d_m;
  x.vartheta = v_C_mps / d_m;
  x.mu = diekf::UnitVector(Vec3(0.0, 0.0, 1.0));
  x.g = diekf::UnitVector(g_C);
  return x;
}

TEST(HeightAbovePlane, MatchesGeometryAndFiniteDifferenceJacobian) {
  State x;
  x.alpha = 0.5;
  x.mu = diekf::UnitVector(Vec3(0.1, -0.2, 1.0));
  x.g = diekf::UnitVector(Vec3(-0.05, 0.1, 1.0));
  const Vec3 point(0.03, -0.02, 0.05);
  diekf_ros::Row14 J;
  const double h = diekf_ros::heightAbovePlane(x, point, &J);
  const Vec3 mu = x.mu.vector(), g = x.g.vector();
  EXPECT_NEAR(h, (2.0 - mu.dot(point)) / mu.dot(g), 1e-12);
  const double eps = 1e-6;
  for (int i = 0; i < diekf::kErrorDim; ++i) {
    diekf::ErrorVec delta = diekf::ErrorVec::Zero();
    delta(i) = eps;
    const double hp = diekf_ros::heightAbovePlane(x.boxplus(delta), point);
    const double hm = diekf_ros::heightAbovePlane(x.boxplus(-delta), point);
    EXPECT_NEAR(J(i), (hp - hm) / (2.0 * eps), 1e-5) << "column " << i;
  }
}

TEST(BodyOdometry, LevelHoverWithForwardVelocity) {
  BodyOdometry odom(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  const diekf::ErrorCov P = diekf::ErrorCov::Identity() * 1e-4;
  const State x = hoverState(2.0, Vec3(0.5, 0.0, 0.0), Vec3(0.0, 0.0, 1.0));
  for (int k = 0; k <= 30; ++k) {
    const double t = k / 30.0;
    for (int j = 0; j < 17; ++j) odom.addImu(t - 0.033 + j * 0.002, Vec3(0, 0, 9.81), Vec3::Zero());
    odom.addFrame(t, x, P);
  }
  const diekf_ros::BodyPose& pose = odom.framePose();
  EXPECT_NEAR(pose.position_m.x(), 0.5, 1e-9);  // 1 s at 0.5 m/s
  EXPECT_NEAR(pose.position_m.y(), 0.0, 1e-9);
  EXPECT_NEAR(pose.position_m.z(), 1.95, 1e-9);  // camera 2 m up, IMU 5 cm below it
  EXPECT_NEAR(pose.linear_velocity_mps.x(), 0.5, 1e-9);
  EXPECT_NEAR(pose.orientation.angularDistance(Eigen::Quaterniond::Identity()), 0.0, 1e-9);
  EXPECT_GT(pose.pose_covariance(0, 0), 0.0);
  EXPECT_GT(pose.pose_covariance(2, 2), 0.0);
  EXPECT_TRUE(pose.allFinite());
}

TEST(BodyOdometry, RollFromGravityAndYawFromGyro) {
  BodyOdometry odom(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  const diekf::ErrorCov P = diekf::ErrorCov::Identity() * 1e-4;
  // Body rolled by +0.2 rad about x: up in the body frame is (0, sin 0.2, cos 0.2); gravity in C = R_CI * (-up).
  const double roll = 0.2;
  const Vec3 g_I(0.0, -std::sin(roll), -std::cos(roll));
  const Vec3 g_C = downwardExtrinsics().linear() * g_I;
  // Yaw: 1 s at 0.3 rad/s about body z (roll is small, so yaw ~ 0.3 rad).
  odom.addImu(0.0, Vec3::Zero(), Vec3::Zero());
  for (int k = 1; k <= 500; ++k) odom.addImu(k * 0.002, Vec3::Zero(), Vec3(0.0, 0.0, 0.3));
  const diekf_ros::BodyPose& pose = odom.addFrame(1.0, hoverState(1.0, Vec3::Zero(), g_C), P);
  const Eigen::Matrix3d R = pose.orientation.toRotationMatrix();
  const Vec3 ypr = R.eulerAngles(2, 1, 0);
  EXPECT_NEAR(ypr(2), roll, 1e-9);
  EXPECT_NEAR(ypr(1), 0.0, 1e-9);
  EXPECT_NEAR(ypr(0), 0.3, 0.01);
  // Up seen from the body matches the gravity estimate.
  EXPECT_NEAR((R.transpose() * Vec3::UnitZ() + g_I).norm(), 0.0, 1e-9);
}

TEST(BodyOdometry, PredictedPoseFromTheFilterStateBetweenFrames) {
  BodyOdometry odom(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  const diekf::ErrorCov P = diekf::ErrorCov::Identity() * 1e-4;
  odom.addImu(0.0, Vec3(0, 0, 9.81), Vec3::Zero());
  odom.addFrame(0.0, hoverState(1.0, Vec3::Zero(), Vec3(0, 0, 1)), P);
  for (int k = 1; k <= 50; ++k) odom.addImu(k * 0.002, Vec3(0, 0, 9.81), Vec3::Zero());
  // The filter's state predicted to 0.1 s: 0.5 m/s along x, 4 cm higher (camera z points down), larger covariance.
  const diekf::ErrorCov P_pred = diekf::ErrorCov::Identity() * 4e-4;
  const diekf_ros::BodyPose p = odom.predictedPose(0.1, hoverState(1.04, Vec3(0.5, 0.0, 0.0), Vec3(0, 0, 1)), P_pred);
  EXPECT_NEAR(p.t_s, 0.1, 1e-12);
  EXPECT_NEAR(p.position_m.x(), 0.5 * (0.0 + 0.5) * 0.1, 1e-9);  // trapezoid from the frame's velocity
  EXPECT_NEAR(p.position_m.z(), 1.04 - 0.05, 1e-9);
  EXPECT_NEAR(p.linear_velocity_mps.x(), 0.5, 1e-9);
  EXPECT_GT(p.pose_covariance(2, 2), odom.framePose().pose_covariance(2, 2));  // from the predicted covariance
  EXPECT_GT(p.twist_covariance(0, 0), odom.framePose().twist_covariance(0, 0));
  // The frame-rate odometry is unchanged by a prediction.
  EXPECT_NEAR(odom.framePose().position_m.x(), 0.0, 1e-12);
  EXPECT_NEAR(odom.framePose().position_m.z(), 0.95, 1e-12);
  EXPECT_FALSE(odom.addImu(0.1, Vec3::Zero(), Vec3::Zero()));  // non-increasing stamp
}

TEST(BodyOdometry, ZContinuousAcrossRestartsAndGroundSteps) {
  BodyOdometry odom(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  const diekf::ErrorCov P = diekf::ErrorCov::Identity() * 1e-4;
  const Vec3 down(0, 0, 1);
  double t = 0.0;
  const auto frame = [&](double d, double climb_mps, bool usable) {
    t += 1.0 / 30.0;
    odom.addImu(t, Vec3(0, 0, 9.81), Vec3::Zero());
    return odom.addFrame(t, hoverState(d, Vec3(0.0, 0.0, -climb_mps), down), P, usable).position_m.z();
  };
  // Climbing at 0.3 m/s: z follows the height, no step.
  double z = 0.0;
  for (int k = 0; k < 30; ++k) z = frame(1.0 + 0.3 * (k + 1) / 30.0, 0.3, true);
  EXPECT_NEAR(z, 1.3 - 0.05, 1e-9);
  EXPECT_EQ(odom.groundSteps(), 0);
  // A box 0.3 m high under the hovering robot: the height drops in one frame, odom z does not.
  for (int k = 0; k < 5; ++k) z = frame(1.3, 0.0, true);
  const double z_before = z;
  for (int k = 0; k < 5; ++k) z = frame(1.0, 0.0, true);
  EXPECT_NEAR(z, z_before, 1e-9);
  EXPECT_EQ(odom.groundSteps(), 1);
  EXPECT_NEAR(odom.zOffset(), 0.3, 1e-9);
  // A filter restart: re-initializing from the prior (0.33 m) z holds; once it has converged (to 1.05 m), z goes
  // on from where it was.
  odom.restart();
  for (int k = 0; k < 10; ++k) EXPECT_NEAR(frame(0.33 + 0.05 * k, 0.0, false), z_before, 1e-9);
  EXPECT_NEAR(frame(1.05, 0.0, true), z_before, 1e-9);
  EXPECT_NEAR(frame(1.15, 3.0, true), z_before + 0.1, 1e-9);  // then follows the height again (3 m/s: no step)
  // Off: the height itself.
  BodyOdometry plain(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  plain.odom_z_step_m = 0.0;
  plain.addImu(0.0, Vec3(0, 0, 9.81), Vec3::Zero());
  plain.addFrame(0.0, hoverState(1.3, Vec3::Zero(), down), P);
  plain.addImu(0.03, Vec3(0, 0, 9.81), Vec3::Zero());
  EXPECT_NEAR(plain.addFrame(0.03, hoverState(1.0, Vec3::Zero(), down), P).position_m.z(), 0.95, 1e-9);
}

TEST(BodyOdometry, BaseLinkAwayFromTheImu) {
  // base_link 10 cm behind and 5 cm below the IMU, turned by 90 degrees about z: p_base = R p_imu + t.
  Eigen::Isometry3d T_base_imu = Eigen::Isometry3d::Identity();
  T_base_imu.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
  T_base_imu.translation() = Vec3(0.1, 0.0, 0.05);  // the IMU's origin in base_link
  BodyOdometry imu_frame(downwardExtrinsics(), 1e-3, 500.0, 9.81);
  BodyOdometry base(downwardExtrinsics(), 1e-3, 500.0, 9.81, T_base_imu);
  const diekf::ErrorCov P = diekf::ErrorCov::Identity() * 1e-4;
  const State x = hoverState(2.0, Vec3(0.4, 0.0, 0.0), Vec3(0.0, 0.0, 1.0));
  for (BodyOdometry* o : {&imu_frame, &base}) {
    o->addImu(0.0, Vec3(0, 0, 9.81), Vec3::Zero());
    o->addFrame(0.0, x, P);
  }
  const diekf_ros::BodyPose& pi = imu_frame.framePose();
  const diekf_ros::BodyPose& pb = base.framePose();
  const Eigen::Matrix3d R_OB = pb.orientation.toRotationMatrix();
  // The IMU is where T_base_imu puts it, seen from base_link's pose; base_link is 5 cm lower.
  EXPECT_NEAR((pb.position_m + R_OB * T_base_imu.translation() - pi.position_m).norm(), 0.0, 1e-9);
  EXPECT_NEAR(pb.position_m.z(), pi.position_m.z() - 0.05, 1e-9);
  EXPECT_TRUE((R_OB * T_base_imu.linear()).isApprox(pi.orientation.toRotationMatrix(), 1e-9));
  // Same velocity (no rotation), expressed in base_link's axes.
  EXPECT_NEAR((R_OB * pb.linear_velocity_mps - pi.orientation * pi.linear_velocity_mps).norm(), 0.0, 1e-9);
}

TEST(Conversions, ImageEncodingsToMono8) {
  sensor_msgs::Image msg;
  msg.width = 2;
  msg.height = 1;
  msg.encoding = "bgr8";
  msg.step = 6;
  msg.data = {255, 0, 0, 0, 0, 255};  // pure blue, pure red
  cv::Mat out;
  std::string error;
  ASSERT_TRUE(diekf_ros::imageToMono8(msg, &out, &error)) << error;
  ASSERT_EQ(out.type(), CV_8UC1);
  EXPECT_NEAR(out.at<uint8_t>(0, 0), 29, 1);  // 0.114 * 255
  EXPECT_NEAR(out.at<uint8_t>(0, 1), 76, 1);  // 0.299 * 255
  msg.encoding = "rgb8";
  ASSERT_TRUE(diekf_ros::imageToMono8(msg, &out, &error));
  EXPECT_NEAR(out.at<uint8_t>(0, 0), 76, 1);

  msg.encoding = "mono16";
  msg.step = 4;
  msg.data = {0x00, 0x80, 0xff, 0xff};  // little endian 32768, 65535
  ASSERT_TRUE(diekf_ros::imageToMono8(msg, &out, &error)) << error;
  EXPECT_EQ(out.at<uint8_t>(0, 0), 128);
  EXPECT_EQ(out.at<uint8_t>(0, 1), 255);

  msg.encoding = "bayer_rggb8";
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  EXPECT_NE(error.find("bayer_rggb8"), std::string::npos);

  msg.encoding = "mono8";
  msg.step = 2;
  msg.data = {1};  // too short
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
}

TEST(Conversions, MalformedImagesRejectedWithReason) {
  sensor_msgs::Image msg;
  msg.width = 4;
  msg.height = 2;
  msg.encoding = "mono16";
  msg.step = 9;  // not a multiple of 2 bytes
  msg.data.assign(18, 7);
  cv::Mat out;
  std::string error;
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  EXPECT_NE(error.find("step"), std::string::npos) << error;
  msg.step = 6;  // below width * 2
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  msg.step = 10;  // padded rows are fine
  msg.data.assign(20, 0);
  msg.data[10] = 0;
  msg.data[11] = 0x80;  // row 1, column 0 = 32768
  ASSERT_TRUE(diekf_ros::imageToMono8(msg, &out, &error)) << error;
  EXPECT_EQ(out.at<uint8_t>(1, 0), 128);
  msg.is_bigendian = 1;
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  msg = sensor_msgs::Image();
  msg.encoding = "mono8";  // empty: no size, no data
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  msg.width = 3;
  msg.height = 3;
  msg.step = 3;
  msg.data.assign(8, 0);  // one byte short
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  msg.encoding = "";
  msg.data.assign(9, 0);
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  msg.encoding = "32FC1";
  EXPECT_FALSE(diekf_ros::imageToMono8(msg, &out, &error));
  EXPECT_NE(error.find("32FC1"), std::string::npos);
}

TEST(Conversions, ImageViewSharesTheMessageBuffer) {
  // The nodelet's image path: the message's pixels are wrapped, not copied (cv_bridge::toCvShare), for every
  // encoding; the one grey conversion happens in Estimator::addImage (diekf::toGrey8).
  for (const char* encoding : {"mono8", "8UC1", "mono16", "bgr8", "rgb8", "bgra8", "rgba8"}) {
    auto msg = boost::make_shared<sensor_msgs::Image>();
    msg->encoding = encoding;
    msg->width = 3;
    msg->height = 2;
    const int bytes = sensor_msgs::image_encodings::bitDepth(encoding) / 8 *
                      sensor_msgs::image_encodings::numChannels(encoding);
    msg->step = 3 * bytes + 4;  // padded rows
    msg->data.assign(msg->step * 2, 0);
    for (size_t i = 0; i < msg->data.size(); ++i) msg->data[i] = static_cast<uint8_t>(i * 7);
    cv_bridge::CvImageConstPtr view;
    diekf::ChannelOrder order;
    std::string error;
    ASSERT_TRUE(diekf_ros::imageView(msg, &view, &order, &error)) << encoding << ": " << error;
    EXPECT_EQ(view->image.data, msg->data.data()) << encoding << ": copied";
    EXPECT_EQ(static_cast<size_t>(view->image.step), msg->step) << encoding;
    EXPECT_EQ(view->image.cols, 3);
    EXPECT_EQ(order == diekf::ChannelOrder::kRgb, std::string(encoding).find("rgb") == 0) << encoding;
    // Same grey as the copying conversion.
    cv::Mat grey, through_view;
    ASSERT_TRUE(diekf_ros::imageToMono8(*msg, &grey, &error)) << error;
    ASSERT_TRUE(diekf::toGrey8(view->image, order, &through_view));
    EXPECT_EQ(cv::norm(grey, through_view, cv::NORM_INF), 0.0) << encoding;
  }
  auto bad = boost::make_shared<sensor_msgs::Image>();
  bad->encoding = "yuv422";
  bad->width = bad->height = 2;
  bad->step = 4;
  bad->data.assign(8, 0);
  cv_bridge::CvImageConstPtr view;
  diekf::ChannelOrder order;
  std::string error;
  EXPECT_FALSE(diekf_ros::imageView(bad, &view, &order, &error));
  EXPECT_NE(error.find("yuv422"), std::string::npos) << error;
}

TEST(Conversions, ClockJumpRestartsOnlyOnce) {
  // Looping bag: sim time goes from 1600000060 back to 1600000000 while the newest stamp is still at 60 s.
  EXPECT_TRUE(diekf_ros::clockJumpNeedsRestart(1600000060.0, 1600000000.0, 1600000059.99, 1.0));
  // The stamps jumped first (their own restart): the clock following them must not restart again.
  EXPECT_FALSE(diekf_ros::clockJumpNeedsRestart(1600000060.0, 1600000000.0, 1600000000.02, 1.0));
  // Small jitter backwards, forward time, the first call (previous 0), a zero clock (sim time not yet set).
  EXPECT_FALSE(diekf_ros::clockJumpNeedsRestart(100.0, 99.5, 100.0, 1.0));
  EXPECT_FALSE(diekf_ros::clockJumpNeedsRestart(100.0, 160.0, 100.0, 1.0));
  EXPECT_FALSE(diekf_ros::clockJumpNeedsRestart(0.0, 100.0, -1.0, 1.0));
  EXPECT_FALSE(diekf_ros::clockJumpNeedsRestart(100.0, 0.0, 100.0, 1.0));
}

TEST(Conversions, PlanarStateRejectsNonFinite) {
  diekf::FrameResult r;
  r.state = hoverState(2.0, Vec3(0.1, 0.2, 0.0), Vec3(0, 0, 1));
  r.covariance = diekf::ErrorCov::Identity() * 1e-3;
  r.status = diekf::FilterStatus::kTracking;
  std_msgs::Header header;
  header.frame_id = "cam";
  diekf::PlanarState msg;
  ASSERT_TRUE(diekf_ros::fillPlanarState(r, header, &msg));
  EXPECT_NEAR(msg.distance, 2.0, 1e-12);
  EXPECT_NEAR(msg.height, 2.0, 1e-12);
  EXPECT_NEAR(msg.velocity.y, 0.2, 1e-12);
  EXPECT_EQ(msg.status, diekf::PlanarState::STATUS_TRACKING);
  EXPECT_NEAR(msg.sigma_distance, std::sqrt(1e-3) * 4.0, 1e-9);  // sigma_alpha / alpha^2
  r.state.vartheta.x() = std::numeric_limits<double>::quiet_NaN();
  diekf::PlanarState untouched;
  EXPECT_FALSE(diekf_ros::fillPlanarState(r, header, &untouched));
  EXPECT_TRUE(untouched.header.frame_id.empty());
}

TEST(Conversions, CameraInfoCheck) {
  diekf::CameraModel cam;
  cam.K.fx = 400;
  cam.K.fy = 400;
  cam.K.cx = 376;
  cam.K.cy = 240;
  cam.K.width = 752;
  cam.K.height = 480;
  cam.distortion = diekf::DistortionModel::kRadTan;
  cam.distortion_coeffs = diekf::Vec4(-0.1, 0.01, 0.0, 0.0);
  sensor_msgs::CameraInfo info;
  info.width = 752;
  info.height = 480;
  info.K = {400, 0, 376, 0, 400, 240, 0, 0, 1};
  info.distortion_model = "plumb_bob";
  info.D = {-0.1, 0.01, 0.0, 0.0, 0.0};
  std::string why;
  EXPECT_TRUE(diekf_ros::cameraInfoAgrees(info, cam, &why)) << why;
  info.K[0] = 450;
  info.D[1] = 0.05;
  EXPECT_FALSE(diekf_ros::cameraInfoAgrees(info, cam, &why));
  EXPECT_NE(why.find("fx"), std::string::npos);
  EXPECT_NE(why.find("D[1]"), std::string::npos);
}

TEST(Conversions, ResidualPicture) {
  cv::Mat r(1, 3, CV_32FC1);
  r.at<float>(0, 0) = 0.0f;
  r.at<float>(0, 1) = 1.0f;
  r.at<float>(0, 2) = -10.0f;
  const cv::Mat p = diekf_ros::residualToMono8(r, 64.0);
  EXPECT_EQ(p.at<uint8_t>(0, 0), 128);
  EXPECT_EQ(p.at<uint8_t>(0, 1), 192);
  EXPECT_EQ(p.at<uint8_t>(0, 2), 0);
}

TEST(Conversions, ResidualPictureShowsTheOutlierWeights) {
  cv::Mat r(1, 3, CV_32FC1, cv::Scalar(1.0f));
  cv::Mat w(1, 3, CV_32FC1);
  w.at<float>(0, 0) = 1.0f;   // kept: the grey residual
  w.at<float>(0, 1) = 0.0f;   // removed: red
  w.at<float>(0, 2) = 0.5f;   // half
  const cv::Mat p = diekf_ros::residualPicture(r, w, 64.0);
  ASSERT_EQ(p.type(), CV_8UC3);
  EXPECT_EQ(p.at<cv::Vec3b>(0, 0), cv::Vec3b(192, 192, 192));
  EXPECT_EQ(p.at<cv::Vec3b>(0, 1), cv::Vec3b(0, 0, 255));
  EXPECT_EQ(p.at<cv::Vec3b>(0, 2), cv::Vec3b(96, 96, 224));
  // Without weights (or of another size): the grey residual.
  EXPECT_EQ(diekf_ros::residualPicture(r, cv::Mat(), 64.0).at<cv::Vec3b>(0, 1), cv::Vec3b(192, 192, 192));
}

TEST(Conversions, MarkersShowTheEstimatedGeometry) {
  diekf::FrameResult r;
  r.state.alpha = 1.0 / 0.8;
  r.state.vartheta = Vec3(0.3, 0.0, 0.0) / 0.8;
  r.state.mu = diekf::UnitVector(Vec3(0.2, -0.1, 1.0));
  r.state.g = diekf::UnitVector(Vec3(0.0, 0.1, 1.0));
  r.status = diekf::FilterStatus::kTracking;
  std_msgs::Header header;
  header.frame_id = "cam";
  const visualization_msgs::MarkerArray a = diekf_ros::makeMarkers(r, header, 0.5, 2.0);
  std::map<std::string, visualization_msgs::Marker> by_ns;
  for (const auto& m : a.markers) {
    EXPECT_EQ(m.header.frame_id, "cam");
    EXPECT_TRUE(by_ns.emplace(m.ns, m).second) << "namespace " << m.ns << " used twice";
  }
  ASSERT_EQ(by_ns.size(), 6u);
  const Vec3 mu = r.state.mu.vector(), g = r.state.g.vector();
  auto end = [](const visualization_msgs::Marker& m) {
    return Vec3(m.points.back().x, m.points.back().y, m.points.back().z);
  };
  EXPECT_LT((end(by_ns.at("normal")) - 0.8 * mu).norm(), 1e-9);   // camera -> plane, length d
  EXPECT_LT((end(by_ns.at("gravity")) - 0.5 * g).norm(), 1e-9);   // fixed length
  EXPECT_LT((end(by_ns.at("velocity")) - Vec3(0.3, 0, 0)).norm(), 1e-9);
  EXPECT_NEAR(mu.dot(end(by_ns.at("height"))), 0.8, 1e-9);       // the height line ends on the plane
  EXPECT_NEAR(end(by_ns.at("height")).norm(), r.state.height_m(), 1e-9);
  const auto& plane = by_ns.at("plane");
  EXPECT_NEAR(mu.dot(Vec3(plane.pose.position.x, plane.pose.position.y, plane.pose.position.z)), 0.8, 1e-9);
  const std::string& label = by_ns.at("label").text;
  EXPECT_NE(label.find("tracking"), std::string::npos) << label;
  EXPECT_NE(label.find("d 0.80 m"), std::string::npos) << label;
  EXPECT_NE(label.find("+- 0.00 m"), std::string::npos) << label;  // zero covariance
  r.state.alpha = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(diekf_ros::makeMarkers(r, header, 0.5, 2.0).markers.empty());
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
