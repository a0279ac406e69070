// Realistic-camera effects: rolling shutter, image time offset, calibration errors in the written camchain,
// defocus, exposure steps, view-dependent glossy patches and the --realism preset.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <cstring>
#include <filesystem>
#include <map>
#include <vector>

#include <opencv2/core/persistence.hpp>
#include <opencv2/imgproc.hpp>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <yaml-cpp/yaml.h>

#include "diekf/camera_model.h"
#include "diekf/sim/realism.h"
#include "diekf/sim/renderer.h"
#include "diekf/sim/sequence_io.h"
#include "blob_texture.h"
#include "diekf/sim/simulator.h"
#include "test_util.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

using simtest::blobTexture;
using simtest::blobWorld;

/// Camera looking straight down (x_C = x_W, y_C = -y_W, z_C = -z_W).
Eigen::Matrix3d downward() {
  Eigen::Matrix3d R;
  R << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  return R;
}

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

SensorOptions noiseless() {
  SensorOptions so;
  so.noise = false;
  so.vignetting = 0.0;
  return so;
}

bool sameImage(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

double gradientEnergy(const cv::Mat& img) {
  cv::Mat gx, gy;
  cv::Sobel(img, gx, CV_32F, 1, 0);
  cv::Sobel(img, gy, CV_32F, 0, 1);
  const cv::Rect inner(4, 4, img.cols - 8, img.rows - 8);
  return cv::sum(gx(inner).mul(gx(inner)))[0] + cv::sum(gy(inner).mul(gy(inner)))[0];
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------
// Rolling shutter

TEST(RealismRender, RollingShutterShearsASidewaysTranslation) {
  const CameraModel cam = myntEyeSimCamera(0.25);  // 188 x 120
  const Renderer r(cam, 2);
  const Texture tex = blobTexture(1.5);
  const Plane plane;
  const Eigen::Vector3d X = blobWorld(plane);
  const double h = 0.5, speed = 1.0, readout = 0.040;  // camera moves along x_W (image u) at 1 m/s
  const SensorOptions so = noiseless();
  std::vector<double> shifts;
  for (const double yn : {-0.45, 0.45}) {  // blob near the top, then near the bottom of the image
    SCOPED_TRACE(::testing::Message() << "yn " << yn);
    CameraPose P0;
    P0.R_WC = downward();
    P0.p_WC = X - h * P0.R_WC * Eigen::Vector3d(0.0, yn, 1.0);
    const auto pose_at = [&](double t) {
      CameraPose P = P0;
      P.p_WC.x() += speed * t;
      return P;
    };
    const cv::Mat gs = r.renderImage({pose_at(0.0)}, plane, tex, 1.0, so, 0);
    const cv::Mat rs =
        r.renderBands(rollingShutterBands(pose_at, 0.0, r.height(), readout, 0.0, 1), plane, tex, 1.0, so, 0);
    // Expected: where the blob projects with the pose of the row that sees it (fixed point over the row time).
    Vec2 px_gs, px_rs;
    ASSERT_TRUE(cam.project(P0.R_WC.transpose() * (X - P0.p_WC), &px_gs));
    px_rs = px_gs;
    for (int it = 0; it < 10; ++it) {
      const double t_row = readout * (px_rs.y() / (r.height() - 1) - 0.5);
      const CameraPose P = pose_at(t_row);
      ASSERT_TRUE(cam.project(P.R_WC.transpose() * (X - P.p_WC), &px_rs));
    }
    const Vec2 c_gs = centroid(gs, px_gs, 5, 20.0), c_rs = centroid(rs, px_rs, 5, 20.0);
    EXPECT_NEAR(c_gs.x(), px_gs.x(), 0.15);
    EXPECT_NEAR(c_rs.x(), px_rs.x(), 0.15);
    EXPECT_NEAR(c_rs.y(), px_rs.y(), 0.15);
    shifts.push_back(c_rs.x() - c_gs.x());
    // Sign: rows below the middle are exposed later, the camera is further along +x_W, the ground moves to -u.
    EXPECT_LT((px_rs.x() - px_gs.x()) * yn, 0.0);
  }
  // Shear: the top and bottom rows are displaced against each other by ~ fx v dt / h (minus distortion).
  const double dt = readout * 0.9 * 0.8;  // the two blobs are ~0.8 of the height apart (approximately)
  EXPECT_GT(shifts[0] - shifts[1], 0.5 * cam.K.fx * speed * dt / h);
  EXPECT_GT(shifts[0] - shifts[1], 2.5);  // pixels
}

TEST(RealismRender, ZeroReadoutAndUniformBandsAreBitIdentical) {
  const CameraModel cam = myntEyeSimCamera(0.25);
  const Renderer r(cam, 2);
  const Texture tex = Texture::natural(3, 0.004, 256);
  const Plane plane = Plane::inclined(10.0, 20.0);
  CameraPose P0;
  P0.R_WC = Eigen::AngleAxisd(0.1, Eigen::Vector3d(1, 2, 0).normalized()).toRotationMatrix() * downward();
  P0.p_WC = Eigen::Vector3d(0.1, 0.2, 0.7);
  const auto pose_at = [&](double t) {
    CameraPose P = P0;
    P.p_WC += Eigen::Vector3d(0.8, -0.5, 0.1) * t;
    return P;
  };
  SensorOptions so;  // with noise and vignetting: the whole sensor path
  const double t = 0.3, exposure = 0.004;
  const int n_sub = 3;
  std::vector<CameraPose> sub;
  for (int j = 0; j < n_sub; ++j) sub.push_back(pose_at(t + exposure * ((j + 0.5) / n_sub - 0.5)));
  const cv::Mat ref = r.renderImage(sub, plane, tex, 1.1, so, 77);
  // The simulator's rolling-shutter path with a 0 ms readout.
  const std::vector<RowBand> gs = rollingShutterBands(pose_at, t, r.height(), 0.0, exposure, n_sub);
  ASSERT_EQ(gs.size(), 1u);
  EXPECT_TRUE(sameImage(r.renderBands(gs, plane, tex, 1.1, so, 77), ref));
  // One band per row with the same poses: the same pixels too.
  std::vector<RowBand> rows;
  for (int v = 0; v < r.height(); ++v) rows.push_back({v, v + 1, sub, {}});
  EXPECT_TRUE(sameImage(r.renderBands(rows, plane, tex, 1.1, so, 77), ref));
  // And a non-zero readout changes the image.
  EXPECT_FALSE(sameImage(
      r.renderBands(rollingShutterBands(pose_at, t, r.height(), 0.016, exposure, n_sub), plane, tex, 1.1, so, 77),
      ref));
  // Bad band layouts are rejected.
  std::vector<RowBand> gap = {{0, 10, sub, {}}, {11, r.height(), sub, {}}};
  EXPECT_THROW(r.renderBands(gap, plane, tex, 1.0, so, 0), std::invalid_argument);
}

TEST(RealismRender, RollingShutterRowTimesAndMotionBlurSubframes) {
  // Row v is centred at t + readout (v / (H - 1) - 1/2); each row averages n_sub sub-frames over the exposure.
  std::vector<double> times;
  const auto pose_at = [&](double t) {
    times.push_back(t);
    return CameraPose();
  };
  const double t = 1.0, readout = 0.016, exposure = 0.004;
  const std::vector<RowBand> bands = rollingShutterBands(pose_at, t, 480, readout, exposure, 2);
  ASSERT_EQ(bands.size(), 480u);
  ASSERT_EQ(times.size(), 960u);
  EXPECT_NEAR(times[0], t - 0.008 - 0.001, 1e-12);        // top row, first sub-frame
  EXPECT_NEAR(times[1], t - 0.008 + 0.001, 1e-12);
  EXPECT_NEAR(times[958], t + 0.008 - 0.001, 1e-12);      // bottom row
  EXPECT_NEAR(times[959], t + 0.008 + 0.001, 1e-12);
  EXPECT_NEAR(rowTimeOffset(0, 480, readout), -0.008, 1e-15);
  EXPECT_NEAR(rowTimeOffset(479, 480, readout), 0.008, 1e-15);
  EXPECT_NEAR(rowTimeOffset(239, 480, readout) + rowTimeOffset(240, 480, readout), 0.0, 1e-15);  // middle
  // Bands of 4 rows share the time of their middle.
  times.clear();
  const std::vector<RowBand> b4 = rollingShutterBands(pose_at, t, 480, readout, 0.0, 1, 4);
  ASSERT_EQ(b4.size(), 120u);
  EXPECT_EQ(b4[1].row0, 4);
  EXPECT_NEAR(times[0], t + readout * (1.5 / 479 - 0.5), 1e-12);
}

// ---------------------------------------------------------------------------------------------------------------
// Defocus and glossy patches

TEST(RealismRender, DefocusReducesGradientEnergy) {
  const CameraModel cam = myntEyeSimCamera(0.25);
  const Renderer r(cam, 2);
  const Texture tex = Texture::checkerboard(0.05, 2, 16);
  CameraPose P;
  P.R_WC = downward();
  P.p_WC = Eigen::Vector3d(0.01, 0.02, 0.5);
  const SensorOptions so = noiseless();
  const std::vector<RowBand> one = {{0, r.height(), {P}, {}}};
  const cv::Mat sharp = r.renderBands(one, Plane(), tex, 1.0, so, 0);
  EXPECT_TRUE(sameImage(sharp, r.renderImage({P}, Plane(), tex, 1.0, so, 0)));
  RenderEffects fx;
  fx.defocus_sigma_px = 1.0;
  const cv::Mat blur1 = r.renderBands(one, Plane(), tex, 1.0, so, 0, fx);
  fx.defocus_sigma_px = 2.0;
  const cv::Mat blur2 = r.renderBands(one, Plane(), tex, 1.0, so, 0, fx);
  const double e0 = gradientEnergy(sharp), e1 = gradientEnergy(blur1), e2 = gradientEnergy(blur2);
  EXPECT_LT(e1, 0.75 * e0);
  EXPECT_LT(e2, 0.75 * e1);
  // Blur keeps the mean brightness.
  EXPECT_NEAR(cv::mean(blur1)[0], cv::mean(sharp)[0], 1.0);
}

TEST(RealismRender, NonLambertianDependsOnTheViewpoint) {
  const CameraModel cam = myntEyeSimCamera(0.25);
  const Renderer r(cam, 1);
  const Texture tex(std::vector<float>(64 * 64, 100.f), 64, 64, 0.01, 0.01);  // uniform ground
  const SpecularPatches spec(5, 0.3);
  EXPECT_NEAR(spec.coverage(), SpecularPatches::kCoverage, 0.01);
  EXPECT_EQ(SpecularPatches(5, 0.3).coverage(), spec.coverage());  // seeded
  const Plane plane;
  Eigen::Vector3d t1, t2;
  plane.basis(&t1, &t2);
  // A point inside a glossy patch and one outside.
  Eigen::Vector2d in(-1, -1), out(-1, -1);
  for (int j = 0; j < 400 && (in.x() < 0 || out.x() < 0); ++j)
    for (int i = 0; i < 400; ++i) {
      const double u = i * 0.01, v = j * 0.01;
      const float m = spec.mask(static_cast<float>(u), static_cast<float>(v));
      if (m > 0.99f && in.x() < 0) in = Eigen::Vector2d(u, v);
      if (m < 1e-3f && out.x() < 0) out = Eigen::Vector2d(u, v);
    }
  ASSERT_GE(in.x(), 0.0);
  ASSERT_GE(out.x(), 0.0);
  const Eigen::Vector3d& l = spec.lightW();
  const Eigen::Vector3d mirror = (2.0 * plane.n.dot(l) * plane.n - l).normalized();  // X -> camera for the highlight
  Eigen::Vector3d away = -mirror;
  away.z() = 0.0;
  const Eigen::Vector3d off_dir = (plane.n + 0.6 * away.normalized()).normalized();  // ~31 deg on the light's side
  const auto radianceAt = [&](const Eigen::Vector3d& X, const Eigen::Vector3d& dir, const SpecularPatches* s) {
    CameraPose P;
    P.R_WC = downward();
    P.p_WC = X + 0.6 / dir.z() * dir;
    Vec2 px;
    EXPECT_TRUE(cam.project(P.R_WC.transpose() * (X - P.p_WC), &px));
    std::vector<float> rad;
    RenderEffects fx;
    fx.specular = s;
    r.renderRadianceBands({{0, r.height(), {P}, {}}}, plane, tex, &rad, fx);
    const int u = static_cast<int>(std::lround(px.x())), v = static_cast<int>(std::lround(px.y()));
    EXPECT_GT(u, 2);
    EXPECT_GT(v, 2);
    EXPECT_LT(u, r.width() - 3);
    EXPECT_LT(v, r.height() - 3);
    return rad[static_cast<std::size_t>(v) * r.width() + u];
  };
  const Eigen::Vector3d X_in = in.x() * t1 + in.y() * t2, X_out = out.x() * t1 + out.y() * t2;
  // Clean: the same ground point is equally bright from both viewpoints.
  EXPECT_NEAR(radianceAt(X_in, mirror, nullptr), 100.f, 0.01f);
  EXPECT_NEAR(radianceAt(X_in, off_dir, nullptr), 100.f, 0.01f);
  // Glossy: bright where the light is mirrored into the camera, not from the other side.
  const float a = radianceAt(X_in, mirror, &spec), b = radianceAt(X_in, off_dir, &spec);
  EXPECT_GT(a - b, 0.8 * 0.3 * 100.0);
  EXPECT_LT(b, 101.f);
  EXPECT_LT(a, 100.f + 0.3f * 100.f + 0.5f);
  // Outside the patches nothing changes.
  EXPECT_NEAR(radianceAt(X_out, mirror, &spec), 100.f, 0.2f);
}

// ---------------------------------------------------------------------------------------------------------------
// Whole simulations (tiny images)

namespace {

struct BagImages {
  std::vector<std::int64_t> stamps_ns;
  std::vector<std::vector<std::uint8_t>> data;
  std::vector<std::int64_t> imu_ns;
  std::vector<sensor_msgs::CameraInfo> infos;
};

BagImages readBag(const std::string& path) {
  BagImages b;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  for (const rosbag::MessageInstance& m : view) {
    if (auto im = m.instantiate<sensor_msgs::Image>()) {
      b.stamps_ns.push_back(static_cast<std::int64_t>(im->header.stamp.toNSec()));
      b.data.push_back(im->data);
    } else if (auto imu = m.instantiate<sensor_msgs::Imu>()) {
      b.imu_ns.push_back(static_cast<std::int64_t>(imu->header.stamp.toNSec()));
    } else if (auto ci = m.instantiate<sensor_msgs::CameraInfo>()) {
      b.infos.push_back(*ci);
    }
  }
  return b;
}

SimulationOptions tinyOptions(const std::string& dir) {
  SimulationOptions o;
  o.preset = "flight2";
  o.duration_s = 1.5;
  o.scale = 0.125;  // 94 x 60
  o.threads = 2;
  o.output_dir = dir;
  return o;
}

double meanOf(const std::vector<std::uint8_t>& d) {
  double s = 0;
  for (std::uint8_t x : d) s += x;
  return s / d.size();
}

}  // namespace

class RealismSim : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new simtest::TempDir();
    clean_ = new BagImages(readBag(runSimulation(tinyOptions((dir_->path() / "clean").string()), nullptr).bag_path));
  }
  static void TearDownTestSuite() {
    delete clean_;
    delete dir_;
  }
  /// Runs the simulation `o` into the suite's directory `name` and reads its bag.
  static BagImages simulate(SimulationOptions o, const std::string& name) {
    o.output_dir = (dir_->path() / name).string();
    return readBag(runSimulation(o, nullptr).bag_path);
  }
  static simtest::TempDir* dir_;
  static BagImages* clean_;
};
simtest::TempDir* RealismSim::dir_ = nullptr;
BagImages* RealismSim::clean_ = nullptr;

