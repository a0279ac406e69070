// Moving objects and boxes on the ground (outliers of the single-plane model): generation, ray casting against the
// ground (nearest hit), texture scale on a box top, rolling shutter and motion blur at the objects' own times,
// coverage masks, occlusion.csv / clutter.yaml of a simulation and the command line.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <yaml-cpp/yaml.h>

#include "blob_texture.h"
#include "diekf/sim/clutter.h"
#include "diekf/sim/renderer.h"
#include "diekf/sim/sequence_io.h"
#include "diekf/sim/simulator.h"
#include "test_util.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

/// Camera looking straight down (x_C = x_W, y_C = -y_W, z_C = -z_W).
Eigen::Matrix3d downward() {
  Eigen::Matrix3d R;
  R << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  return R;
}

SensorOptions noiseless() {
  SensorOptions so;
  so.noise = false;
  so.vignetting = 0.0;
  return so;
}

/// The small simulator camera without lens distortion (straight edges stay straight).
CameraModel pinholeCamera() {
  CameraModel cam = myntEyeSimCamera(0.25);  // 188 x 120
  cam.distortion_coeffs = Vec4::Zero();
  return cam;
}

std::shared_ptr<const Texture> uniformTexture(float value) {
  return std::make_shared<const Texture>(std::vector<float>(64 * 64, value), 64, 64, 0.01, 0.01);
}

SceneObject flatMover(double hx, double hy, const Eigen::Vector3d& p0, const Eigen::Vector3d& v, int texture = 0) {
  SceneObject o;
  o.hx = hx;
  o.hy = hy;
  o.z0 = o.z1 = 0.01;
  o.flat = o.mover = true;
  o.p0_W = p0;
  o.v_W = v;
  o.texture = texture;
  return o;
}

