// Procedural natural textures (grass, leaves, dirt): determinism, physical scale, contrast and gradient statistics.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "diekf/sim/renderer.h"
#include "diekf/sim/sequence_io.h"
#include "diekf/sim/texture.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

constexpr double kTexel_m = 0.001;
constexpr int kTile = 1024;  // 1.02 m tiles keep the tests fast; the statistics are per area

struct Stats {
  double mean = 0, sd = 0;
  double coherence = 0;       ///< (l1 - l2) / (l1 + l2) of the summed gradient structure tensor: 0 isotropic, 1 one direction
  double gradient_dir_deg = 0;  ///< dominant gradient direction in the tile's (u, v) axes, in [-90, 90)
  double rms_contrast() const { return sd / mean; }
};

/// Grey-level statistics of one mip level (level L averages 2^L x 2^L level-0 texels).
Stats levelStats(const Texture& t, int level) {
  const int w = t.width(level), h = t.height(level);
  Stats s;
  double sum = 0, sum2 = 0, jxx = 0, jyy = 0, jxy = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double v = t.at(level, x, y);
      sum += v;
      sum2 += v * v;
      const double gx = t.at(level, x + 1, y) - t.at(level, x - 1, y);
      const double gy = t.at(level, x, y + 1) - t.at(level, x, y - 1);
      jxx += gx * gx;
      jyy += gy * gy;
      jxy += gx * gy;
    }
  const double n = static_cast<double>(w) * h;
  s.mean = sum / n;
  s.sd = std::sqrt(std::max(0.0, sum2 / n - s.mean * s.mean));
  s.coherence = std::sqrt((jxx - jyy) * (jxx - jyy) + 4 * jxy * jxy) / (jxx + jyy);
  s.gradient_dir_deg = 0.5 * std::atan2(2 * jxy, jxx - jyy) * 180.0 / M_PI;
  return s;
}

/// Level whose texels are about `size_m` wide.
int levelFor(const Texture& t, double size_m) { return static_cast<int>(std::lround(std::log2(size_m / t.texelU()))); }

double angleDiffDeg(double a, double b) {  // difference of two axis directions (mod 180), in [0, 90]
  double d = std::fmod(std::abs(a - b), 180.0);
  return d > 90.0 ? 180.0 - d : d;
}

bool sameLevel0(const Texture& a, const Texture& b) {
  for (int y = 0; y < a.height(); y += 7)
    for (int x = 0; x < a.width(); x += 5)
      if (a.at(0, x, y) != b.at(0, x, y)) return false;
  return true;
}

Texture make(const std::string& name, std::uint64_t seed) {
  if (name == "grass") return Texture::grass(seed, kTexel_m, kTile);
  if (name == "leaves") return Texture::leaves(seed, kTexel_m, kTile);
  return Texture::dirt(seed, kTexel_m, kTile);
}

class NaturalTextures : public ::testing::TestWithParam<std::string> {};

TEST_P(NaturalTextures, DeterministicPerSeedAndPhysicallyScaled) {
  const Texture a = make(GetParam(), 7), b = make(GetParam(), 7), c = make(GetParam(), 8);
  EXPECT_TRUE(sameLevel0(a, b)) << "same seed, different texture";
  EXPECT_FALSE(sameLevel0(a, c)) << "different seeds, same texture";
  EXPECT_DOUBLE_EQ(a.texelU(), kTexel_m);
  EXPECT_NEAR(a.tileU(), kTile * kTexel_m, 1e-12);
  // Default tiles: 1 mm texels over 4.1 m, wider than the view from 1.3 m (about 2.7 m), so no repetition in view.
  // Every grey level is a valid 8-bit value.
  const Stats s = levelStats(a, 0);
  EXPECT_GT(s.mean, 60.0);
  EXPECT_LT(s.mean, 160.0);
  for (int y = 0; y < a.height(); y += 13)
    for (int x = 0; x < a.width(); x += 11) {
      ASSERT_GE(a.at(0, x, y), 0.f);
      ASSERT_LE(a.at(0, x, y), 255.f);
    }
}

TEST_P(NaturalTextures, SameStatisticsAtTwiceTheTexelDensity) {
  // The texture is defined in metres: halving the texel size (same physical tile) keeps the statistics seen at
  // 8 mm (the footprint of a 180 px working pixel from ~0.4 m) within 20 %.
  const Texture fine = GetParam() == "grass"    ? Texture::grass(3, 0.0005, 2 * kTile)
                       : GetParam() == "leaves" ? Texture::leaves(3, 0.0005, 2 * kTile)
                                                : Texture::dirt(3, 0.0005, 2 * kTile);
  const Texture coarse = make(GetParam(), 3);
  const Stats sf = levelStats(fine, levelFor(fine, 0.008)), sc = levelStats(coarse, levelFor(coarse, 0.008));
  EXPECT_NEAR(sf.sd / sc.sd, 1.0, 0.2) << "fine sd " << sf.sd << ", coarse sd " << sc.sd;
  EXPECT_NEAR(sf.mean, sc.mean, 5.0);
}

INSTANTIATE_TEST_SUITE_P(Sim, NaturalTextures, ::testing::Values("grass", "leaves", "dirt"));

TEST(NaturalTextures, DirtHasLowContrast) {
  const Stats dirt = levelStats(make("dirt", 1), 0);
  const Stats checker = levelStats(Texture::checkerboard(), 0);
  const Stats grass = levelStats(make("grass", 1), 0);
  const Stats leaves = levelStats(make("leaves", 1), 0);
  EXPECT_LT(dirt.rms_contrast(), 0.15);
  EXPECT_LT(dirt.rms_contrast(), 0.25 * checker.rms_contrast());
  EXPECT_LT(dirt.rms_contrast(), 0.5 * grass.rms_contrast());
  EXPECT_LT(dirt.rms_contrast(), 0.5 * leaves.rms_contrast());
  // Leaves, with their dark gaps and shadows, have the most contrast of the three.
  EXPECT_GT(leaves.rms_contrast(), grass.rms_contrast());
}