TEST_F(RealismSim, CleanRunWritesTheTrueCalibrationAndZeroEffects) {
  const CameraModel cam = CameraModel::fromKalibrYaml((dir_->path() / "clean" / "camchain.yaml").string());
  const CameraModel ref = myntEyeSimCamera(0.125);
  EXPECT_EQ(cam.K.fx, ref.K.fx);
  EXPECT_EQ(cam.K.cx, ref.K.cx);
  EXPECT_LT((cam.T_cam_imu.matrix() - ref.T_cam_imu.matrix()).norm(), 1e-11);
  const YAML::Node y = YAML::LoadFile((dir_->path() / "clean" / "realism.yaml").string());
  EXPECT_EQ(y["realism"].as<std::string>(), "clean");
  EXPECT_EQ(y["rolling_shutter_ms"].as<double>(), 0.0);
  EXPECT_EQ(y["time_offset_ms"].as<double>(), 0.0);
  EXPECT_EQ(y["non_lambertian"].as<double>(), 0.0);
  EXPECT_FALSE(y["exposure_steps"].as<bool>());
  ASSERT_GT(clean_->data.size(), 40u);
}

TEST_F(RealismSim, TimeOffsetShiftsImageStampsExactly) {
  for (const double off_ms : {5.0, -7.25}) {
    SCOPED_TRACE(::testing::Message() << "offset " << off_ms << " ms");
    SimulationOptions o = tinyOptions((dir_->path() / ("off" + std::to_string(off_ms))).string());
    o.realism.time_offset_ms = off_ms;
    const BagImages b = readBag(runSimulation(o, nullptr).bag_path);
    ASSERT_EQ(b.stamps_ns.size(), clean_->stamps_ns.size());
    for (std::size_t i = 0; i < b.stamps_ns.size(); ++i) {
      EXPECT_EQ(b.stamps_ns[i] - clean_->stamps_ns[i], std::llround(off_ms * 1e6)) << "image " << i;
      EXPECT_EQ(b.data[i], clean_->data[i]) << "image " << i;  // same capture, only the stamp moves
      ASSERT_EQ(b.infos.size(), b.stamps_ns.size());
      EXPECT_EQ(static_cast<std::int64_t>(b.infos[i].header.stamp.toNSec()), b.stamps_ns[i]);
    }
    EXPECT_EQ(b.imu_ns, clean_->imu_ns);  // the IMU clock is the truth
    const CameraModel cam = CameraModel::fromKalibrYaml((std::filesystem::path(o.output_dir) / "camchain.yaml").string());
    EXPECT_EQ(cam.timeshift_cam_imu_s, 0.0);
    const YAML::Node y = YAML::LoadFile((std::filesystem::path(o.output_dir) / "realism.yaml").string());
    EXPECT_DOUBLE_EQ(y["true_timeshift_cam_imu_s"].as<double>(), -off_ms * 1e-3);
  }
}