bool sameImage(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

/// Whether the ray of pixel (u, v) from pose P hits the flat object o (at time t) inside its rectangle.
bool rayHitsFlat(const Renderer& r, int u, int v, const CameraPose& P, const SceneObject& o, double t) {
  const Eigen::Vector3d d_O = o.R_WO.transpose() * P.R_WC * r.ray(u, v);
  const Eigen::Vector3d c_O = o.R_WO.transpose() * (P.p_WC - o.positionAt(t));
  if (d_O.z() >= 0.0) return false;
  const double lam = (o.z1 - c_O.z()) / d_O.z();
  const Eigen::Vector3d X = c_O + lam * d_O;
  return std::fabs(X.x()) <= o.hx && std::fabs(X.y()) <= o.hy;
}

std::vector<std::vector<std::string>> readCsv(const std::string& path) {
  std::vector<std::vector<std::string>> rows;
  std::ifstream f(path);
  std::string line;
  while (std::getline(f, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string c;
    while (std::getline(ss, c, ',')) cells.push_back(c);
    rows.push_back(cells);
  }
  return rows;
}

std::vector<std::vector<std::uint8_t>> bagImages(const std::string& path) {
  std::vector<std::vector<std::uint8_t>> out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag))
    if (auto im = m.instantiate<sensor_msgs::Image>()) out.push_back(im->data);
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------
// Rendering

TEST(MoverRender, CoversItsProjectedRectangleAndTheMaskMatchesTheImage) {
  const CameraModel cam = pinholeCamera();
  const Renderer r(cam, 2);
  const Texture ground(std::vector<float>(64 * 64, 50.f), 64, 64, 0.01, 0.01);
  const Clutter clutter({flatMover(0.2013, 0.1207, Eigen::Vector3d(0.0, 0.0, 0.0), Eigen::Vector3d::Zero())},
                        {uniformTexture(200.f)});
  CameraPose P;
  P.R_WC = downward();
  P.p_WC = Eigen::Vector3d(0.0, 0.0, 1.0);
  ClutterMask mask;
  RenderEffects fx;
  fx.clutter = &clutter;
  fx.mask = &mask;
  RowBand band{0, r.height(), {P}, {0.0}};
  const cv::Mat img = r.renderBands({band}, Plane(), ground, 1.0, noiseless(), 0, fx);
  // Expected: the pixel centres inside the rectangle's image, |u - cx| <= hx fx / d, |v - cy| <= hy fy / d.
  const double d = 1.0 - 0.01;
  int expected = 0;
  for (int v = 0; v < r.height(); ++v)
    for (int u = 0; u < r.width(); ++u)
      expected += std::fabs(u - cam.K.cx) <= 0.2013 * cam.K.fx / d && std::fabs(v - cam.K.cy) <= 0.1207 * cam.K.fy / d;
  ASSERT_GT(expected, 500);
  int in_mask = 0, bright = 0, mismatch = 0;
  for (int v = 0; v < r.height(); ++v)
    for (int u = 0; u < r.width(); ++u) {
      const float m = mask.mover[static_cast<std::size_t>(v) * r.width() + u];
      EXPECT_TRUE(m == 0.f || m == 1.f);
      in_mask += m > 0.5f;
      const int g = img.at<unsigned char>(v, u);
      bright += g > 125;
      mismatch += (m > 0.5f) != (g > 125);
      if (m > 0.5f) {
        EXPECT_EQ(g, 200);
      }
    }
  EXPECT_NEAR(in_mask, expected, 2);
  EXPECT_EQ(mismatch, 0);
  EXPECT_EQ(bright, in_mask);
  EXPECT_NEAR(mask.moverFraction(), static_cast<double>(in_mask) / (r.width() * r.height()), 1e-6);
  EXPECT_EQ(mask.boxFraction(), 0.0);
  // The same fraction as the projected area (4 hx hy fx fy / d^2) to within the pixel edges.
  const double area_fraction = 4 * 0.2013 * 0.1207 * cam.K.fx * cam.K.fy / (d * d) / (r.width() * r.height());
  EXPECT_NEAR(mask.moverFraction(), area_fraction, 0.1 * area_fraction);
}

TEST(MoverRender, BoxTopShowsItsTextureAtItsHeight) {
  // A box whose top carries a Gaussian blob: the blob is drawn where the top's 3D point projects (not where the
  // ground point below it would), at the scale of the closer plane, and the sides are drawn too.
  const CameraModel cam = pinholeCamera();  // no distortion: the blob's image is a Gaussian of known size
  const Renderer r(cam, 2);
  const Texture ground(std::vector<float>(64 * 64, 20.f), 64, 64, 0.01, 0.01);
  const double sigma_texels = 4.0, texel = simtest::kBlobTexel_m;
  auto blob = std::make_shared<const Texture>(simtest::blobTexture(sigma_texels));
  SceneObject box;
  box.hx = box.hy = 0.12;
  box.z0 = 0.0;
  box.z1 = 0.3;
  box.p0_W = Eigen::Vector3d(0.0, 0.0, 0.0);
  box.R_WO = Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const double bx = 0.03, by = -0.02;  // the blob on the top, in O
  box.u0_m = (simtest::kBlobI + 0.5) * texel - box.hx - bx;
  box.v0_m = (simtest::kBlobJ + 0.5) * texel - box.hy - by;
  const Clutter clutter({box}, {blob});
  CameraPose P;
  P.R_WC = downward();
  P.p_WC = Eigen::Vector3d(0.25, 0.15, 0.8);
  RenderEffects fx;
  fx.clutter = &clutter;
  ClutterMask mask;
  fx.mask = &mask;
  const cv::Mat img = r.renderBands({{0, r.height(), {P}, {0.0}}}, Plane(), ground, 1.0, noiseless(), 0, fx);
  const Eigen::Vector3d X = box.p0_W + box.R_WO * Eigen::Vector3d(bx, by, box.z1);
  Vec2 px, px_ground;
  ASSERT_TRUE(cam.project(P.R_WC.transpose() * (X - P.p_WC), &px));
  ASSERT_TRUE(cam.project(P.R_WC.transpose() * (X - Eigen::Vector3d(0, 0, box.z1) - P.p_WC), &px_ground));
  EXPECT_GT((px - px_ground).norm(), 10.0);  // the parallax the test tells apart
  // Centroid and spread of the blob (background 20).
  double sw = 0, sx = 0, sy = 0, sxx = 0;
  const int half = 17;
  for (int v = static_cast<int>(px.y()) - half; v <= static_cast<int>(px.y()) + half; ++v)
    for (int u = static_cast<int>(px.x()) - half; u <= static_cast<int>(px.x()) + half; ++u) {
      ASSERT_TRUE(u >= 0 && v >= 0 && u < r.width() && v < r.height());
      const double w = std::max(0.0, img.at<unsigned char>(v, u) - 20.0);
      sw += w, sx += w * u, sy += w * v, sxx += w * ((u - px.x()) * (u - px.x()) + (v - px.y()) * (v - px.y()));
    }
  ASSERT_GT(sw, 0.0);
  EXPECT_NEAR(sx / sw, px.x(), 0.15);
  EXPECT_NEAR(sy / sw, px.y(), 0.15);
  // Scale: blob sigma in pixels = sigma (m) x f / depth of the top (0.5 m), not of the ground (0.8 m). (The
  // 8-bit rounding of the faint tails and the window make the measure a few per cent small.)
  const double sigma_px = std::sqrt(0.5 * sxx / sw);
  const double top_px = sigma_texels * texel * cam.K.fx / (P.p_WC.z() - box.z1);
  EXPECT_NEAR(sigma_px, top_px, 0.08 * top_px);
  // The camera is off to the side: some pixels see a side of the box (more box pixels than the top's area).
  int box_px = 0;
  for (float m : mask.box) box_px += m > 0.5f;
  const double top_area_px = 4 * box.hx * box.hy * cam.K.fx * cam.K.fy / std::pow(P.p_WC.z() - box.z1, 2);
  EXPECT_GT(box_px, 1.05 * top_area_px);
  EXPECT_LT(box_px, 2.0 * top_area_px);
  EXPECT_EQ(mask.moverFraction(), 0.0);
}

TEST(MoverRender, WithoutVisibleObjectsTheImageIsBitIdentical) {
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
  const SensorOptions so;
  const SpecularPatches spec(5, 0.3);
  // An empty scene, and a mover far away: both give the images of the ground-only renderer.
  const Clutter empty;
  const Clutter far({flatMover(0.3, 0.2, Eigen::Vector3d(30.0, 0.0, 5.3), Eigen::Vector3d(1, 0, 0))},
                    {uniformTexture(200.f)});
  for (const double readout : {0.0, 0.016}) {
    for (const SpecularPatches* s : {static_cast<const SpecularPatches*>(nullptr), &spec}) {
      SCOPED_TRACE(::testing::Message() << "readout " << readout << " specular " << (s != nullptr));
      const std::vector<RowBand> bands = rollingShutterBands(pose_at, 0.3, r.height(), readout, 0.004, 3);
      RenderEffects plain;
      plain.specular = s;
      const cv::Mat ref = r.renderBands(bands, plane, tex, 1.1, so, 77, plain);
      for (const Clutter* c : {&empty, &far}) {
        RenderEffects fx = plain;
        fx.clutter = c;
        ClutterMask mask;
        fx.mask = &mask;
        EXPECT_TRUE(sameImage(r.renderBands(bands, plane, tex, 1.1, so, 77, fx), ref));
        EXPECT_EQ(mask.anyFraction(), 0.0);
        EXPECT_EQ(mask.mover.size(), static_cast<std::size_t>(r.width() * r.height()));
      }
    }
  }
  // Movers need the sub-frame times.
  RenderEffects fx;
  fx.clutter = &far;
  EXPECT_THROW(r.renderBands({{0, r.height(), {P0}, {}}}, plane, tex, 1.0, so, 0, fx), std::invalid_argument);
}

TEST(MoverRender, RollingShutterAndMotionBlurSeeTheMoverAtItsOwnTimes) {
  // Static camera, a mover crossing along x_W (image u) at 2 m/s: each pixel's mask is the fraction of its
  // row's sub-frame times at which its ray hits the mover (computed here independently).
  const CameraModel cam = pinholeCamera();
  const Renderer r(cam, 2);
  const Texture ground(std::vector<float>(64 * 64, 50.f), 64, 64, 0.01, 0.01);
  const SceneObject o = flatMover(0.1, 0.6, Eigen::Vector3d(-0.05, 0.0, 0.0), Eigen::Vector3d(2.0, 0.0, 0.0));
  const Clutter clutter({o}, {uniformTexture(200.f)});
  CameraPose P;
  P.R_WC = downward();
  P.p_WC = Eigen::Vector3d(0.0, 0.0, 0.6);
  const auto pose_at = [&](double) { return P; };
  struct Case {
    double readout, exposure;
    int n_sub;
  };
  for (const Case& c : {Case{0.030, 0.0, 1}, Case{0.0, 0.010, 4}, Case{0.020, 0.008, 3}}) {
    SCOPED_TRACE(::testing::Message() << "readout " << c.readout << " exposure " << c.exposure);
    const std::vector<RowBand> bands = rollingShutterBands(pose_at, 0.0, r.height(), c.readout, c.exposure, c.n_sub);
    RenderEffects fx;
    fx.clutter = &clutter;
    ClutterMask mask;
    fx.mask = &mask;
    r.renderBands(bands, Plane(), ground, 1.0, noiseless(), 0, fx);
    int mismatch = 0, fractional = 0, covered = 0;
    std::vector<double> front(r.height(), -1.0);  // last covered column per row
    for (const RowBand& b : bands)
      for (int v = b.row0; v < b.row1; ++v)
        for (int u = 0; u < r.width(); ++u) {
          double expected = 0.0;
          for (std::size_t j = 0; j < b.poses.size(); ++j)
            expected += rayHitsFlat(r, u, v, b.poses[j], o, b.times[j]) ? 1.0 / b.poses.size() : 0.0;
          const float m = mask.mover[static_cast<std::size_t>(v) * r.width() + u];
          mismatch += std::fabs(m - expected) > 1e-4;
          fractional += m > 0.01f && m < 0.99f;
          covered += m > 0.5f;
          if (m > 0.5f) front[v] = u;
        }
    EXPECT_LE(mismatch, 2);  // float rounding exactly at an edge
    EXPECT_GT(covered, 1000);
    if (c.n_sub > 1) {
      // The blur: 2 m/s over the exposure moves the edges by ~ fx v T / d pixels, intermediate mask values there.
      const double blur_px = cam.K.fx * 2.0 * c.exposure / 0.59;
      EXPECT_GT(fractional, r.height() * std::max(1.0, blur_px - 2.0));
    } else {
      EXPECT_EQ(fractional, 0);
    }
    if (c.readout > 0.0) {
      // Rows read out later see the mover further along: front edge shear ~ fx v readout / d.
      const double shear = front[r.height() - 1] - front[0];
      EXPECT_NEAR(shear, cam.K.fx * 2.0 * c.readout / 0.59, 1.5);
    }
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Generation

TEST(ClutterGeneration, MoversCrossWhereTheCameraLooksAndBoxesDoNotOverlap) {
  const Plane plane = Plane::inclined(15.0, 30.0);
  const auto look_at = [&](double t) {
    const Eigen::Vector3d X(0.3 * std::sin(0.5 * t), 0.5 * t, 0.0);
    return Eigen::Vector3d(X.x(), X.y(), plane.zAt(X.x(), X.y()));
  };
  ClutterOptions o;
  o.movers = 2;
  o.mover_interval_s = 5.0;
  o.boxes = 12;
  o.mover_texture = "checkerboard";
  o.box_texture = "checkerboard";
  const Clutter c = makeClutter(o, plane, look_at, 20.0, 4);
  int movers = 0, boxes = 0;
  for (const SceneObject& ob : c.objects()) {
    // Objects stand on the plane, upright to it.
    EXPECT_NEAR(plane.n.dot(ob.p0_W) + plane.e_m, 0.0, 1e-9);
    EXPECT_NEAR(ob.R_WO.col(2).dot(plane.n), 1.0, 1e-12);
    EXPECT_NEAR((ob.R_WO.transpose() * ob.R_WO - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    if (ob.mover) {
      ++movers;
      EXPECT_TRUE(ob.flat);
      // Crossing time on the schedule, path through the look-at point (+-0.15 m sideways), speed 0.8-1.2 x.
      const double phase = std::fmod(ob.t0_s / o.mover_interval_s, 1.0);
      EXPECT_TRUE(std::fabs(phase - 0.25) < 1e-9 || std::fabs(phase - 0.75) < 1e-9) << ob.t0_s;
      EXPECT_LE((ob.positionAt(ob.t0_s) - look_at(ob.t0_s)).norm(), 0.15 + 1e-9);
      EXPECT_NEAR(ob.v_W.dot(plane.n), 0.0, 1e-12);
      EXPECT_GE(ob.v_W.norm(), 0.8 * o.mover_speed_mps - 1e-12);
      EXPECT_LE(ob.v_W.norm(), 1.2 * o.mover_speed_mps + 1e-12);
      EXPECT_NEAR(2 * ob.hx, o.mover_size_m, 1e-12);
      EXPECT_NEAR(ob.hy / ob.hx, o.mover_aspect, 1e-12);
    } else {
      ++boxes;
      EXPECT_EQ(ob.v_W.norm(), 0.0);
      EXPECT_EQ(ob.z1, o.box_height_m);
      EXPECT_GE(2 * ob.hx, 0.75 * o.box_size_m - 1e-12);
      EXPECT_LE(2 * ob.hx, 1.25 * o.box_size_m + 1e-12);
    }
  }
  EXPECT_EQ(movers, 5 + 4);  // crossings at 1.25, 6.25, ... and 3.75, 8.75, ... up to 20 + 2.5 s
  EXPECT_EQ(boxes, 12);
  for (std::size_t i = 0; i < c.objects().size(); ++i)
    for (std::size_t j = i + 1; j < c.objects().size(); ++j) {
      const SceneObject &a = c.objects()[i], &b = c.objects()[j];
      if (a.mover || b.mover) continue;
      EXPECT_GT((a.p0_W - b.p0_W).norm(), std::hypot(a.hx, a.hy) + std::hypot(b.hx, b.hy)) << i << " " << j;
    }
  // Deterministic for the seed, different across seeds.
  const Clutter again = makeClutter(o, plane, look_at, 20.0, 4), other = makeClutter(o, plane, look_at, 20.0, 5);
  ASSERT_EQ(again.objects().size(), c.objects().size());
  for (std::size_t i = 0; i < c.objects().size(); ++i) EXPECT_EQ(again.objects()[i].p0_W, c.objects()[i].p0_W);
  EXPECT_NE(other.objects()[0].p0_W, c.objects()[0].p0_W);
  EXPECT_TRUE(makeClutter(ClutterOptions(), plane, look_at, 20.0, 4).empty());
}

// ---------------------------------------------------------------------------------------------------------------
// Whole simulations (tiny images)

namespace {

SimulationOptions tinyOptions(const std::string& dir) {
  SimulationOptions o;
  o.preset = "flight4";
  o.texture = "checkerboard";  // quick to build
  o.duration_s = 2.0;
  o.scale = 0.125;  // 94 x 60
  o.threads = 2;
  o.output_dir = dir;
  return o;
}

}  // namespace

TEST(ClutterSim, OcclusionCsvMatchesTheImagesAndTheSummary) {
  simtest::TempDir dir;
  SimulationOptions clean = tinyOptions((dir.path() / "clean").string());
  SimulationOptions movers = tinyOptions((dir.path() / "movers").string());
  movers.clutter.movers = 1;
  movers.clutter.mover_interval_s = 4.0;  // one crossing, at t = 2 s: in view over the last ~0.8 s
  movers.clutter.mover_speed_mps = 1.5;
  movers.clutter.mover_size_m = 0.6;
  movers.clutter.mover_texture = "checkerboard";
  SimulationOptions none = tinyOptions((dir.path() / "none").string());
  std::string err;
  ASSERT_EQ(parseSimulateArgs({"--movers", "0", "--boxes", "0", "--output", none.output_dir}, &none, &err),
            ParseResult::kOk);
  const auto a = bagImages(runSimulation(clean, nullptr).bag_path);
  const auto b = bagImages(runSimulation(movers, nullptr).bag_path);
  // N = 0: the same bag images as without the options, and no clutter files.
  EXPECT_EQ(bagImages(runSimulation(none, nullptr).bag_path), a);
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "none" / "occlusion.csv"));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "clean" / "clutter.yaml"));
  // occlusion.csv: one row per image; where nothing is covered the image is the clean one, bit for bit.
  const auto rows = readCsv((dir.path() / "movers" / "occlusion.csv").string());
  ASSERT_EQ(rows.size(), b.size() + 1);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(rows[0], (std::vector<std::string>{"frame", "t_s", "stamp_ns", "mover_fraction", "box_fraction",
                                                "total_fraction"}));
  int covered = 0, free = 0;
  double sum = 0, mx = 0;
  for (std::size_t i = 0; i < b.size(); ++i) {
    const auto& row = rows[i + 1];
    ASSERT_EQ(row.size(), 6u);
    const double fm = std::stod(row[3]);
    EXPECT_EQ(std::stod(row[4]), 0.0);
    EXPECT_NEAR(std::stod(row[5]), fm, 1e-12);
    EXPECT_NEAR(std::stod(row[1]), (i + 1) / 30.0, 1e-9);
    sum += fm;
    mx = std::max(mx, fm);
    if (fm == 0.0) {
      ++free;
      EXPECT_EQ(b[i], a[i]) << "image " << i;
    } else if (fm > 0.01) {
      ++covered;
      EXPECT_NE(b[i], a[i]) << "image " << i;
    }
  }
  EXPECT_GT(covered, 10);
  EXPECT_GT(free, 3);
  EXPECT_GT(mx, 0.05);  // a 0.6 m x 0.36 m object under a ~1.7 m x 1.1 m view: ~12 % when fully in view
  EXPECT_LT(mx, 0.3);
  const YAML::Node y = YAML::LoadFile((dir.path() / "movers" / "clutter.yaml").string());
  EXPECT_EQ(y["movers"].as<int>(), 1);
  EXPECT_EQ(y["boxes"].as<int>(), 0);
  EXPECT_EQ(y["frames"].as<int>(), static_cast<int>(b.size()));
  EXPECT_NEAR(y["mover_coverage_mean"].as<double>(), sum / b.size(), 1e-9);
  EXPECT_NEAR(y["mover_coverage_max"].as<double>(), mx, 1e-12);
  EXPECT_EQ(y["objects"].size(), 1u);
}

TEST(ClutterSim, BoxesAndMoversTwoSecondsRender) {
  // A 2 s flight at 188 x 120 with movers and boxes together (the time is printed, not asserted).
  simtest::TempDir dir;
  SimulationOptions o = tinyOptions(dir.str());
  o.scale = 0.25;
  o.realism.rolling_shutter_ms = 16.0;
  o.clutter.movers = 2;
  o.clutter.mover_interval_s = 2.0;
  o.clutter.boxes = 4;
  o.clutter.box_size_m = 0.2;
  o.clutter.box_height_m = 0.2;
  const auto t0 = std::chrono::steady_clock::now();
  const SimulationSummary s = runSimulation(o, nullptr);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::cout << "[ info ] 2 s at 188x120 with 2 movers, 4 boxes and a rolling shutter: " << wall << " s, "
            << s.frames_written << " images, coverage movers mean " << s.mover_coverage_mean << " boxes mean "
            << s.box_coverage_mean << "\n";
  EXPECT_EQ(s.frames_written, 59);
  EXPECT_GT(s.box_coverage_mean, 0.03);   // placed along the ground track: in view
  EXPECT_GT(s.mover_coverage_max, 0.02);
  EXPECT_LT(s.mover_coverage_mean + s.box_coverage_mean, 0.8);
  const YAML::Node y = YAML::LoadFile((dir.path() / "clutter.yaml").string());
  EXPECT_GE(y["boxes_placed"].as<int>(), 3);  // around the hover point (2 s): some candidates overlap
  EXPECT_LE(y["boxes_placed"].as<int>(), 4);
  EXPECT_NEAR(y["box_coverage_max"].as<double>(), s.box_coverage_max, 1e-12);
}

TEST(ClutterSim, BoxesTallerThanTheFlightAreRejected) {
  SimulationOptions o = tinyOptions("unused");
  o.clutter.boxes = 3;
  o.clutter.box_height_m = 2.0;  // above the camera
  const Trajectory traj = makeTrajectory(o);
  try {
    makeSimulationClutter(o, traj, myntEyeSimCamera(0.125));
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("--box-height-m"), std::string::npos) << e.what();
  }
  o.clutter.box_height_m = 0.2;
  o.clutter.box_texture = "checkerboard";
  EXPECT_EQ(makeSimulationClutter(o, traj, myntEyeSimCamera(0.125)).objects().size(), 3u);
}

