// CameraModel: Kalibr camchain parsing, error messages, distortion round trips, projection.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <string>

#include "diekf/camera_model.h"

#include "mynt_camera.h"

namespace diekf {
namespace {

// Package root, located from this source file's path (no machine path in the repository).
std::string packageDir() {
  std::string f = __FILE__;
  const std::string tail = "test/core/test_camera_model.cpp";
  return f.substr(0, f.size() - tail.size());
}

std::string writeTemp(const std::string& name, const std::string& text) {
  const std::string path = ::testing::TempDir() + "diekf_camtest_" + name + ".yaml";
  std::ofstream(path) << text;
  return path;
}

const char* kGoodCam = R"(cam0:
  camera_model: pinhole
  intrinsics: [364.91, 364.97, 379.91, 245.53]
  distortion_model: radtan
  distortion_coeffs: [-0.3178, 0.0962, -0.00011, 0.00033]
  resolution: [752, 480]
  T_cam_imu:
  - [0.0, 1.0, 0.0, 0.048]
  - [-1.0, 0.0, 0.0, -0.004]
  - [0.0, 0.0, 1.0, -0.012]
  - [0.0, 0.0, 0.0, 1.0]
  timeshift_cam_imu: 0.0025
  rostopic: /mynteye/left/image_raw
)";

std::string replaceLine(std::string text, const std::string& from, const std::string& to) {
  const auto pos = text.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  if (pos != std::string::npos) text.replace(pos, from.size(), to);
  return text;
}

// Expects fromKalibrYaml on `text` to throw std::runtime_error whose message names the file and `key`.
void expectErrorNaming(const std::string& name, const std::string& text, const std::string& key) {
  const std::string path = writeTemp(name, text);
  try {
    CameraModel::fromKalibrYaml(path);
    FAIL() << "no exception for " << name;
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path), std::string::npos) << msg;
    EXPECT_NE(msg.find(key), std::string::npos) << msg;
  }
  std::remove(path.c_str());
}


CameraModel fisheye() {
  CameraModel m;
  m.K = PinholeK{400.0, 401.0, 376.0, 240.0, 752, 480};  // corner at theta_d ~ 1.1 rad
  m.distortion = DistortionModel::kEquidistant;
  m.distortion_coeffs = Vec4(-0.013, 0.021, -0.016, 0.004);
  return m;
}

TEST(CameraModel, ParsesSampleCamchain) {
  const CameraModel m = CameraModel::fromKalibrYaml(packageDir() + "config/mynteye_camchain.yaml");
  EXPECT_DOUBLE_EQ(m.K.fx, 364.91);
  EXPECT_DOUBLE_EQ(m.K.fy, 364.97);
  EXPECT_DOUBLE_EQ(m.K.cx, 379.91);
  EXPECT_DOUBLE_EQ(m.K.cy, 245.53);
  EXPECT_EQ(m.K.width, 752);
  EXPECT_EQ(m.K.height, 480);
  EXPECT_EQ(m.distortion, DistortionModel::kRadTan);
  EXPECT_DOUBLE_EQ(m.distortion_coeffs[0], -0.3178);
  EXPECT_DOUBLE_EQ(m.distortion_coeffs[3], 0.00033);
  EXPECT_EQ(m.rostopic, "/mynteye/left/image_raw");
  // 90 degrees about the optical axis: x_C = y_I, y_C = -x_I.
  EXPECT_TRUE((m.R_CI() * Vec3(0, 1, 0)).isApprox(Vec3(1, 0, 0), 1e-12));
  EXPECT_TRUE((m.R_CI() * Vec3(1, 0, 0)).isApprox(Vec3(0, -1, 0), 1e-12));
  EXPECT_TRUE(m.t_CI().isApprox(Vec3(0.048, -0.004, -0.012), 1e-12));
  EXPECT_DOUBLE_EQ(m.timeshift_cam_imu_s, 0.0);
}

