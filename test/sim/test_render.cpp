// Renderer geometry: a rendered texture point lands where CameraModel::project puts it.
#include <gtest/gtest.h>

#include <cmath>

#include "diekf/sim/renderer.h"
#include "diekf/sim/sequence_io.h"
#include "blob_texture.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

using simtest::blobTexture;
using simtest::blobWorld;

/// Camera pose looking down (optical axis -z_W) from `height` above the blob, offset so that the blob appears
/// at normalised undistorted image coordinates (xn, yn), with an extra tilt.
CameraPose poseSeeing(const Eigen::Vector3d& X, double height, double xn, double yn, double tilt_rad) {
  CameraPose P;
  // C axes in W: x_C = x_W, y_C = -y_W, z_C = -z_W, then tilted about x_W.
  Eigen::Matrix3d R;
  R << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  P.R_WC = Eigen::AngleAxisd(tilt_rad, Eigen::Vector3d::UnitX()).toRotationMatrix() * R;
  // Want X = p + d * R_WC (xn, yn, 1): choose the depth d so the camera is `height` above X along z_W.
  const Eigen::Vector3d r_W = P.R_WC * Eigen::Vector3d(xn, yn, 1.0);
  const double d = height / -r_W.z();
  P.p_WC = X - d * r_W;
  return P;
}

/// Intensity-weighted centroid of (I - background) in a window around `c`.
Vec2 centroid(const cv::Mat& img, const Vec2& c, int half, double background) {
  double sw = 0, sx = 0, sy = 0;
  for (int v = static_cast<int>(std::round(c.y())) - half; v <= static_cast<int>(std::round(c.y())) + half; ++v)
    for (int u = static_cast<int>(std::round(c.x())) - half; u <= static_cast<int>(std::round(c.x())) + half; ++u) {
      if (u < 0 || v < 0 || u >= img.cols || v >= img.rows) continue;
      const double w = std::max(0.0, img.at<unsigned char>(v, u) - background);
      sw += w;
      sx += w * u;
      sy += w * v;
    }
  return sw > 0 ? Vec2(sx / sw, sy / sw) : Vec2(-1, -1);
}

void checkBlob(const Renderer& r, const Plane& plane, const CameraPose& P, double tol_px) {
  const Texture tex = blobTexture(1.3);
  SensorOptions so;
  so.noise = false;
  so.vignetting = 0.0;
  const cv::Mat img = r.renderImage({P}, plane, tex, 1.0, so, 0);
  const Eigen::Vector3d X = blobWorld(plane);
  Vec2 px;
  ASSERT_TRUE(r.camera().project(P.R_WC.transpose() * (X - P.p_WC), &px));
  ASSERT_GT(px.x(), 4);
  ASSERT_GT(px.y(), 4);
  ASSERT_LT(px.x(), img.cols - 5);
  ASSERT_LT(px.y(), img.rows - 5);
  const Vec2 c = centroid(img, px, 4, 20.0);
  EXPECT_NEAR(c.x(), px.x(), tol_px) << "projected " << px.transpose();
  EXPECT_NEAR(c.y(), px.y(), tol_px) << "projected " << px.transpose();
  // The blob is bright where it should be and the background is the dark texture level.
  EXPECT_GT(img.at<unsigned char>(static_cast<int>(std::round(px.y())), static_cast<int>(std::round(px.x()))), 60);
  const Vec2 far = px + Vec2(px.x() < img.cols / 2 ? 3.5 : -3.5, 0) * 2;
  EXPECT_NEAR(img.at<unsigned char>(static_cast<int>(far.y()), static_cast<int>(far.x())), 20, 2);
}

}  // namespace