TEST_F(RealismSim, CalibrationErrorsAppearInTheCamchainOnly) {
  SimulationOptions o = tinyOptions((dir_->path() / "calib").string());
  o.realism.intrinsics_error_pct = 1.5;
  o.realism.extrinsic_rot_error_deg = 1.0;
  const BagImages b = readBag(runSimulation(o, nullptr).bag_path);
  const CameraModel w = CameraModel::fromKalibrYaml((dir_->path() / "calib" / "camchain.yaml").string());
  const CameraModel t = myntEyeSimCamera(0.125);
  EXPECT_NEAR(w.K.fx, t.K.fx * 1.015, 1e-9);
  EXPECT_NEAR(w.K.fy, t.K.fy * 1.015, 1e-9);
  EXPECT_NEAR(w.K.cx, t.K.cx + 0.015 * 0.5 * 94, 1e-9);
  EXPECT_NEAR(w.K.cy, t.K.cy - 0.015 * 0.5 * 60, 1e-9);
  EXPECT_EQ(w.distortion_coeffs, t.distortion_coeffs);
  EXPECT_EQ(w.timeshift_cam_imu_s, 0.0);
  // Rotation error: R_CI_written = R(axis, 1 deg) R_CI_true, axis (1, 1, 0)/sqrt(2) in C; camera centre kept.
  const Eigen::AngleAxisd err(w.R_CI() * t.R_CI().transpose());
  EXPECT_NEAR(err.angle() * 180.0 / M_PI, 1.0, 1e-9);
  EXPECT_NEAR(err.axis().dot(Eigen::Vector3d(1, 1, 0).normalized()), 1.0, 1e-9);
  const Eigen::Vector3d c_w = -w.R_CI().transpose() * w.t_CI(), c_t = -t.R_CI().transpose() * t.t_CI();
  EXPECT_LT((c_w - c_t).norm(), 1e-12);
  // camera_info carries the written intrinsics too; the images are rendered with the truth (identical).
  ASSERT_FALSE(b.infos.empty());
  EXPECT_NEAR(b.infos[0].K[0], w.K.fx, 1e-9);
  EXPECT_NEAR(b.infos[0].K[2], w.K.cx, 1e-9);
  ASSERT_EQ(b.data.size(), clean_->data.size());
  for (std::size_t i = 0; i < b.data.size(); ++i) EXPECT_EQ(b.data[i], clean_->data[i]) << "image " << i;
  // realism.yaml states both.
  const YAML::Node y = YAML::LoadFile((dir_->path() / "calib" / "realism.yaml").string());
  EXPECT_NEAR(y["true_intrinsics"][0].as<double>(), t.K.fx, 1e-9);
  EXPECT_NEAR(y["written_intrinsics"][0].as<double>(), w.K.fx, 1e-9);
  EXPECT_NEAR(y["written_T_cam_imu"][0][0].as<double>(), w.T_cam_imu.matrix()(0, 0), 1e-11);
  EXPECT_NEAR(y["true_T_cam_imu"][0][0].as<double>(), t.T_cam_imu.matrix()(0, 0), 1e-11);
}

