// VignettingLearner (docs/noise_model.md section 11, "Vignetting from the motion"): the lens's radial vignetting
// from the same ground seen at two places of the image, against the ground's own large-scale structure.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "diekf/vignetting_learner.h"

namespace diekf {
namespace {

constexpr int kW = 120, kH = 80;
constexpr double kCx = 70.0, kCy = 35.0;  // the principal point, off the image's centre

/// A large piece of ground: smooth random texture (spread about 25 % of its level) under a bright region of
/// `bump` times the level, broader than the image, at the middle of the ground.
cv::Mat bigGround(cv::RNG* rng, double bump) {
  cv::Mat g(400, 400, CV_32FC1);
  rng->fill(g, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(g, g, cv::Size(0, 0), 1.5);
  cv::Scalar m, sd;
  cv::meanStdDev(g, m, sd);
  for (int y = 0; y < g.rows; ++y)
    for (int x = 0; x < g.cols; ++x) {
      const double r2 = ((x - 200.0) * (x - 200.0) + (y - 200.0) * (y - 200.0)) / (90.0 * 90.0);
      const double level = 100.0 * (1.0 + bump * std::exp(-0.5 * r2));
      g.at<float>(y, x) = static_cast<float>(level * (1.0 + 0.25 * (g.at<float>(y, x) - m[0]) / sd[0]));
    }
  return g;
}

/// ln V of the lens of the tests, 1 - 0.3 s - 0.05 s^2 (s = r^2, 1 at the farthest corner).
cv::Mat lens(double strength) {
  cv::Mat v(kH, kW, CV_32FC1);
  const double dx = std::max(kCx, kW - 1 - kCx), dy = std::max(kCy, kH - 1 - kCy);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const double s = ((x - kCx) * (x - kCx) + (y - kCy) * (y - kCy)) / (dx * dx + dy * dy);
      v.at<float>(y, x) = static_cast<float>(1.0 - strength * (0.3 * s + 0.05 * s * s));
    }
  return v;
}

struct Learned {
  bool ok = false;
  double corner_ln = 0.0, sigma = 0.0;
  double mean_corner_over_centre = 0.0;  // the temporal mean's corner against its centre (what a mean-based fit sees)
};

/// A camera circling over the middle of the ground (radius 25 px, 2.5 px per image), its exposure changing, the
/// lens of `strength`; every pair given to `learner` with its exact map. Returns the images' temporal mean.
cv::Mat circle(VignettingLearner* learner, double strength, double bump, int images) {
  cv::RNG rng(21);
  const cv::Mat ground = bigGround(&rng, bump), vig = lens(strength);
  cv::Mat prev, sum(kH, kW, CV_32FC1, cv::Scalar(0.f));
  cv::Point2f prev_c;
  for (int i = 0; i < images; ++i) {
    const double a = 0.1 * i;
    const cv::Point2f c(static_cast<float>(200.0 + 25.0 * std::cos(a)), static_cast<float>(200.0 + 25.0 * std::sin(a)));
    cv::Mat view;
    cv::getRectSubPix(ground, cv::Size(kW, kH), c, view, CV_32F);
    const double exposure = 0.8 + 0.4 * rng.uniform(0.0, 1.0);
    cv::Mat img = exposure * view.mul(vig);
    cv::Mat u = img / cv::mean(img)[0];
    sum += u;
    if (i > 0) {
      // The current image's pixel x sees the ground at x + c - centre; the reference sees it at x + c - prev_c.
      Vec2* t = learner->gridTargets();
      for (int j = 0; j < learner->gridRows(); ++j)
        for (int k = 0; k < learner->gridCols(); ++k)
          t[j * learner->gridCols() + k] = Vec2(k * VignettingLearner::kGridPx + (c.x - prev_c.x),
                                                j * VignettingLearner::kGridPx + (c.y - prev_c.y));
      learner->observe(u.ptr<float>(), prev.ptr<float>());
    }
    prev = u;
    prev_c = c;
  }
  return sum / images;
}

/// circle() with a new learner, and what it learned.
Learned fly(double strength, double bump, int images) {
  VignettingLearner learner;
  learner.configure(kW, kH, kCx, kCy);
  const cv::Mat mean = circle(&learner, strength, bump, images);
  Learned out;
  double a1 = 0.0, a2 = 0.0;
  out.ok = learner.estimate(&a1, &a2, &out.sigma);
  out.corner_ln = a1 + a2;
  const cv::Rect centre(static_cast<int>(kCx) - 5, static_cast<int>(kCy) - 5, 10, 10), corner(0, kH - 10, 10, 10);
  out.mean_corner_over_centre = cv::mean(mean(corner))[0] / cv::mean(mean(centre))[0];
  std::printf("[ vignetting ] lens %.1f, ground bump %.1f: corner ln V %+.4f +- %.4f (truth %+.4f) after %d pairs; "
              "the temporal mean's corner / centre %.3f\n",
              strength, bump, out.corner_ln, out.sigma, std::log(1.0 - 0.35 * strength), learner.pairs(),
              out.mean_corner_over_centre);
  return out;
}

// The lens is found from the ground's motion, through exposure changes.
TEST(VignettingLearner, FindsTheLensFromTheGroundsMotion) {
  const Learned l = fly(1.0, 0.0, 200);
  ASSERT_TRUE(l.ok);
  const double truth = std::log(0.65);
  EXPECT_NEAR(l.corner_ln, truth, 0.02);
  EXPECT_LT(std::abs(l.corner_ln - truth), 3.0 * l.sigma + 0.005);
  EXPECT_LT(l.sigma, 0.02);
}

// Every pair is asked for until the corner is known to kSettledSigmaLn, then every kSettledEvery-th.
TEST(VignettingLearner, OnceSettledEveryFourthPairIsAskedFor) {
  VignettingLearner learner;
  learner.configure(kW, kH, kCx, kCy);
  int asked = 0;
  for (int i = 0; i < 40; ++i) asked += learner.due() ? 1 : 0;
  EXPECT_EQ(asked, 40);  // nothing learned: not settled
  // Settled: the lens of the tests learned from 200 pairs (FindsTheLensFromTheGroundsMotion: 1-sigma 0.007).
  circle(&learner, 1.0, 0.0, 200);
  asked = 0;
  for (int i = 0; i < 40; ++i) asked += learner.due() ? 1 : 0;
  EXPECT_EQ(asked, 40 / VignettingLearner::kSettledEvery);
}

// A bright region of the ground broader than the image, under a camera that circles over it, darkens the temporal
// mean towards the image's rim like a lens would; the learner sees the same ground point at both places and finds
// no vignetting, and with a lens it finds the lens alone.
TEST(VignettingLearner, TheGroundsLargeStructureIsNotVignetting) {
  const Learned flat = fly(0.0, 0.6, 200);
  ASSERT_TRUE(flat.ok);
  EXPECT_LT(flat.mean_corner_over_centre, 0.9);  // what a fit to the mean would take for a lens
  EXPECT_LT(std::abs(flat.corner_ln), 0.02);
  EXPECT_LT(std::abs(flat.corner_ln), 3.0 * flat.sigma + 0.005);
  const Learned both = fly(1.0, 0.6, 200);
  ASSERT_TRUE(both.ok);
  EXPECT_NEAR(both.corner_ln, std::log(0.65), 0.02);
}

// Too few pairs give no estimate; a still camera (every pair the same ground at the same place) teaches nothing.
TEST(VignettingLearner, NoEstimateWithoutEnoughMotion) {
  VignettingLearner learner;
  learner.configure(kW, kH, kCx, kCy);
  cv::RNG rng(4);
  const cv::Mat ground = bigGround(&rng, 0.0);
  const cv::Mat u = ground(cv::Rect(100, 100, kW, kH)).clone() / 100.0;
  for (int i = 0; i < 2 * VignettingLearner::kMinPairs; ++i) {
    Vec2* t = learner.gridTargets();
    for (int j = 0; j < learner.gridRows(); ++j)
      for (int k = 0; k < learner.gridCols(); ++k)
        t[j * learner.gridCols() + k] = Vec2(k * VignettingLearner::kGridPx, j * VignettingLearner::kGridPx);
    if (i < VignettingLearner::kMinPairs - 1) {
      double a1, a2, s;
      EXPECT_FALSE(learner.estimate(&a1, &a2, &s));
    }
    learner.observe(u.ptr<float>(), u.ptr<float>());
  }
  double a1 = 0.0, a2 = 0.0, s = 0.0;
  EXPECT_FALSE(learner.estimate(&a1, &a2, &s));  // no radial difference between the two places: singular
}

}  // namespace
}  // namespace diekf
