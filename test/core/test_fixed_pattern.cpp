// FixedPattern (docs/noise_model.md section 11): the camera-fixed gain and offset learned from the temporal
// statistics of the working images, the start-up, the significance shrinkage, the confidence, and the motion
// that counts as a new sample.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "diekf/fixed_pattern.h"
#include "diekf/image_preprocessor.h"

#include "mynt_camera.h"

namespace diekf {
namespace {

constexpr int kW = 120, kH = 80;

/// A new, independent piece of ground: smooth random texture, mean about 100 grey levels, spread about 25.
cv::Mat ground(cv::RNG* rng) {
  cv::Mat big(kH + 20, kW + 20, CV_32FC1);  // blurred with a margin: the same spread at every pixel
  rng->fill(big, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(big, big, cv::Size(0, 0), 1.5);
  cv::Mat g = big(cv::Rect(10, 10, kW, kH)).clone();
  cv::Scalar m, sd;
  cv::meanStdDev(g, m, sd);
  g = (g - m[0]) * (25.0 / sd[0]) + 100.0;
  return g;
}

/// A wide piece of ground to crop moving views from: smooth random texture drawn from rng, mean 100 grey levels,
/// spread 25.
cv::Mat wideGround(int rows, int cols, cv::RNG* rng) {
  cv::Mat big(rows, cols, CV_32FC1);
  rng->fill(big, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(big, big, cv::Size(0, 0), 1.5);
  cv::Scalar m, sd;
  cv::meanStdDev(big, m, sd);
  return (big - m[0]) * (25.0 / sd[0]) + 100.0;
}

/// The pattern of the tests: a soft shadow (gain 0.45 in its core) at the left and bright dots (offset +60).
void pattern(cv::Mat* gain, cv::Mat* offset) {
  *gain = cv::Mat(kH, kW, CV_32FC1, cv::Scalar(1.f));
  *offset = cv::Mat(kH, kW, CV_32FC1, cv::Scalar(0.f));
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const double d = std::hypot(x - 25.0, y - 40.0);
      gain->at<float>(y, x) = static_cast<float>(1.0 - 0.55 / (1.0 + std::exp((d - 15.0) / 2.0)));
    }
  for (int y = 6; y < kH - 6; y += 9)
    for (int x = 60; x < kW - 4; x += 11) offset->at<float>(y, x) = 60.f;
}

double correlation(const cv::Mat& a, const cv::Mat& b) {
  cv::Scalar ma, sa, mb, sb;
  cv::meanStdDev(a, ma, sa);
  cv::meanStdDev(b, mb, sb);
  return cv::mean((a - ma[0]).mul(b - mb[0]))[0] / (sa[0] * sb[0]);
}

/// The ground's shift of a camera flying on (working px per image): every image of new ground.
const Vec2 kFlyingOn(10.0, 0.0);

FixedPatternParams params() {
  FixedPatternParams p;
  p.refresh_frames = 4;
  return p;
}

TEST(FixedPattern, LearnsAShadowAndDotsAndRemovesThem) {
  cv::RNG rng(3);
  cv::Mat gain, offset;
  pattern(&gain, &offset);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  for (int i = 0; i < 200; ++i) {
    const double exposure = 0.7 + 0.6 * rng.uniform(0.0, 1.0);  // auto-exposure: every frame its own gain
    cv::Mat img = exposure * (ground(&rng).mul(gain) + offset);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(10.0, kFlyingOn);  // the ground moved by much more than decorrelation_px, every image new ground
  }
  ASSERT_TRUE(fp.active());
  EXPECT_NEAR(fp.samples(), 150.0, 1e-9);  // capped at memory_samples
  // The shadow's core and the dots are recovered (gain relative to the rest of the image, offset in image means).
  EXPECT_NEAR(fp.gain().at<float>(40, 25), 0.45, 0.06);
  EXPECT_NEAR(fp.gain().at<float>(40, 100), 1.0, 0.02);
  EXPECT_NEAR(fp.offset().at<float>(6, 60), 60.f / (cv::mean(gain)[0] * 100.0 + cv::mean(offset)[0]), 0.08);
  EXPECT_GT(fp.strongFraction(), 0.05);
  EXPECT_LT(fp.strongFraction(), 0.25);
  // A new image: corrected, it is the ground again (up to a scale); uncorrected it is not.
  const cv::Mat g = ground(&rng);
  cv::Mat img = g.mul(gain) + offset;
  const double before = correlation(img, g);
  fp.apply(img.ptr<float>(), &s, &s2);
  const double after = correlation(img, g);
  EXPECT_LT(before, 0.9);
  EXPECT_GT(after, 0.99);
  // The returned moments are those of the corrected image.
  EXPECT_NEAR(s / (kW * kH), cv::mean(img)[0], 1e-3 * cv::mean(img)[0]);
  EXPECT_NEAR(s2 / (kW * kH), cv::mean(img.mul(img))[0], 1e-3 * cv::mean(img.mul(img))[0]);
}

/// An IR projector's pattern at the working resolution: a gain 1 + 0.5..1 x a blurred dot (sigma 0.8 px) about
/// every 16 px^2, dense enough that nearly every pixel is part of a dot's tail.
cv::Mat denseDots(cv::RNG* rng) {
  cv::Mat dots(kH, kW, CV_32FC1, cv::Scalar(0.f));
  for (int k = 0; k < kW * kH / 16; ++k) {
    const double cx = rng->uniform(0.0, kW - 1.0), cy = rng->uniform(0.0, kH - 1.0), amp = rng->uniform(0.5, 1.0);
    for (int y = std::max(0, static_cast<int>(cy) - 3); y <= std::min(kH - 1, static_cast<int>(cy) + 3); ++y)
      for (int x = std::max(0, static_cast<int>(cx) - 3); x <= std::min(kW - 1, static_cast<int>(cx) + 3); ++x)
        dots.at<float>(y, x) += static_cast<float>(amp * std::exp(-0.5 * ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / 0.64));
  }
  return 1.0 + dots;
}

TEST(FixedPattern, DenseDotsAreTestedAgainstTheNoiseNotAgainstThemselves) {
  // The dots fill the detail's spatial spread; its noise is measured against an earlier snapshot of the mean (the
  // pattern cancels in the difference), so they stand out and are removed, and they dominate the contrast.
  cv::RNG rng(13);
  const cv::Mat gain = denseDots(&rng);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  for (int i = 0; i < 200; ++i) {
    cv::Mat img = ground(&rng).mul(gain);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(10.0, Vec2(10.0, 0.0));  // flying on: every image of new ground
  }
  ASSERT_TRUE(fp.active());
  cv::Mat learned = fp.gain().clone();
  for (int i = 0; i < kW * kH; ++i)  // the whole correction as a gain at the ground's level (offset included)
    learned.ptr<float>()[i] += fp.offset().ptr<float>()[i] / static_cast<float>(cv::mean(gain)[0]);
  EXPECT_GT(correlation(learned, gain), 0.9);  // (measured against the spatial spread alone: 0.53)
  EXPECT_GT(fp.contrastShare(), 0.25);          // (0.17)
  const cv::Mat g = ground(&rng);
  cv::Mat img = g.mul(gain);
  const double before = correlation(img, g);
  fp.apply(img.ptr<float>(), &s, &s2);
  EXPECT_LT(before, 0.9);
  EXPECT_GT(correlation(img, g), 0.95);  // (0.78)
}

TEST(FixedPattern, DenseDotsStayFoundWhenTheFlightTurnsBack) {
  // Flying on, the dots are found against the noise measured in time; then the camera flies to and fro about one
  // place (new ground in every image, but no net motion: no snapshot is far enough from the mean to measure the
  // noise again). The noise measured last still holds; the image's spatial spread, which the dots fill, would
  // shrink them away again (contrast share 0.16, correlation 0.54 when only a measurement of the same refresh
  // counted).
  cv::RNG rng(13);
  const cv::Mat gain = denseDots(&rng);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  double share_flying_on = 0.0;
  for (int i = 0; i < 1000; ++i) {
    cv::Mat img = ground(&rng).mul(gain);
    fp.apply(img.ptr<float>(), &s, &s2);
    const bool to_and_fro = i >= 150;
    fp.learn(10.0, to_and_fro ? (i % 2 == 0 ? 1.0 : -1.0) * Vec2(10.0, 0.0) : Vec2(10.0, 0.0));
    if (i == 149) share_flying_on = fp.contrastShare();
  }
  ASSERT_TRUE(fp.active());
  cv::Mat learned = fp.gain().clone();
  for (int i = 0; i < kW * kH; ++i)
    learned.ptr<float>()[i] += fp.offset().ptr<float>()[i] / static_cast<float>(cv::mean(gain)[0]);
  std::printf("[dots, to and fro] contrast share flying on %.3f, after 850 images to and fro %.3f; correlation %.3f\n",
              share_flying_on, fp.contrastShare(), correlation(learned, gain));
  EXPECT_GT(share_flying_on, 0.25);
  EXPECT_GT(fp.contrastShare(), 0.25);
  EXPECT_GT(correlation(learned, gain), 0.9);
}

TEST(FixedPattern, HoveringOverTheSameGroundIsNotAPattern) {
  // A camera hovering (or flying the same path again and again) sees the same few pieces of ground: their mean is
  // fixed in the image like a pattern, and an earlier snapshot of it agrees with it. Unless the ground under the
  // mean has moved on, the detail is tested against the image's spread, and the ground is left alone.
  cv::RNG rng(17);
  std::vector<cv::Mat> grounds;
  for (int k = 0; k < 6; ++k) grounds.push_back(ground(&rng));
  const auto run = [&](const Vec2& drift) {
    FixedPattern fp(params(), kW, kH);
    double s = 0, s2 = 0;
    for (int i = 0; i < 300; ++i) {
      cv::Mat img = grounds[static_cast<size_t>(i) % grounds.size()].clone();
      fp.apply(img.ptr<float>(), &s, &s2);
      fp.learn(10.0, (i % 2 == 0 ? 1.0 : -1.0) * Vec2(10.0, 0.0) + drift);  // back and forth, plus the drift
    }
    return fp.contrastShare();
  };
  const double hovering = run(Vec2::Zero());
  // The same images said to come from a camera flying on (impossible for real ground): the test believes the
  // snapshots, and the mean of the six images becomes a "pattern".
  const double flying_on = run(Vec2(3.0, 0.0));
  std::printf("[hover] contrast share of the learned pattern: hovering %.3f, said to fly on %.3f\n", hovering, flying_on);
  EXPECT_LT(hovering, 0.05);
  EXPECT_GT(flying_on, 3.0 * hovering + 0.05);
}

TEST(FixedPattern, HoldingAPositionIsNotAPattern) {
  // A camera holding its position wobbles over one spot: each image is the same ground shifted by a few pixels
  // (here up to 6 px, 1 s period at 30 Hz), so the ground moves by decorrelation_px and more per image and the
  // samples add up, but the mean holds only a few patches of ground (cells of the local mean's window; 3.3). Its
  // structure is fixed in the image like a pattern; the fields are not computed from it. The same images with a
  // slow drift (the camera flying on) hold new ground and the model starts.
  cv::RNG rng(23);
  const cv::Mat big = wideGround(kH + 200, kW + 400, &rng);
  const auto run = [&](double drift_px, bool waived = false) {
    FixedPattern fp(params(), kW, kH);
    fp.waivePatchCondition(waived);
    double s = 0, s2 = 0;
    Vec2 previous(0.0, 0.0);
    bool ever_active = false;
    for (int i = 0; i < 600; ++i) {
      const double phase = 2.0 * M_PI * i / 30.0;
      const Vec2 at(6.0 * std::sin(phase) + drift_px * i, 4.0 * std::sin(phase + 0.5));
      const cv::Rect crop(static_cast<int>(std::lround(100.0 + at.x())), static_cast<int>(std::lround(100.0 + at.y())),
                          kW, kH);
      cv::Mat img = big(crop).clone();
      fp.apply(img.ptr<float>(), &s, &s2);
      const Vec2 shift = -(at - previous);  // the camera moves by at: the ground the other way
      fp.learn(shift.norm(), shift);
      previous = at;
      ever_active = ever_active || fp.active();
    }
    std::printf("[position hold] drift %.2f px per image: %.1f samples, %.1f different pieces and %.1f patches of "
                "ground, active %d, contrast share %.3f\n",
                drift_px, fp.samples(), fp.independentGround(), fp.independentPatches(), ever_active ? 1 : 0,
                fp.contrastShare());
    return std::make_pair(ever_active, fp.independentPatches());
  };
  const auto holding = run(0.0);
  EXPECT_FALSE(holding.first);
  EXPECT_LT(holding.second, params().min_ground_patches);
  const auto flying_on = run(0.5);
  EXPECT_TRUE(flying_on.first);
  EXPECT_GE(flying_on.second, params().min_ground_patches);
  // With the condition waived (the estimator does so while the images deny the motion the IMU measures) the
  // held ground is taken for a pattern: the condition is what keeps it off.
  EXPECT_TRUE(run(0.0, true).first);
}

TEST(FixedPattern, AHoldAboutTheStartIsOnePatchOfGround) {
  // A camera holding its position, heading and height from the start: the ground's track through the image, its turn
  // and its log scale all jitter about zero, the start, and the track drifts slowly as the estimated velocity's bias
  // integrates (0.1 px per second). On one grid of cells the start lies on an edge along all four axes, so the jitter
  // alternated between up to 16 cells of the same ground (a periodic flight at 90 px was taken for a pattern of 44 % of
  // the image's contrast after 69 s); counted on the grid shifted by half a cell as well, the lesser count, it stays
  // one patch (two while the drift crosses an edge; on the first grid alone 6.7, and the model started). The images
  // wobble by up to 2 px (the ground's shift per image is at most 0.4 px, so each image counts as a fifth of a sample
  // at most).
  cv::RNG rng(29);
  const cv::Mat big = wideGround(kH + 100, kW + 100, &rng);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  Vec2 previous(0.0, 0.0), previous_turn_scale(0.0, 0.0);
  bool ever_active = false;
  double most_patches = 0.0;
  for (int i = 0; i < 3000; ++i) {  // 100 s at 30 Hz
    const double phase = 2.0 * M_PI * i / 30.0;
    const Vec2 at(2.0 * std::sin(phase), 1.5 * std::sin(phase + 0.5));
    const Vec2 turn_scale(0.02 * std::sin(phase + 1.0), 0.01 * std::sin(phase + 2.0));  // rad, log scale
    const cv::Rect crop(static_cast<int>(std::lround(50.0 + at.x())), static_cast<int>(std::lround(50.0 + at.y())),
                        kW, kH);
    cv::Mat img = big(crop).clone();
    fp.apply(img.ptr<float>(), &s, &s2);
    const Vec2 shift = -(at - previous) + Vec2(0.1 / 30.0, 0.0);  // the ground moves against the camera; drift
    fp.learn(shift.norm(), shift, turn_scale - previous_turn_scale);
    previous = at;
    previous_turn_scale = turn_scale;
    ever_active = ever_active || fp.active();
    if (fp.samples() >= params().startup_samples) most_patches = std::max(most_patches, fp.independentPatches());
  }
  std::printf("[hold about the start] %.1f samples, at most %.2f patches of ground, active %d\n", fp.samples(),
              most_patches, ever_active ? 1 : 0);
  EXPECT_GE(fp.samples(), params().startup_samples);  // (the condition, not the start-up, keeps it off)
  EXPECT_LT(most_patches, 2.5);
  EXPECT_FALSE(ever_active);
}

TEST(FixedPattern, AClimbOverOneSpotIsNotAPatternAtTheImagesCentre) {
  // A vertical climb and descent over one spot (flight 7's first 12 s): the ground zooms about the image's centre,
  // so away from the centre it moves on and decorrelates, but at the centre it stays where it is. Each pixel
  // counts its own ground's motion; else the centre's ground, seen again and again, is learned as a pattern once
  // the flight moves on sideways and the start-up completes. The per-pixel weights are the ground's shift plus its
  // radius times the change of log scale.
  cv::RNG rng(31);
  const cv::Mat big = wideGround(3 * kH, 3 * kW, &rng);  // (rng goes on: the new ground below)
  FixedPattern fp(params(), kW, kH);
  const double r_max = std::hypot(0.5 * (kW - 1), 0.5 * (kH - 1));
  double s = 0, s2 = 0, prev_log_scale = 0.0;
  for (int i = 0; i < 300; ++i) {  // 10 s of climbing and descending, scale 0.75-1.35
    const double log_scale = 0.3 * std::sin(2.0 * M_PI * i / 90.0);
    const double k = std::exp(log_scale);
    cv::Mat A = (cv::Mat_<double>(2, 3) << k, 0.0, 0.5 * (kW - 1) - k * (1.5 * kW - 0.5), 0.0, k,
                 0.5 * (kH - 1) - k * (1.5 * kH - 0.5));
    cv::Mat img;
    cv::warpAffine(big, img, A, cv::Size(kW, kH), cv::INTER_LINEAR);
    fp.apply(img.ptr<float>(), &s, &s2);
    const double d = log_scale - prev_log_scale;
    fp.learn(std::abs(d) * r_max, Vec2::Zero(), Vec2(0.0, d));
    prev_log_scale = log_scale;
  }
  EXPECT_FALSE(fp.active());  // one spot: too few patches of ground
  int sideways = 0;
  for (; sideways < 300 && !fp.active(); ++sideways) {  // then on, sideways: new ground in every image
    cv::Mat img = ground(&rng);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(10.0, kFlyingOn);
  }
  ASSERT_TRUE(fp.active());
  // The central quarter of the image: its ground is no pattern.
  const cv::Rect centre(3 * kW / 8, 3 * kH / 8, kW / 4, kH / 4);
  const double centre_dev = cv::norm(fp.gain()(centre) - 1.0, cv::NORM_INF);
  std::printf("[climb over one spot] start-up after %d images sideways: contrast share %.3f, strong fraction %.3f, "
              "largest gain deviation in the central quarter %.3f\n",
              sideways, fp.contrastShare(), fp.strongFraction(), centre_dev);
  EXPECT_LT(centre_dev, 0.05);
  EXPECT_LT(fp.contrastShare(), 0.005);
}

TEST(FixedPattern, NothingIsCorrectedBeforeTheStartUpOrWithoutMotion) {
  cv::RNG rng(5);
  cv::Mat gain, offset;
  pattern(&gain, &offset);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  for (int i = 0; i < 100; ++i) {  // a hovering camera: the same ground every frame, no motion
    cv::Mat img = ground(&rng).mul(gain) + offset;
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(0.0, Vec2::Zero());
  }
  EXPECT_FALSE(fp.active());
  EXPECT_EQ(fp.samples(), 0.0);
  EXPECT_EQ(fp.confidence(), nullptr);
  // Slow motion counts as a fraction of a sample: 28 frames at a quarter of decorrelation_px are 7 samples.
  for (int i = 0; i < 28; ++i) {
    cv::Mat img = ground(&rng).mul(gain) + offset;
    const cv::Mat copy = img.clone();
    fp.apply(img.ptr<float>(), &s, &s2);
    EXPECT_EQ(cv::norm(img, copy, cv::NORM_INF), 0.0);  // inactive: the image is left as it is
    fp.learn(0.25 * params().decorrelation_px, Vec2(0.25 * params().decorrelation_px, 0.0));
  }
  EXPECT_NEAR(fp.samples(), 7.0, 1e-9);
  EXPECT_FALSE(fp.active());
  // Without a new apply() there is nothing to learn from.
  fp.learn(100.0, kFlyingOn);
  EXPECT_NEAR(fp.samples(), 7.0, 1e-9);
}

TEST(FixedPattern, CleanImagesAreLeftAlone) {
  cv::RNG rng(7);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  for (int i = 0; i < 300; ++i) {
    cv::Mat img = ground(&rng);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(5.0, Vec2(5.0, 0.0));
  }
  ASSERT_TRUE(fp.active());
  // The statistics' own noise is shrunk away: almost every pixel keeps gain 1 and offset 0.
  int changed = 0;
  for (int i = 0; i < kW * kH; ++i)
    if (fp.gain().ptr<float>()[i] != 1.f || fp.offset().ptr<float>()[i] != 0.f) ++changed;
  EXPECT_LT(changed, kW * kH / 100);
  EXPECT_LT(fp.strongFraction(), 0.005);
  EXPECT_LT(fp.contrastShare(), 0.005);  // far from dominant_contrast_share
  // Deviations near the significance threshold lose some weight (neither trusted nor removed); few pixels do.
  if (fp.confidence() != nullptr) {
    int low = 0;
    for (int i = 0; i < kW * kH; ++i)
      if (fp.confidence()->ptr<float>()[i] < 0.5f) ++low;
    EXPECT_LT(low, kW * kH / 100);
  }
  const cv::Mat g = ground(&rng);
  cv::Mat img = g.clone();
  fp.apply(img.ptr<float>(), &s, &s2);
  EXPECT_GT(correlation(img, g), 0.999);
}

/// A lens's vignetting about an optical centre off the image's centre: 1 - 0.3 r^2 - 0.05 r^4, r = 1 at the
/// farthest corner.
cv::Mat radialVignetting(double cx, double cy) {
  cv::Mat v(kH, kW, CV_32FC1);
  const double dx = std::max(cx, kW - 1 - cx), dy = std::max(cy, kH - 1 - cy);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const double r2 = ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (dx * dx + dy * dy);
      v.at<float>(y, x) = static_cast<float>(1.0 - 0.3 * r2 - 0.05 * r2 * r2);
    }
  return v;
}

/// |gain - truth| per pixel, both relative to their medians.
cv::Mat relativeGainError(const cv::Mat& gain, const cv::Mat& truth) {
  const auto median = [](const cv::Mat& m) {
    std::vector<float> v(m.begin<float>(), m.end<float>());
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  return cv::abs(gain / median(gain) - truth / median(truth));
}

double maxGainError(const cv::Mat& gain, const cv::Mat& truth) {
  return cv::norm(relativeGainError(gain, truth), cv::NORM_INF);
}

/// Pixels where the relative gain error exceeds tol.
int pixelsOff(const cv::Mat& gain, const cv::Mat& truth, double tol) {
  return cv::countNonZero(relativeGainError(gain, truth) > tol);
}

/// Learns `fp` from `images` images of one large piece of ground under a camera flying over it (2.5 px per image,
/// turning), each darkened by `vig` and exposed anew, and gives each pair to the vignetting's learner with its
/// exact map (the estimator gives it the filter's warp).
void flyOverOneGround(FixedPattern* fp, const cv::Mat& vig, int images, cv::RNG* rng) {
  cv::Mat ground(kH + 300, kW + 300, CV_32FC1);
  rng->fill(ground, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(ground, ground, cv::Size(0, 0), 1.5);
  cv::Scalar m, sd;
  cv::meanStdDev(ground, m, sd);
  ground = (ground - m[0]) * (25.0 / sd[0]) + 100.0;
  VignettingLearner& learner = fp->vignettingLearner();
  cv::Mat prev;
  cv::Point2f prev_c;
  double s = 0, s2 = 0;
  for (int i = 0; i < images; ++i) {
    const double a = 0.02 * i;
    const cv::Point2f c(static_cast<float>(0.5 * ground.cols + 120.0 * std::cos(a)),
                        static_cast<float>(0.5 * ground.rows + 120.0 * std::sin(a)));
    cv::Mat view;
    cv::getRectSubPix(ground, cv::Size(kW, kH), c, view, CV_32F);
    cv::Mat img = (0.7 + 0.6 * rng->uniform(0.0, 1.0)) * view.mul(vig);
    fp->apply(img.ptr<float>(), &s, &s2);
    const cv::Mat u = fp->lastImage().clone();
    if (i > 0) {
      Vec2* t = learner.gridTargets();
      for (int j = 0; j < learner.gridRows(); ++j)
        for (int k = 0; k < learner.gridCols(); ++k)
          t[j * learner.gridCols() + k] = Vec2(k * VignettingLearner::kGridPx + (c.x - prev_c.x),
                                               j * VignettingLearner::kGridPx + (c.y - prev_c.y));
      learner.observe(u.ptr<float>(), prev.ptr<float>());
    }
    fp->learn(10.0, kFlyingOn);
    prev = u;
    prev_c = c;
  }
}

TEST(FixedPattern, RadialVignettingIsFittedAsOneSmoothField) {
  const double cx = 70.0, cy = 35.0;  // the principal point, off the image's centre
  const cv::Mat vig = radialVignetting(cx, cy);
  FixedPatternParams p = params();
  p.radial_vignetting = true;
  FixedPattern fp(p, kW, kH, cv::Mat(), Vec2(cx, cy));
  FixedPatternParams p_per_pixel = params();
  p_per_pixel.radial_vignetting = false;
  FixedPattern per_pixel(p_per_pixel, kW, kH, cv::Mat(), Vec2(cx, cy));  // the per-pixel model alone
  cv::RNG rng(13), rng2(13);
  flyOverOneGround(&fp, vig, 200, &rng);
  flyOverOneGround(&per_pixel, vig, 200, &rng2);
  ASSERT_TRUE(fp.active());
  // The field is the lens's, everywhere (the per-pixel model leaves the weak parts uncorrected and steps where its
  // significance test switches on), and it is not reported as a strong pattern.
  EXPECT_NEAR(fp.vignettingAtCorner(), 0.65, 0.03);
  const double err = maxGainError(fp.gain(), vig), err_per_pixel = maxGainError(per_pixel.gain(), vig);
  std::printf("[ vignetting ] corner %.3f (truth 0.650); largest gain error %.3f (per-pixel model alone %.3f)\n",
              fp.vignettingAtCorner(), err, err_per_pixel);
  EXPECT_LT(maxGainError(fp.vignetting(), vig), 0.03);
  EXPECT_LT(err, 0.25);
  const int off = pixelsOff(fp.gain(), vig, 0.04), off_per_pixel = pixelsOff(per_pixel.gain(), vig, 0.04);
  std::printf("[ vignetting ] gain off by more than 0.04: %d pixels (per-pixel model alone %d) of %d\n", off,
              off_per_pixel, kW * kH);
  EXPECT_LT(off, kW * kH / 100);
  EXPECT_GT(off_per_pixel, kW * kH / 10);
  EXPECT_LT(fp.strongFraction(), 0.01);
  // A new image, corrected, is the ground again.
  const cv::Mat g = ground(&rng);
  cv::Mat img = g.mul(vig);
  double s = 0, s2 = 0;
  fp.apply(img.ptr<float>(), &s, &s2);
  EXPECT_GT(correlation(img, g), 0.995);

  // Without vignetting the learner finds none.
  FixedPattern flat(p, kW, kH, cv::Mat(), Vec2(cx, cy));
  flyOverOneGround(&flat, cv::Mat(kH, kW, CV_32FC1, cv::Scalar(1.f)), 200, &rng);
  ASSERT_TRUE(flat.active());
  EXPECT_NEAR(flat.vignettingAtCorner(), 1.0, 0.01);
  EXPECT_LT(maxGainError(flat.vignetting(), cv::Mat(kH, kW, CV_32FC1, cv::Scalar(1.f))), 0.01);
}

TEST(FixedPattern, TheLensIsCorrectedBeforeTheStartUp) {
  // The per-pixel model waits for enough different ground (here never: min_ground_patches out of reach). The
  // radial vignetting is learned from pair ratios, in which the ground cancels: once its corner is significant it
  // is applied alone, before the start-up, and nothing else is corrected or reported.
  const double cx = 70.0, cy = 35.0;
  const cv::Mat vig = radialVignetting(cx, cy);
  FixedPatternParams p = params();
  p.radial_vignetting = true;
  p.min_ground_patches = 1e9;
  FixedPattern fp(p, kW, kH, cv::Mat(), Vec2(cx, cy));
  cv::RNG rng(29);
  const auto correctedCorrelation = [&](FixedPattern* f) {
    const cv::Mat g = ground(&rng);
    cv::Mat img = g.mul(vig);
    double s = 0, s2 = 0;
    f->apply(img.ptr<float>(), &s, &s2);
    return correlation(img, g);
  };
  flyOverOneGround(&fp, vig, VignettingLearner::kMinPairs / 2, &rng);  // too few pairs for an estimate
  EXPECT_FALSE(fp.corrects());
  const double before = correctedCorrelation(&fp);
  flyOverOneGround(&fp, vig, 200, &rng);
  EXPECT_FALSE(fp.active());
  EXPECT_TRUE(fp.corrects());
  EXPECT_NEAR(fp.vignettingAtCorner(), 0.65, 0.03);
  EXPECT_LT(maxGainError(fp.gain(), vig), 0.03);  // the gain in use is the lens's field alone
  EXPECT_EQ(fp.confidence(), nullptr);
  EXPECT_EQ(fp.contrastShare(), 0.0);
  EXPECT_EQ(fp.strongFraction(), 0.0);
  const double after = correctedCorrelation(&fp);
  std::printf("[ vignetting before the start-up ] corner %.3f (truth 0.650); a new image against its ground: "
              "correlation %.4f uncorrected, %.4f corrected\n",
              fp.vignettingAtCorner(), before, after);
  EXPECT_GT(after, 0.995);
  EXPECT_LT(before, after - 0.01);

  // The per-pixel model alone (no radial field) corrects nothing before its start-up.
  FixedPatternParams q = p;
  q.radial_vignetting = false;
  FixedPattern per_pixel(q, kW, kH, cv::Mat(), Vec2(cx, cy));
  flyOverOneGround(&per_pixel, vig, 200, &rng);
  EXPECT_FALSE(per_pixel.corrects());

  // A lens does not brighten its periphery: a field that does (here the inverse of the lens's) is the estimate's
  // error and is not applied, before the start-up or after.
  FixedPattern brighter(p, kW, kH, cv::Mat(), Vec2(cx, cy));
  flyOverOneGround(&brighter, 1.0 / vig, 200, &rng);
  double a1 = 0.0, a2 = 0.0, sigma = 0.0;
  ASSERT_TRUE(brighter.vignettingLearner().estimate(&a1, &a2, &sigma));
  EXPECT_GT(a1 + a2, 10.0 * sigma);  // found, and significant
  EXPECT_FALSE(brighter.corrects());
  EXPECT_EQ(brighter.vignettingAtCorner(), 1.0);
}

TEST(FixedPattern, SaturatedPixelsLoseTheirWeight) {
  cv::RNG rng(9);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  const cv::Rect blob(50, 30, 8, 8);
  for (int i = 0; i < 120; ++i) {
    cv::Mat img = ground(&rng);
    img(blob).setTo(255.f);  // a saturated projector dot
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(5.0, Vec2(5.0, 0.0));
  }
  ASSERT_TRUE(fp.active());
  ASSERT_NE(fp.confidence(), nullptr);
  EXPECT_LT(fp.confidence()->at<float>(34, 54), 0.05f);
  EXPECT_GT(fp.confidence()->at<float>(10, 10), 0.9f);
  // Forgetting everything: back to the start-up.
  fp.reset();
  EXPECT_FALSE(fp.active());
  EXPECT_EQ(fp.confidence(), nullptr);
}

TEST(FixedPattern, AShadowThatMovesIsFollowed) {
  cv::RNG rng(11);
  cv::Mat gain, offset;
  pattern(&gain, &offset);
  offset.setTo(0.f);
  FixedPattern fp(params(), kW, kH);
  double s = 0, s2 = 0;
  for (int i = 0; i < 300; ++i) {
    cv::Mat img = ground(&rng).mul(gain);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(10.0, kFlyingOn);
  }
  EXPECT_NEAR(fp.gain().at<float>(40, 25), 0.45, 0.06);
  cv::Mat moved;
  cv::flip(gain, moved, 1);  // the drone turned: the shadow is on the other side now
  // A jump of the mean leaks into the spread for a while (its lagging part, e^-(n / memory) of the jump): six
  // memory time constants to forget it.
  for (int i = 0; i < 900; ++i) {
    cv::Mat img = ground(&rng).mul(moved);
    fp.apply(img.ptr<float>(), &s, &s2);
    fp.learn(10.0, kFlyingOn);
  }
  EXPECT_NEAR(fp.gain().at<float>(40, kW - 1 - 25), 0.45, 0.08);
  EXPECT_NEAR(fp.gain().at<float>(40, 25), 1.0, 0.08);
}

TEST(FixedPattern, ImageMotionFromTheState) {
  PinholeK K{100.0, 100.0, 59.5, 39.5, 120, 80};
  const double r = 0.5 * std::hypot(120.0, 80.0);
  // Sideways at 0.3 1/s (0.3 m/s at 1 m) for 0.1 s: 3 px at the centre.
  EXPECT_NEAR(imageMotionPx(Vec3(0.3, 0.0, 0.0), Vec3::Zero(), K, 0.1), 3.0, 1e-12);
  // Turning about x at 0.2 rad/s: 2 px; about z at 0.2 rad/s: 0.02 r px at the rim; descending at 0.1 1/s.
  EXPECT_NEAR(imageMotionPx(Vec3::Zero(), Vec3(0.2, 0.0, 0.0), K, 0.1), 2.0, 1e-12);
  EXPECT_NEAR(imageMotionPx(Vec3(0.0, 0.0, 0.1), Vec3(0.0, 0.0, 0.2), K, 0.1), 0.03 * r, 1e-12);
  EXPECT_EQ(imageMotionPx(Vec3(0.3, 0.0, 0.0), Vec3::Zero(), K, 0.0), 0.0);
  EXPECT_EQ(imageMotionPx(Vec3(NAN, 0.0, 0.0), Vec3::Zero(), K, 0.1), 0.0);
  // The ground's net shift through the image at its centre: against the camera's motion, the divergence left out;
  // tilting about x at 0.2 rad/s moves it by +2 px in y, about y by -2 px in x (a world-fixed direction seen from
  // the camera turns by -w x q); the turn about the optical axis apart.
  EXPECT_TRUE(groundShiftPx(Vec3(0.3, -0.2, 0.5), Vec3::Zero(), K, 0.1).isApprox(Vec2(-3.0, 2.0), 1e-12));
  EXPECT_TRUE(groundShiftPx(Vec3::Zero(), Vec3(0.2, 0.0, 0.7), K, 0.1).isApprox(Vec2(0.0, 2.0), 1e-12));
  EXPECT_TRUE(groundShiftPx(Vec3::Zero(), Vec3(0.0, 0.2, 0.0), K, 0.1).isApprox(Vec2(-2.0, 0.0), 1e-12));
  EXPECT_TRUE(groundTurnScale(Vec3(0.0, 0.0, 0.5), Vec3(0.2, 0.0, 0.7), 0.1).isApprox(Vec2(-0.07, 0.05), 1e-15));
  EXPECT_TRUE(groundShiftPx(Vec3(NAN, 0.0, 0.0), Vec3::Zero(), K, 0.1).isZero());
  EXPECT_TRUE(groundShiftPx(Vec3(0.3, 0.0, 0.0), Vec3::Zero(), K, 0.0).isZero());
  EXPECT_TRUE(groundTurnScale(Vec3::Zero(), Vec3(0.0, 0.0, NAN), 0.1).isZero());
  // Before convergence, vartheta shrunk by twice its 1-sigma (sqrt of the covariance's trace): 0.5 1/s with a
  // 1-sigma of 0.1 counts as 0.3; not larger than twice its 1-sigma, as no motion.
  const Vec3 v(0.3, 0.4, 0.0);
  EXPECT_TRUE(lowerBoundVartheta(v, Mat3::Identity() * (0.01 / 3.0)).isApprox(0.6 * v, 1e-12));
  EXPECT_TRUE(lowerBoundVartheta(v, Mat3::Identity() * (0.07 / 3.0)).isZero());
  EXPECT_TRUE(lowerBoundVartheta(v, Mat3::Zero()).isApprox(v, 1e-15));
  EXPECT_TRUE(lowerBoundVartheta(Vec3(NAN, 0.0, 0.0), Mat3::Zero()).isZero());
  EXPECT_TRUE(lowerBoundVartheta(v, Mat3::Identity() * NAN).isZero());
}

TEST(FixedPattern, InThePreprocessingAndAFlatFieldFile) {
  // The preprocessing hands the blurred image to the pattern before its normalisation.
  const CameraModel cam = myntEyeCamera();
  PreprocessParams pp;
  pp.working_width_px = 90;
  ImagePreprocessor pre(cam, pp);
  const cv::Size ws = pre.workingSize();
  // A flat field file at the raw resolution: darker corners (vignetting).
  cv::Mat flat(cam.K.height, cam.K.width, CV_32FC1);
  for (int y = 0; y < flat.rows; ++y)
    for (int x = 0; x < flat.cols; ++x) {
      const double r2 = (std::pow(x - 376.0, 2) + std::pow(y - 240.0, 2)) / (376.0 * 376.0 + 240.0 * 240.0);
      flat.at<float>(y, x) = static_cast<float>(1.0 - 0.4 * r2);
    }
  const std::string path = ::testing::TempDir() + "diekf_flat_field.yaml";
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "gain" << flat;
  }
  const cv::Mat field = loadFlatField(path, cam, pp);
  ASSERT_EQ(field.size(), ws);
  const double centre = field.at<float>(ws.height / 2, ws.width / 2);
  const double corner = field.at<float>(1, 1);
  EXPECT_LT(corner / centre, 0.9);  // the working corner sees the raw image inside its corner (undistortion)
  EXPECT_GT(corner / centre, 0.55);
  EXPECT_THROW(loadFlatField(path + ".missing", cam, pp), std::invalid_argument);
  // A vignetted uniform-ish image: the flat field makes its working image flat.
  cv::Mat raw(cam.K.height, cam.K.width, CV_8UC1);
  for (int y = 0; y < raw.rows; ++y)
    for (int x = 0; x < raw.cols; ++x)
      raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(200.0 * flat.at<float>(y, x) + 10.0 * ((x / 40 + y / 40) % 2));
  FixedPattern fp(FixedPatternParams(), ws.width, ws.height, field);
  PreprocessedFrame plain, flattened;
  pp.normalize_brightness = false;
  ImagePreprocessor pre_raw(cam, pp);
  pre_raw.process(raw, 0.0, &plain);
  pre_raw.process(raw, 0.0, &flattened, &fp);
  cv::Scalar m0, s0, m1, s1;
  cv::meanStdDev(plain.intensity, m0, s0);
  cv::meanStdDev(flattened.intensity, m1, s1);
  EXPECT_GT(s0[0], 2.0 * s1[0]);  // the vignetting dominated the spread before
}

}  // namespace
}  // namespace diekf