TEST_F(RealismSim, ExposureStepsMakeBrightnessSteps) {
  SimulationOptions o = tinyOptions((dir_->path() / "steps").string());
  o.preset = "hover";
  o.duration_s = 7.0;
  o.sensor.noise = false;
  SimulationOptions c = o;
  c.output_dir = (dir_->path() / "steps_clean").string();
  o.realism.exposure_steps = true;
  const BagImages b = readBag(runSimulation(o, nullptr).bag_path);
  const BagImages ref = readBag(runSimulation(c, nullptr).bag_path);
  const ExposureSteps steps(o.seed, o.duration_s + 1.0);
  ASSERT_GE(steps.stepTimes().size(), 2u);  // every 1-3 s
  ASSERT_EQ(b.data.size(), ref.data.size());
  int jumps = 0;
  double prev_ratio = 1.0;
  for (std::size_t i = 0; i < b.data.size(); ++i) {
    const double t = (b.stamps_ns[i] - b.stamps_ns[0]) * 1e-9 + 1.0 / o.fps;
    const double ratio = meanOf(b.data[i]) / meanOf(ref.data[i]);
    const double level = steps.gain(t);
    if (level * 200.0 < 250.0) {
      EXPECT_NEAR(ratio, level, 0.02) << "image " << i << " t " << t;
    }
    const double jump = std::fabs(ratio / prev_ratio - 1.0);
    if (jump > 0.08) {
      ++jumps;
    } else {
      EXPECT_LT(jump, 0.01) << "image " << i;  // piecewise constant between the steps
    }
    prev_ratio = ratio;
  }
  const double t_last = (b.stamps_ns.back() - b.stamps_ns[0]) * 1e-9 + 1.0 / o.fps;
  int expected = 0;
  for (double ts : steps.stepTimes()) expected += ts > 1.0 / o.fps && ts <= t_last;
  EXPECT_EQ(jumps, expected);
  EXPECT_GE(jumps, 2);
}