TEST(CameraModel, ParsesOptionalKeysAndOtherCam) {
  std::string text = kGoodCam;
  text += replaceLine(replaceLine(replaceLine(kGoodCam, "cam0:", "cam1:"), "distortion_model: radtan",
                                  "distortion_model: equidistant"),
                      "  timeshift_cam_imu: 0.0025\n  rostopic: /mynteye/left/image_raw\n", "");
  const std::string path = writeTemp("twocams", text);
  const CameraModel c0 = CameraModel::fromKalibrYaml(path, "cam0");
  EXPECT_DOUBLE_EQ(c0.timeshift_cam_imu_s, 0.0025);
  const CameraModel c1 = CameraModel::fromKalibrYaml(path, "cam1");
  EXPECT_EQ(c1.distortion, DistortionModel::kEquidistant);
  EXPECT_DOUBLE_EQ(c1.timeshift_cam_imu_s, 0.0);  // optional, default 0
  EXPECT_TRUE(c1.rostopic.empty());
  EXPECT_DOUBLE_EQ(c1.line_delay_s, 0.0);  // optional: global shutter
  std::remove(path.c_str());
}

TEST(CameraModel, ParsesTheRollingShutterLineDelay) {
  const std::string path = writeTemp(
      "linedelay", replaceLine(kGoodCam, "timeshift_cam_imu: 0.0025", "timeshift_cam_imu: 0.0025\n  line_delay_s: 3.3e-5"));
  EXPECT_DOUBLE_EQ(CameraModel::fromKalibrYaml(path).line_delay_s, 3.3e-5);
  std::remove(path.c_str());
  // A negative delay, or one whose frame readout takes 0.2 s or more, names the key.
  expectErrorNaming("negdelay",
                    replaceLine(kGoodCam, "timeshift_cam_imu: 0.0025", "timeshift_cam_imu: 0.0025\n  line_delay_s: -1e-5"),
                    "cam0/line_delay_s");
  expectErrorNaming("longdelay",
                    replaceLine(kGoodCam, "timeshift_cam_imu: 0.0025", "timeshift_cam_imu: 0.0025\n  line_delay_s: 0.001"),
                    "cam0/line_delay_s");
}

TEST(CameraModel, ErrorsNameFileAndKey) {
  expectErrorNaming("nocam", replaceLine(kGoodCam, "cam0:", "camX:"), "cam0");
  expectErrorNaming("nointr", replaceLine(kGoodCam, "  intrinsics: [364.91, 364.97, 379.91, 245.53]\n", ""),
                    "cam0/intrinsics");
  expectErrorNaming("shortintr", replaceLine(kGoodCam, "[364.91, 364.97, 379.91, 245.53]", "[364.91, 364.97]"),
                    "cam0/intrinsics");
  expectErrorNaming("textintr", replaceLine(kGoodCam, "[364.91, 364.97, 379.91, 245.53]", "[364.91, abc, 1, 2]"),
                    "cam0/intrinsics");
  expectErrorNaming("model", replaceLine(kGoodCam, "camera_model: pinhole", "camera_model: omni"),
                    "cam0/camera_model");
  expectErrorNaming("dist", replaceLine(kGoodCam, "distortion_model: radtan", "distortion_model: fov"),
                    "cam0/distortion_model");
  expectErrorNaming("coeffs", replaceLine(kGoodCam, "[-0.3178, 0.0962, -0.00011, 0.00033]", "[-0.3178, 0.0962]"),
                    "cam0/distortion_coeffs");
  expectErrorNaming("res", replaceLine(kGoodCam, "[752, 480]", "[752]"), "cam0/resolution");
  expectErrorNaming("notorth", replaceLine(kGoodCam, "- [0.0, 1.0, 0.0, 0.048]", "- [0.5, 1.0, 0.0, 0.048]"),
                    "cam0/T_cam_imu");
  expectErrorNaming("reflect", replaceLine(kGoodCam, "- [0.0, 0.0, 1.0, -0.012]", "- [0.0, 0.0, -1.0, -0.012]"),
                    "cam0/T_cam_imu");
  expectErrorNaming("Trows", replaceLine(kGoodCam, "  - [0.0, 0.0, 0.0, 1.0]\n", ""), "cam0/T_cam_imu");
  expectErrorNaming("noT", replaceLine(kGoodCam, "  T_cam_imu:\n", "  T_other:\n"), "cam0/T_cam_imu");
  expectErrorNaming("shift", replaceLine(kGoodCam, "timeshift_cam_imu: 0.0025", "timeshift_cam_imu: soon"),
                    "cam0/timeshift_cam_imu");
  // Unreadable file: the message names the file.
  try {
    CameraModel::fromKalibrYaml("/nonexistent_dir_diekf/camchain.yaml");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent_dir_diekf/camchain.yaml"), std::string::npos);
  }
}