TEST(NaturalTextures, GrassGradientsAreAnisotropicAcrossTheBlades) {
  for (const double dir_deg : {30.0, -60.0}) {
    const Texture g = Texture::grass(1, kTexel_m, kTile, dir_deg);
    const Stats s = levelStats(g, 0);
    EXPECT_GT(s.coherence, 0.4) << dir_deg;
    // Gradients point across the blades, i.e. perpendicular to their direction.
    EXPECT_LT(angleDiffDeg(s.gradient_dir_deg, dir_deg + 90.0), 10.0) << "gradient direction " << s.gradient_dir_deg;
  }
  // Leaves and dirt are isotropic at the millimetre scale.
  EXPECT_LT(levelStats(make("leaves", 1), 0).coherence, 0.1);
  EXPECT_LT(levelStats(make("dirt", 1), 0).coherence, 0.1);
}

TEST(NaturalTextures, FineTexturesLoseContrastWhenAveragedOverAWorkingPixel) {
  // A 90 px working pixel seen from 0.8 m covers about 18 mm of ground (16 mm: mip level 4 of 1 mm texels).
  // Grass and dirt keep most of their structure at millimetre scales: averaged over 16 mm, grass keeps less than
  // 60 % of its standard deviation and its millimetre gradients are gone (coherence drops), while a 5 cm
  // checkerboard keeps all of it. Leaves, with centimetre structure, keep more than grass.
  const Texture grass = make("grass", 1), leaves = make("leaves", 1), dirt = make("dirt", 1);
  const Texture checker = Texture::checkerboard();
  const auto kept = [](const Texture& t) { return levelStats(t, levelFor(t, 0.016)).sd / levelStats(t, 0).sd; };
  EXPECT_LT(kept(grass), 0.6);
  EXPECT_GT(kept(checker), 0.95);
  EXPECT_GT(kept(leaves), kept(grass) + 0.1);
  EXPECT_LT(levelStats(grass, 4).coherence, levelStats(grass, 0).coherence - 0.15);
  // Dirt at 16 mm: under 10 grey levels of standard deviation left (the checkerboard keeps 80).
  EXPECT_LT(levelStats(dirt, levelFor(dirt, 0.016)).sd, 11.0);
  EXPECT_GT(levelStats(dirt, levelFor(dirt, 0.016)).sd, 3.0);  // but not featureless
}

TEST(NaturalTextures, LeavesHaveDarkGapsAndCentimetreStructure) {
  const Texture t = make("leaves", 2);
  long dark = 0, total = 0;
  for (int y = 0; y < t.height(); y += 3)
    for (int x = 0; x < t.width(); x += 3, ++total) dark += t.at(0, x, y) < 45.f;
  const double frac = static_cast<double>(dark) / total;
  EXPECT_GT(frac, 0.03) << "gaps and shadows";
  EXPECT_LT(frac, 0.35);
  // Leaves are 3-8 cm: structure survives averaging over 16 mm but mostly not over 128 mm.
  EXPECT_GT(levelStats(t, 4).sd, 0.6 * levelStats(t, 0).sd);
  EXPECT_LT(levelStats(t, 7).sd, 0.3 * levelStats(t, 0).sd);
}

TEST(NaturalTextures, ByNameBuildsEveryProceduralTexture) {
  for (const char* name : {"checkerboard", "natural", "grass", "leaves", "dirt"}) EXPECT_TRUE(Texture::isProcedural(name));
  EXPECT_FALSE(Texture::isProcedural("gras"));
  EXPECT_FALSE(Texture::isProcedural("grass.png"));
  // Not a known name: read as an image file, which fails with the file's name.
  try {
    Texture::byName("gras", 1, 0.05, 1.0);
    FAIL() << "expected an exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("gras"), std::string::npos);
  }
  EXPECT_THROW(Texture::grass(1, kTexel_m, 1000), std::invalid_argument);
  EXPECT_THROW(Texture::dirt(1, 0.0, kTile), std::invalid_argument);
  const Texture d = Texture::byName("dirt", 4, 0.05, 1.0);
  EXPECT_DOUBLE_EQ(d.texelU(), 0.001);
  EXPECT_NEAR(d.tileU(), 4.096, 1e-9);
}

TEST(NaturalTextures, RenderedThroughTheMipPath) {
  // From 1.3 m a full-resolution pixel covers ~3.6 mm: the renderer averages grass blades (mip levels), so the
  // image has less contrast than the 1 mm texture but keeps more than the texture averaged over a 90 px pixel.
  const Texture g = make("grass", 1);
  const Renderer r(myntEyeSimCamera(1.0), 1);
  CameraPose P;
  P.R_WC << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  P.p_WC = Eigen::Vector3d(0.3, 0.2, 1.3);
  SensorOptions so;
  so.noise = false;
  so.vignetting = 0.0;
  const cv::Mat img = r.renderImage({P}, Plane(), g, 1.0, so, 0);
  cv::Scalar mean, sd;
  cv::meanStdDev(img(cv::Rect(200, 100, 352, 280)), mean, sd);
  EXPECT_NEAR(mean[0], levelStats(g, 0).mean, 10.0);
  EXPECT_LT(sd[0], 0.95 * levelStats(g, 0).sd);
  EXPECT_GT(sd[0], levelStats(g, levelFor(g, 0.03)).sd);
}

}  // namespace