// Mains flicker (--mains-flicker-hz): with a rolling shutter each row integrates its own part of the light's cycle,
// so an image's rows are banded (1.6 cycles of 100 Hz over a 16 ms readout, depth 0.2 less the 4 ms exposure's
// averaging: sinc(0.4 pi) = 0.76) and the bands move between images; with a global shutter every row of an image
// has the same brightness, which changes from image to image.
TEST_F(RealismSim, MainsFlickerBandsTheRowsOfARollingShutter) {
  auto rowRatios = [&](double readout_ms, const std::string& name) {
    SimulationOptions o = tinyOptions((dir_->path() / name).string());
    o.preset = "hover";
    o.duration_s = 1.0;
    o.sensor.noise = false;
    o.realism.rolling_shutter_ms = readout_ms;
    SimulationOptions steady = o;
    steady.output_dir += "_steady";
    o.mains_flicker_hz = 100.0;
    o.mains_flicker_depth = 0.2;
    const BagImages b = readBag(runSimulation(o, nullptr).bag_path);
    const BagImages ref = readBag(runSimulation(steady, nullptr).bag_path);
    EXPECT_EQ(b.data.size(), ref.data.size());
    const CameraModel cam = myntEyeSimCamera(0.125);
    const int W = cam.K.width, H = cam.K.height;
    std::vector<std::vector<double>> ratios;  // per image, per row: flickering / steady row mean
    for (std::size_t i = 0; i < std::min(b.data.size(), ref.data.size()); ++i) {
      std::vector<double> rows;
      for (int y = 0; y < H; ++y) {
        double sb = 0, sr = 0;
        for (int x = 0; x < W; ++x) {
          sb += b.data[i][y * W + x];
          sr += ref.data[i][y * W + x];
        }
        rows.push_back(sb / sr);
      }
      ratios.push_back(rows);
    }
    return ratios;
  };
  auto spread = [](const std::vector<double>& v) {
    return *std::max_element(v.begin(), v.end()) - *std::min_element(v.begin(), v.end());
  };
  const auto rolling = rowRatios(16.0, "flicker_rs");
  ASSERT_GT(rolling.size(), 20u);
  double first_row_lo = 1e9, first_row_hi = -1e9;
  for (const auto& rows : rolling) {
    const double mean = std::accumulate(rows.begin(), rows.end(), 0.0) / rows.size();
    EXPECT_GT(spread(rows), 0.2);   // about 2 x 0.2 x 0.76 peak to peak, over 1.6 cycles
    EXPECT_LT(spread(rows), 0.34);
    int crossings = 0;
    for (std::size_t y = 1; y < rows.size(); ++y) crossings += (rows[y - 1] - mean) * (rows[y] - mean) < 0.0;
    EXPECT_GE(crossings, 2);
    EXPECT_LE(crossings, 4);
    first_row_lo = std::min(first_row_lo, rows[0]);
    first_row_hi = std::max(first_row_hi, rows[0]);
  }
  EXPECT_GT(first_row_hi - first_row_lo, 0.15) << "the bands move from image to image";
  const auto global = rowRatios(0.0, "flicker_gs");
  double mean_lo = 1e9, mean_hi = -1e9;
  for (const auto& rows : global) {
    EXPECT_LT(spread(rows), 0.01);  // one brightness per image
    mean_lo = std::min(mean_lo, rows[0]);
    mean_hi = std::max(mean_hi, rows[0]);
  }
  EXPECT_GT(mean_hi - mean_lo, 0.15);
}