void roundTripOverImage(const CameraModel& m) {
  double max_err = 0.0, max_px_err = 0.0;
  int failures = 0;
  for (double v = 0.0; v <= m.K.height - 1; v += 4.0) {
    for (double u = 0.0; u <= m.K.width - 1; u += 4.0) {
      const Vec2 px(u, v);
      Vec2 xn;
      if (!m.unproject(px, &xn)) {
        ++failures;
        continue;
      }
      const Vec2 xd((u - m.K.cx) / m.K.fx, (v - m.K.cy) / m.K.fy);
      max_err = std::max(max_err, (m.distort(xn) - xd).norm());
      Vec2 px2;
      ASSERT_TRUE(m.project(Vec3(xn.x(), xn.y(), 1.0) * 2.5, &px2));
      max_px_err = std::max(max_px_err, (px2 - px).norm());
    }
  }
  EXPECT_EQ(failures, 0);
  EXPECT_LT(max_err, 1e-9);
  EXPECT_LT(max_px_err, 1e-9 * m.K.fx);
  // Corners exactly.
  for (const Vec2& c : {Vec2(-0.5, -0.5), Vec2(m.K.width - 0.5, -0.5), Vec2(-0.5, m.K.height - 0.5),
                        Vec2(m.K.width - 0.5, m.K.height - 0.5)}) {
    Vec2 xn;
    ASSERT_TRUE(m.unproject(c, &xn));
    Vec2 px;
    ASSERT_TRUE(m.project(Vec3(xn.x(), xn.y(), 1.0), &px));
    EXPECT_LT((px - c).norm(), 1e-9);
  }
}

TEST(CameraModel, RadtanRoundTripOverImage) { roundTripOverImage(myntEyeCamera()); }
TEST(CameraModel, EquidistantRoundTripOverImage) { roundTripOverImage(fisheye()); }

TEST(CameraModel, DistortionIsNotIdentity) {
  // Guards against a round trip passing because both directions do nothing.
  const Vec2 x(0.8, -0.5);
  EXPECT_GT((myntEyeCamera().distort(x) - x).norm(), 0.05);
  EXPECT_GT((fisheye().distort(x) - x).norm(), 0.05);
  // Radtan at r^2 = 0.89: radial factor 1 - 0.3178 r^2 + 0.0962 r^4 plus tangential terms.
  const double r2 = 0.89, rad = 1.0 - 0.3178 * r2 + 0.0962 * r2 * r2;
  const Vec2 expected(0.8 * rad + 2 * -0.00011 * 0.8 * -0.5 + 0.00033 * (r2 + 2 * 0.64),
                      -0.5 * rad + -0.00011 * (r2 + 2 * 0.25) + 2 * 0.00033 * 0.8 * -0.5);
  EXPECT_LT((myntEyeCamera().distort(x) - expected).norm(), 1e-15);
  // Equidistant: theta_d = theta (1 + k1 theta^2 + ...), direction kept.
  const double r = x.norm(), th = std::atan(r);
  const Vec4 k = fisheye().distortion_coeffs;
  const double thd = th * (1 + k[0] * th * th + k[1] * std::pow(th, 4) + k[2] * std::pow(th, 6) +
                           k[3] * std::pow(th, 8));
  EXPECT_LT((fisheye().distort(x) - x * (thd / r)).norm(), 1e-15);
}

TEST(CameraModel, ProjectUnprojectRoundTrip) {
  for (const CameraModel& m : {myntEyeCamera(), fisheye()}) {
    const Vec3 P(0.3, -0.2, 1.7);
    Vec2 px, xn;
    ASSERT_TRUE(m.project(P, &px));
    ASSERT_TRUE(m.unproject(px, &xn));
    EXPECT_LT((xn - P.head<2>() / P.z()).norm(), 1e-12);
    EXPECT_FALSE(m.project(Vec3(0.1, 0.1, -1.0), &px));  // behind the camera
  }
  CameraModel pin = myntEyeCamera();
  pin.distortion = DistortionModel::kNone;
  Vec2 px;
  ASSERT_TRUE(pin.project(Vec3(1.0, 2.0, 4.0), &px));
  EXPECT_NEAR(px.x(), 364.91 * 0.25 + 379.91, 1e-12);
  EXPECT_NEAR(px.y(), 364.97 * 0.5 + 245.53, 1e-12);
}

}  // namespace
}  // namespace diekf
