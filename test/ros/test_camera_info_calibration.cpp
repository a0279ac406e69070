// The calibration from sensor_msgs/CameraInfo (diekf/ros/camera_info_calibration.h): the camera model it builds
// projects like OpenCV's own models of the same coefficients (cv::projectPoints for plumb_bob and
// rational_polynomial, cv::fisheye::projectPoints for the equidistant / KANNALA_BRANDT models), and what it cannot
// use is refused naming the field.
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>

#include "diekf/ros/camera_info_calibration.h"

namespace {

sensor_msgs::CameraInfo info(const std::string& model, const std::vector<double>& D) {
  sensor_msgs::CameraInfo m;
  m.width = 752;
  m.height = 480;
  m.distortion_model = model;
  m.D = D;
  m.K = {365.0, 0.0, 376.5, 0.0, 364.0, 241.0, 0.0, 0.0, 1.0};
  return m;
}

/// Points in front of the camera spanning the image (and its corners) at 0.5-3 m.
std::vector<cv::Point3d> points() {
  std::vector<cv::Point3d> p;
  for (double x = -0.9; x <= 0.91; x += 0.15)
    for (double y = -0.6; y <= 0.61; y += 0.15)
      for (double z : {0.5, 1.3, 3.0}) p.emplace_back(x * z, y * z, z);
  return p;
}

/// Largest pixel distance between diekf's projection and OpenCV's.
double maxDifferencePx(const diekf::CameraModel& cam, const std::vector<cv::Point2d>& reference) {
  const std::vector<cv::Point3d> p = points();
  double worst = 0.0;
  for (size_t i = 0; i < p.size(); ++i) {
    diekf::Vec2 px;
    EXPECT_TRUE(cam.project(diekf::Vec3(p[i].x, p[i].y, p[i].z), &px));
    worst = std::max(worst, std::hypot(px.x() - reference[i].x, px.y() - reference[i].y));
  }
  return worst;
}

const cv::Matx33d kK(365.0, 0.0, 376.5, 0.0, 364.0, 241.0, 0.0, 0.0, 1.0);

TEST(CameraInfoCalibration, PlumbBobAndRationalPolynomialProjectLikeOpenCV) {
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  for (const std::vector<double>& D :
       {std::vector<double>{-0.30, 0.09, -1e-4, 3e-4, -0.012},
        std::vector<double>{-0.30, 0.09, -1e-4, 3e-4, 0.0, 0.0, 0.0, 0.0},
        std::vector<double>{0.6, -0.2, 2e-4, -1e-4, 0.03, 0.9, -0.1, 0.05}}) {
    const std::string model = D.size() == 5 ? "plumb_bob" : "rational_polynomial";
    const diekf::CameraModel cam = diekf_ros::cameraModelFromCameraInfo(info(model, D), T, "/cam/camera_info");
    EXPECT_EQ(cam.distortion, diekf::DistortionModel::kRadTan);
    EXPECT_EQ(cam.K.width, 752);
    std::vector<cv::Point2d> ref;
    cv::projectPoints(points(), cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), kK, D, ref);
    const double diff = maxDifferencePx(cam, ref);
    EXPECT_LT(diff, 1e-6) << model << " D[4] " << D[4];
    // Undistortion inverts it (the preprocessing's map uses unproject).
    for (const cv::Point2d& px : ref) {
      diekf::Vec2 xn;
      ASSERT_TRUE(cam.unproject(diekf::Vec2(px.x, px.y), &xn)) << model;
      diekf::Vec2 back;
      ASSERT_TRUE(cam.project(diekf::Vec3(xn.x(), xn.y(), 1.0), &back));
      EXPECT_LT((back - diekf::Vec2(px.x, px.y)).norm(), 1e-6) << model;
    }
  }
}

TEST(CameraInfoCalibration, EquidistantModelsProjectLikeOpenCVFisheye) {
  const std::vector<double> k = {-0.01, 0.02, -0.005, 0.001};
  std::vector<cv::Point2d> ref;
  cv::fisheye::projectPoints(points(), ref, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), kK, k);
  for (const std::string model : {"equidistant", "fisheye", "KANNALA_BRANDT"}) {
    std::vector<double> D = k;
    if (model == "KANNALA_BRANDT") D.push_back(0.0);  // the MYNT EYE driver sends a 5th, zero entry
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(0.02, -0.03, 0.01);
    const diekf::CameraModel cam = diekf_ros::cameraModelFromCameraInfo(info(model, D), T, "/cam/camera_info");
    EXPECT_EQ(cam.distortion, diekf::DistortionModel::kEquidistant);
    EXPECT_TRUE(cam.T_cam_imu.isApprox(T));
    EXPECT_LT(maxDifferencePx(cam, ref), 1e-6) << model;
  }
}

void expectRefused(const sensor_msgs::CameraInfo& m, const std::string& field) {
  try {
    diekf_ros::cameraModelFromCameraInfo(m, Eigen::Isometry3d::Identity(), "/cam/camera_info");
    ADD_FAILURE() << "accepted; expected a complaint about " << field;
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("/cam/camera_info"), std::string::npos) << what;
    EXPECT_NE(what.find(field), std::string::npos) << what;
  }
}

TEST(CameraInfoCalibration, WhatCannotBeUsedIsRefusedNamingTheField) {
  expectRefused(info("unified", {0.1}), "distortion_model");
  expectRefused(info("plumb_bob", {0.1, 0.2}), "D");
  expectRefused(info("rational_polynomial", {0, 0, 0, 0, 0}), "D");
  expectRefused(info("rational_polynomial", {0, 0, 0, 0, 0, 0, 0, 0, 0.01, 0, 0, 0}), "D[8]");
  expectRefused(info("KANNALA_BRANDT", {0.1, 0, 0, 0, 0.3}), "D[4]");
  expectRefused(info("", {0.1, 0, 0, 0, 0}), "D[0]");
  sensor_msgs::CameraInfo m = info("plumb_bob", {0, 0, 0, 0, 0});
  m.K[1] = 0.5;
  expectRefused(m, "skew");
  m = info("plumb_bob", {0, 0, 0, 0, 0});
  m.K[0] = 0.0;  // an uncalibrated driver
  expectRefused(m, "focal");
  m = info("plumb_bob", {0, 0, 0, 0, 0});
  m.binning_x = 2;
  expectRefused(m, "binning");
  m = info("plumb_bob", {0, 0, 0, 0, 0});
  m.roi.x_offset = 10;
  m.roi.width = 100;
  expectRefused(m, "roi");
  m = info("plumb_bob", {0, 0, 0, 0, 0});
  m.width = 0;
  expectRefused(m, "width");
  EXPECT_NO_THROW(diekf_ros::cameraModelFromCameraInfo(info("", {}), Eigen::Isometry3d::Identity(), "x"));
}

}  // namespace