// A webcam's image processor (--gamma, --jpeg-quality): the gamma encodes each grey level as 255 (s / 255)^(1/G),
// and the JPEG round trip changes the image by a fraction of its contrast.
TEST_F(RealismSim, GammaAndJpegAreAWebcamsEncoding) {
  SimulationOptions o = tinyOptions("");
  o.sensor.noise = false;
  const BagImages linear = simulate(o, "linear");
  SimulationOptions g = o;
  g.sensor.gamma = 2.2;
  const BagImages encoded = simulate(g, "gamma");
  SimulationOptions q = o;
  q.jpeg_quality = 75;
  const BagImages jpeg = simulate(q, "jpeg");
  ASSERT_GT(linear.data.size(), 20u);
  ASSERT_EQ(encoded.data.size(), linear.data.size());
  ASSERT_EQ(jpeg.data.size(), linear.data.size());
  EXPECT_EQ(encoded.stamps_ns, linear.stamps_ns);
  EXPECT_EQ(jpeg.stamps_ns, linear.stamps_ns);
  double abs_change = 0.0, abs_contrast = 0.0;
  std::size_t n = 0, changed = 0;
  for (std::size_t i = 0; i < linear.data.size(); ++i) {
    ASSERT_EQ(encoded.data[i].size(), linear.data[i].size());
    ASSERT_EQ(jpeg.data[i].size(), linear.data[i].size());
    const double mean = meanOf(linear.data[i]);
    for (std::size_t k = 0; k < linear.data[i].size(); ++k) {
      // The linear image is the signal rounded: the encoded one is its curve within half a grey level of input.
      const double s = linear.data[i][k];
      const double lo = 255.0 * std::pow(std::max(s - 0.5, 0.0) / 255.0, 1.0 / 2.2);
      const double hi = 255.0 * std::pow(std::min(s + 0.5, 255.0) / 255.0, 1.0 / 2.2);
      EXPECT_GE(encoded.data[i][k], std::floor(lo));
      EXPECT_LE(encoded.data[i][k], std::ceil(hi) + 1.0);
      const double d = std::abs(static_cast<double>(jpeg.data[i][k]) - s);
      abs_contrast += std::abs(s - mean);
      abs_change += d;
      changed += d >= 2.0;
      ++n;
    }
  }
  EXPECT_GT(meanOf(encoded.data[0]), meanOf(linear.data[0]) + 20.0);  // mid-greys brightened
  EXPECT_GT(changed, n / 50) << "the JPEG round trip changes the images";
  EXPECT_LT(abs_change, 0.3 * abs_contrast) << "by a fraction of the image's own contrast";
  EXPECT_NEAR(meanOf(jpeg.data[0]), meanOf(linear.data[0]), 1.5);
}