TEST(Renderer, BlobLandsAtProjectionLevelPlane) {
  const CameraModel cam = myntEyeSimCamera(0.25);  // 188 x 120
  const Renderer r(cam, 2);
  const Plane plane;  // level ground
  const Eigen::Vector3d X = blobWorld(plane);
  // Centre, and towards the corners where the radtan distortion is strong.
  const double pts[][2] = {{0.0, 0.0}, {0.8, 0.5}, {-0.9, -0.55}, {0.95, -0.55}, {-0.6, 0.5}};
  for (const auto& p : pts) {
    SCOPED_TRACE(::testing::Message() << "xn " << p[0] << " yn " << p[1]);
    checkBlob(r, plane, poseSeeing(X, 0.5, p[0], p[1], 0.0), 0.15);
  }
}

TEST(Renderer, BlobLandsAtProjectionInclinedPlaneAndTiltedCamera) {
  const CameraModel cam = myntEyeSimCamera(0.25);
  const Renderer r(cam, 1);
  const Plane plane = Plane::inclined(20.0, 30.0);
  const Eigen::Vector3d X = blobWorld(plane);
  checkBlob(r, plane, poseSeeing(X, 0.6, 0.3, -0.2, 0.25), 0.15);
  checkBlob(r, plane, poseSeeing(X, 0.6, -0.7, 0.4, -0.2), 0.15);
}

TEST(Renderer, RayTableInvertsDistortion) {
  const CameraModel cam = myntEyeSimCamera(0.25);
  const Renderer r(cam, 1);
  for (int v = 0; v < r.height(); v += 7)
    for (int u = 0; u < r.width(); u += 11) {
      Vec2 px;
      ASSERT_TRUE(cam.project(r.ray(u, v), &px));
      EXPECT_NEAR(px.x(), u, 1e-3);  // the table is float
      EXPECT_NEAR(px.y(), v, 1e-3);
    }
}

TEST(Renderer, MipmapKeepsDistantCheckerboardGrey) {
  // Seen from far away, a checkerboard must average out (no aliasing): rendered pixels near the mean grey.
  const CameraModel cam = myntEyeSimCamera(0.125);
  const Renderer r(cam, 1);
  const Texture tex = Texture::checkerboard(0.05, 16, 16, 40.f, 200.f);
  CameraPose P;
  P.R_WC << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  P.p_WC = Eigen::Vector3d(0.013, 0.021, 20.0);  // 20 m up: ~0.9 m per pixel, 18 squares per pixel
  SensorOptions so;
  so.noise = false;
  so.vignetting = 0.0;
  const cv::Mat img = r.renderImage({P}, Plane(), tex, 1.0, so, 0);
  double mn = 255, mx = 0;
  cv::minMaxLoc(img, &mn, &mx);
  EXPECT_GT(mn, 110);
  EXPECT_LT(mx, 130);
  // And from 0.3 m the same texture shows full contrast.
  P.p_WC.z() = 0.3;
  const cv::Mat near = r.renderImage({P}, Plane(), tex, 1.0, so, 0);
  cv::minMaxLoc(near, &mn, &mx);
  EXPECT_LT(mn, 50);
  EXPECT_GT(mx, 190);
}

TEST(Renderer, MotionBlurAveragesSubframes) {
  const CameraModel cam = myntEyeSimCamera(0.125);
  const Renderer r(cam, 1);
  const Texture tex = Texture::checkerboard(0.05, 16, 16, 40.f, 200.f);
  CameraPose a;
  a.R_WC << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  a.p_WC = Eigen::Vector3d(0.0, 0.0, 0.5);
  CameraPose b = a;
  b.p_WC.x() += 0.05;  // one square: the average of a and b is uniform grey in the middle
  std::vector<float> ra, rb, rab;
  r.renderRadiance({a}, Plane(), tex, &ra);
  r.renderRadiance({b}, Plane(), tex, &rb);
  r.renderRadiance({a, b}, Plane(), tex, &rab);
  for (std::size_t i = 0; i < ra.size(); i += 13) EXPECT_NEAR(rab[i], 0.5f * (ra[i] + rb[i]), 1e-3f);
  EXPECT_GT(r.motionPixels(a, b, Plane()), 0.05 / 0.5 * cam.K.fx * 0.8);
}