TEST(SimulatorCli, MoverAndBoxOptions) {
  std::string err;
  SimulationOptions d;
  ASSERT_EQ(parseSimulateArgs({"--output", "x"}, &d, &err), ParseResult::kOk);
  EXPECT_FALSE(d.clutter.any());
  SimulationOptions o;
  ASSERT_EQ(parseSimulateArgs({"--movers", "2", "--mover-size-m", "0.8", "--mover-aspect=0.5", "--mover-speed-mps",
                               "1.5", "--mover-interval-s", "4", "--mover-texture", "dirt", "--boxes", "7",
                               "--box-size-m", "0.3", "--box-height-m", "0.25", "--box-texture", "natural",
                               "--output", "x"},
                              &o, &err),
            ParseResult::kOk)
      << err;
  EXPECT_EQ(o.clutter.movers, 2);
  EXPECT_EQ(o.clutter.mover_size_m, 0.8);
  EXPECT_EQ(o.clutter.mover_aspect, 0.5);
  EXPECT_EQ(o.clutter.mover_speed_mps, 1.5);
  EXPECT_EQ(o.clutter.mover_interval_s, 4.0);
  EXPECT_EQ(o.clutter.mover_texture, "dirt");
  EXPECT_EQ(o.clutter.boxes, 7);
  EXPECT_EQ(o.clutter.box_size_m, 0.3);
  EXPECT_EQ(o.clutter.box_height_m, 0.25);
  EXPECT_EQ(o.clutter.box_texture, "natural");
  const std::vector<std::vector<std::string>> bad = {{"--movers", "-1", "--output", "x"},
                                                     {"--movers", "65", "--output", "x"},
                                                     {"--boxes", "1.5", "--output", "x"},
                                                     {"--mover-size-m", "0", "--output", "x"},
                                                     {"--mover-speed-mps", "-1", "--output", "x"},
                                                     {"--box-height-m", "x", "--output", "x"},
                                                     {"--box-texture", "", "--output", "x"},
                                                     {"--movers"}};
  for (const auto& args : bad) {
    err.clear();
    SimulationOptions fresh;
    EXPECT_EQ(parseSimulateArgs(args, &fresh, &err), ParseResult::kError) << args[0];
    EXPECT_FALSE(err.empty());
  }
  for (const char* flag : {"--movers", "--mover-size-m", "--mover-aspect", "--mover-speed-mps", "--mover-interval-s",
                           "--mover-texture", "--boxes", "--box-size-m", "--box-height-m", "--box-texture",
                           "occlusion.csv"})
    EXPECT_NE(simulateUsage().find(flag), std::string::npos) << flag;
}