// An IMU at another rate (--imu-rate) and its stamps taken on arrival at a host (--imu-stamp-jitter-ms): the
// stamps keep their order, each is late by |N(0, J)| (mean 0.8 J) or by what keeps the order, and imu.yaml
// carries the rate.
TEST_F(RealismSim, ImuRateAndArrivalStampsOfAHostReadIMU) {
  SimulationOptions o = tinyOptions("");
  o.imu_noise.rate_hz = 200.0;
  const BagImages exact = simulate(o, "imu200");
  SimulationOptions j = o;
  j.imu_stamp_jitter_ms = 1.0;
  const BagImages late = simulate(j, "imu200_jitter");
  const YAML::Node imu_yaml = YAML::LoadFile((dir_->path() / "imu200" / "imu.yaml").string());
  EXPECT_DOUBLE_EQ(imu_yaml["update_rate"].as<double>(), 200.0);
  ASSERT_GT(exact.imu_ns.size(), 250u);
  ASSERT_EQ(late.imu_ns.size(), exact.imu_ns.size());
  std::vector<std::int64_t> sorted_exact = exact.imu_ns, sorted_late = late.imu_ns;
  std::sort(sorted_exact.begin(), sorted_exact.end());
  std::sort(sorted_late.begin(), sorted_late.end());
  for (std::size_t i = 1; i < sorted_exact.size(); ++i) EXPECT_EQ(sorted_exact[i] - sorted_exact[i - 1], 5000000);
  double delay_sum = 0.0;
  for (std::size_t i = 0; i < sorted_late.size(); ++i) {
    const std::int64_t delay = sorted_late[i] - sorted_exact[i];
    EXPECT_GE(delay, 0);
    EXPECT_LT(delay, 6000000);
    if (i > 0) {
      EXPECT_GE(sorted_late[i] - sorted_late[i - 1], 50000);
    }
    delay_sum += delay * 1e-6;  // ms
  }
  EXPECT_NEAR(delay_sum / sorted_late.size(), 0.8, 0.15);  // E|N(0, 1 ms)| = 0.80 ms
  EXPECT_EQ(late.stamps_ns, exact.stamps_ns);  // the images' stamps stay exact
}

TEST_F(RealismSim, RealisticPresetRunsAndRecordsItsValues) {
  SimulationOptions o = tinyOptions((dir_->path() / "realistic").string());
  std::string err;
  ASSERT_EQ(parseSimulateArgs({"--realism", "realistic", "--output", o.output_dir}, &o, &err), ParseResult::kOk) << err;
  const SimulationSummary s = runSimulation(o, nullptr);
  const BagImages b = readBag(s.bag_path);
  ASSERT_GT(b.data.size(), 30u);
  // Different images from the clean run (rolling shutter, defocus, glossy patches, exposure).
  int differ = 0;
  for (std::size_t i = 0; i < std::min(b.data.size(), clean_->data.size()); ++i) differ += b.data[i] != clean_->data[i];
  EXPECT_GT(differ, static_cast<int>(b.data.size()) / 2);
  const YAML::Node y = YAML::LoadFile((dir_->path() / "realistic" / "realism.yaml").string());
  EXPECT_EQ(y["realism"].as<std::string>(), "realistic");
  EXPECT_EQ(y["rolling_shutter_ms"].as<double>(), 16.0);
  EXPECT_EQ(y["time_offset_ms"].as<double>(), 5.0);
  EXPECT_EQ(y["intrinsics_error_pct"].as<double>(), 1.5);
  EXPECT_EQ(y["extrinsic_rot_error_deg"].as<double>(), 1.0);
  EXPECT_EQ(y["defocus_px"].as<double>(), 1.0);
  EXPECT_TRUE(y["exposure_steps"].as<bool>());
  EXPECT_EQ(y["non_lambertian"].as<double>(), 0.3);
  EXPECT_NEAR(y["non_lambertian_coverage"].as<double>(), 0.2, 0.01);
  EXPECT_EQ(b.stamps_ns[0] - clean_->stamps_ns[0], 5000000);
}

TEST_F(RealismSim, FlatFieldFileIsTheImagesFixedGain) {
  // --write-flat-field: vignetting x the projector's dots, what the estimator's fixed_pattern/vignetting_file takes.
  SimulationOptions o = tinyOptions((dir_->path() / "dots").string());
  std::string err;
  ASSERT_EQ(parseSimulateArgs({"--projector-dots", "300", "--write-flat-field", "--output", o.output_dir}, &o, &err),
            ParseResult::kOk)
      << err;
  const BagImages b = readBag(runSimulation(o, nullptr).bag_path);
  cv::Mat flat;
  cv::FileStorage((dir_->path() / "dots" / "flat_field.yaml").string(), cv::FileStorage::READ)["gain"] >> flat;
  ASSERT_EQ(flat.type(), CV_32FC1);
  ASSERT_EQ(flat.cols * flat.rows, static_cast<int>(b.data.at(0).size()));
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(flat, &lo, &hi);
  EXPECT_GT(hi, 1.5);  // dots
  EXPECT_LT(lo, 0.8);  // vignetted corners (0.35 r^2 with the dots' gain of 1 there)
  // The same flight without the dots, seen through the flat field: the image with the dots over the image without
  // them is the dots' gain, flat / vignetting (pixels not saturated, over every image of the flight).
  SimulationOptions c = tinyOptions((dir_->path() / "vignetting").string());
  c.write_flat_field = true;
  runSimulation(c, nullptr);
  cv::Mat vig;
  cv::FileStorage((dir_->path() / "vignetting" / "flat_field.yaml").string(), cv::FileStorage::READ)["gain"] >> vig;
  ASSERT_EQ(vig.size(), flat.size());
  const cv::Mat dots_gain = flat / vig;
  cv::Mat ratio_sum(flat.size(), CV_64FC1, cv::Scalar(0.0)), count(flat.size(), CV_64FC1, cv::Scalar(0.0));
  for (std::size_t i = 0; i < std::min(b.data.size(), clean_->data.size()); ++i)
    for (int p = 0; p < flat.cols * flat.rows; ++p) {
      const double with = b.data[i][p], without = clean_->data[i][p];
      if (with >= 250.0 || without < 20.0) continue;
      ratio_sum.ptr<double>()[p] += with / without;
      count.ptr<double>()[p] += 1.0;
    }
  std::vector<double> measured, written;
  for (int p = 0; p < flat.cols * flat.rows; ++p)
    if (count.ptr<double>()[p] > 10.0) {
      measured.push_back(ratio_sum.ptr<double>()[p] / count.ptr<double>()[p]);
      written.push_back(dots_gain.ptr<float>()[p]);
    }
  ASSERT_GT(measured.size(), static_cast<std::size_t>(flat.cols * flat.rows / 2));
  double ma = 0, mb = 0, sab = 0, saa = 0, sbb = 0;
  for (std::size_t i = 0; i < measured.size(); ++i) ma += measured[i] / measured.size(), mb += written[i] / written.size();
  for (std::size_t i = 0; i < measured.size(); ++i) {
    sab += (measured[i] - ma) * (written[i] - mb);
    saa += (measured[i] - ma) * (measured[i] - ma);
    sbb += (written[i] - mb) * (written[i] - mb);
  }
  EXPECT_GT(sab / std::sqrt(saa * sbb), 0.9);
  EXPECT_FALSE(std::filesystem::exists(dir_->path() / "clean" / "flat_field.yaml"));  // only when asked for
}

// ---------------------------------------------------------------------------------------------------------------
// Command line

TEST(SimulatorCli, RealismPresetAndExplicitOverrides) {
  std::string err;
  SimulationOptions d;
  ASSERT_EQ(parseSimulateArgs({"--output", "x"}, &d, &err), ParseResult::kOk);
  EXPECT_EQ(d.realism.rolling_shutter_ms, 0.0);
  EXPECT_FALSE(d.realism.exposure_steps);
  EXPECT_EQ(d.realism_preset, "clean");

  SimulationOptions r;
  ASSERT_EQ(parseSimulateArgs({"--realism", "realistic", "--output", "x"}, &r, &err), ParseResult::kOk) << err;
  EXPECT_EQ(r.realism.rolling_shutter_ms, 16.0);
  EXPECT_EQ(r.realism.time_offset_ms, 5.0);
  EXPECT_EQ(r.realism.intrinsics_error_pct, 1.5);
  EXPECT_EQ(r.realism.extrinsic_rot_error_deg, 1.0);
  EXPECT_EQ(r.realism.defocus_px, 1.0);
  EXPECT_TRUE(r.realism.exposure_steps);
  EXPECT_EQ(r.realism.non_lambertian, 0.3);
  EXPECT_EQ(r.realism_preset, "realistic");

  // Explicit options win over the preset (after it, and before it too).
  SimulationOptions o;
  ASSERT_EQ(parseSimulateArgs({"--time-offset-ms", "-3", "--realism", "realistic", "--rolling-shutter-ms", "0",
                               "--no-exposure-steps", "--non-lambertian=0.5", "--output", "x"},
                              &o, &err),
            ParseResult::kOk)
      << err;
  EXPECT_EQ(o.realism.rolling_shutter_ms, 0.0);
  EXPECT_EQ(o.realism.time_offset_ms, -3.0);
  EXPECT_FALSE(o.realism.exposure_steps);
  EXPECT_EQ(o.realism.non_lambertian, 0.5);
  EXPECT_EQ(o.realism.intrinsics_error_pct, 1.5);  // from the preset
  EXPECT_EQ(o.realism.defocus_px, 1.0);

  SimulationOptions c;
  ASSERT_EQ(parseSimulateArgs({"--realism", "clean", "--exposure-steps", "--defocus-px", "2", "--output", "x"}, &c,
                              &err),
            ParseResult::kOk);
  EXPECT_TRUE(c.realism.exposure_steps);
  EXPECT_EQ(c.realism.defocus_px, 2.0);
  EXPECT_EQ(c.realism.rolling_shutter_ms, 0.0);

  const std::vector<std::vector<std::string>> bad = {{"--realism", "gritty", "--output", "x"},
                                                     {"--realism"},
                                                     {"--rolling-shutter-ms", "-1", "--output", "x"},
                                                     {"--rolling-shutter-ms", "150", "--output", "x"},
                                                     {"--time-offset-ms", "250", "--output", "x"},
                                                     {"--intrinsics-error", "12", "--output", "x"},
                                                     {"--extrinsic-rot-error-deg", "x", "--output", "x"},
                                                     {"--defocus-px", "-0.5", "--output", "x"},
                                                     {"--non-lambertian", "1.5", "--output", "x"}};
  for (const auto& args : bad) {
    err.clear();
    SimulationOptions fresh;
    EXPECT_EQ(parseSimulateArgs(args, &fresh, &err), ParseResult::kError) << args[0] << " " << args.size();
    EXPECT_FALSE(err.empty());
    EXPECT_EQ(err.find('\n'), std::string::npos);
  }
  for (const char* flag : {"--realism", "--rolling-shutter-ms", "--time-offset-ms", "--intrinsics-error",
                           "--extrinsic-rot-error-deg", "--defocus-px", "--exposure-steps", "--non-lambertian"})
    EXPECT_NE(simulateUsage().find(flag), std::string::npos) << flag;
}
