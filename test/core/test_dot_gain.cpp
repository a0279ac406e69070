// The projector dots' gain learned from the ground's motion (DotGainLearner, docs/noise_model.md section 11, "Dots
// divided out"), the division of the raw images by it, and the preprocessor dividing before its fill.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "../../src/core/dot_gain.h"
#include "diekf/image_preprocessor.h"

namespace diekf {
namespace {

using internal::DotGainLearner;

TEST(DotGain, DivideByGainIsTheRoundedQuotient) {
  cv::RNG rng(5);
  const size_t n = 1000 + 7;  // (the tail after the last 16)
  std::vector<uint8_t> src(n), out(n);
  std::vector<uint16_t> inv(n);
  for (size_t i = 0; i < n; ++i) {
    src[i] = static_cast<uint8_t>(rng.uniform(0, 256));
    inv[i] = static_cast<uint16_t>(i % 5 == 0 ? 4096 : rng.uniform(512, 32769));  // gains 1/8..8, and exactly 1
  }
  internal::divideByGain(src.data(), inv.data(), n, out.data());
  int saturated = 0;
  for (size_t i = 0; i < n; ++i) {
    const long want = std::min(255L, std::lround(std::floor((src[i] * static_cast<double>(inv[i]) + 2048.0) / 4096.0)));
    ASSERT_EQ(out[i], want) << "at " << i << ": " << int(src[i]) << " x " << inv[i] << " / 4096";
    if (i % 5 == 0) {
      ASSERT_EQ(out[i], src[i]);
    }
    saturated += want == 255 && src[i] * static_cast<long>(inv[i]) / 4096 > 255;
  }
  EXPECT_GT(saturated, 10);  // the saturation was exercised
}

constexpr int kW = 320, kH = 240;

/// A ground larger than the view: brightness 40..160 varying over 3-4 px (the detail the division must keep) and
/// over tens of pixels.
cv::Mat ground(int w, int h) {
  cv::RNG rng(11);
  cv::Mat coarse(h / 24, w / 24, CV_32FC1), fine(h / 3, w / 3, CV_32FC1);
  rng.fill(coarse, cv::RNG::UNIFORM, 60.0, 140.0);
  rng.fill(fine, cv::RNG::UNIFORM, -20.0, 20.0);
  cv::Mat a, b;
  cv::resize(coarse, a, cv::Size(w, h), 0, 0, cv::INTER_CUBIC);
  cv::resize(fine, b, cv::Size(w, h), 0, 0, cv::INTER_CUBIC);
  return a + b;
}

/// Gain 1 + 1.5 a exp(-r^2 / (2 sigma^2)) of `dots` dots (a 0.6..1.4), as the simulator's projector.
cv::Mat dotGain(int dots, double sigma_px) {
  cv::RNG rng(3);
  cv::Mat g(kH, kW, CV_32FC1, cv::Scalar(1.f));
  const int reach = static_cast<int>(std::ceil(4.0 * sigma_px));
  for (int k = 0; k < dots; ++k) {
    const double cx = rng.uniform(10.0, kW - 10.0), cy = rng.uniform(10.0, kH - 10.0);
    const double a = 1.5 * rng.uniform(0.6, 1.4);
    for (int y = std::max(0, static_cast<int>(cy) - reach); y <= std::min(kH - 1, static_cast<int>(cy) + reach); ++y)
      for (int x = std::max(0, static_cast<int>(cx) - reach); x <= std::min(kW - 1, static_cast<int>(cx) + reach);
           ++x)
        g.at<float>(y, x) += static_cast<float>(
            a * std::exp(-0.5 * ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (sigma_px * sigma_px)));
  }
  return g;
}

/// The camera's view of `world` at offset (ox, oy) (the ground point at view pixel x is world pixel x + o), times
/// the dots' gain and `exposure`, with 1 grey level of noise, 8 bits.
cv::Mat view(const cv::Mat& world, const cv::Mat& gain, double ox, double oy, double exposure, cv::RNG* rng) {
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, ox, 0, 1, oy);
  cv::Mat v, noise(kH, kW, CV_32FC1);
  cv::warpAffine(world, v, shift, cv::Size(kW, kH), cv::INTER_CUBIC | cv::WARP_INVERSE_MAP);
  rng->fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
  v = v.mul(gain) * exposure + noise;
  cv::Mat out;
  v.convertTo(out, CV_8UC1);
  return out;
}

TEST(DotGainLearner, LearnsTheDotsGainFromTheGroundsMotion) {
  const cv::Mat world = ground(kW + 200, kH + 200);
  const cv::Mat gain = dotGain(60, 1.2);
  const cv::Mat fill_mask = gain > 1.05f;  // (as the detector's mask, about)
  DotGainLearner learner;
  learner.start(fill_mask);
  ASSERT_TRUE(learner.learning());
  EXPECT_GT(learner.regionShare(), cv::countNonZero(fill_mask) / double(kW * kH));
  cv::RNG rng(1);
  double ox = 100.0, oy = 100.0;
  cv::Mat ref = view(world, gain, ox, oy, 1.0, &rng);
  int pairs = 0;
  double last_ox = ox, last_oy = oy;
  for (; pairs < DotGainLearner::kMaxPairs && !learner.ready(); ++pairs) {
    // A wandering path, 1-3 px per image in changing directions, and the exposure stepping by up to 8 %.
    const double heading = 0.37 * pairs + std::sin(0.05 * pairs), step = 1.0 + std::fabs(2.0 * std::sin(0.11 * pairs));
    const double dx = step * std::cos(heading), dy = step * std::sin(heading);
    ox = std::clamp(ox + dx, 5.0, 195.0);
    oy = std::clamp(oy + dy, 5.0, 195.0);
    const double exposure = 1.0 + 0.08 * std::sin(0.3 * pairs);
    const cv::Mat cur = view(world, gain, ox, oy, exposure, &rng);
    // The ground at current pixel x is at x + (o_cur - o_ref) in the reference.
    Vec2* t = learner.gridTargets();
    for (int j = 0; j < learner.gridRows(); ++j)
      for (int i = 0; i < learner.gridCols(); ++i)
        t[j * learner.gridCols() + i] =
            Vec2(i * DotGainLearner::kGridPx + (ox - last_ox), j * DotGainLearner::kGridPx + (oy - last_oy));
    learner.observe(cur.data, ref.data);
    last_ox = ox;
    last_oy = oy;
    ref = cur;
  }
  ASSERT_TRUE(learner.ready()) << "after " << pairs << " pairs: " << learner.readyShare();
  EXPECT_LT(pairs, 150);
  cv::Mat inv, core;
  const double core_share = learner.result(&inv, &core);
  EXPECT_EQ(core_share, cv::countNonZero(core) / double(kW * kH));
  double sum2 = 0.0, worst = 0.0;
  int divided = 0, bright_missed = 0, bright = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const double g = gain.at<float>(y, x), q = inv.at<uint16_t>(y, x);
      if (g > 2.2) {
        ++bright;
        bright_missed += core.at<uint8_t>(y, x) == 0;  // would saturate on bright ground: must stay filled
      }
      if (core.at<uint8_t>(y, x) != 0) {
        EXPECT_EQ(q, 4096);
        continue;
      }
      if (q == 4096 && learner.gainAt(x, y) == 1.0) {
        EXPECT_LT(g, 1.1) << "at " << x << "," << y;  // outside the region: only the dots' faintest tails
        continue;
      }
      const double e = 4096.0 / q / g - 1.0;
      sum2 += e * e;
      worst = std::max(worst, std::fabs(e));
      ++divided;
    }
  }
  std::printf("[dot gain] learned after %d pairs: %d px divided, gain error %.2f %% r.m.s., %.2f %% at most; core "
              "%.2f %%\n",
              pairs, divided, 100.0 * std::sqrt(sum2 / std::max(divided, 1)), 100.0 * worst, 100.0 * core_share);
  ASSERT_GT(divided, cv::countNonZero(fill_mask) / 2);
  EXPECT_LT(std::sqrt(sum2 / divided), 0.008);  // the learned gains within 0.8 % r.m.s. of the truth (0.27 %)
  EXPECT_LT(worst, 0.05);
  EXPECT_GT(bright, 20);
  EXPECT_EQ(bright_missed, 0);
  learner.stop();
  EXPECT_FALSE(learner.learning());
  EXPECT_FALSE(learner.ready());
}

TEST(DotGainLearner, AStillGroundTeachesNothing) {
  const cv::Mat world = ground(kW + 200, kH + 200);
  const cv::Mat gain = dotGain(60, 1.2);
  DotGainLearner learner;
  learner.start(gain > 1.05f);
  cv::RNG rng(2);
  const cv::Mat img = view(world, gain, 100.0, 100.0, 1.0, &rng);
  for (int k = 0; k < 100; ++k) {
    Vec2* t = learner.gridTargets();
    for (int j = 0; j < learner.gridRows(); ++j)
      for (int i = 0; i < learner.gridCols(); ++i)
        t[j * learner.gridCols() + i] = Vec2(i * DotGainLearner::kGridPx, j * DotGainLearner::kGridPx);
    learner.observe(img.data, img.data);
  }
  // A pixel's reference sample lands on itself, in the region: never a known gain, nothing learned.
  EXPECT_EQ(learner.readyShare(), 0.0);
  EXPECT_FALSE(learner.ready());
}

TEST(DotGainLearner, RejectsABadMask) {
  DotGainLearner learner;
  EXPECT_THROW(learner.start(cv::Mat()), std::invalid_argument);
  EXPECT_THROW(learner.start(cv::Mat(10, 10, CV_32FC1)), std::invalid_argument);
  EXPECT_FALSE(learner.learning());
}

TEST(ImagePreprocessor, DividesByTheDotsGainBeforeItsFill) {
  CameraModel cam;
  cam.K = PinholeK{364.91, 364.97, 379.91, 245.53, 752, 480};
  cam.distortion = DistortionModel::kRadTan;
  cam.distortion_coeffs = Vec4(-0.3178, 0.0962, -0.00011, 0.00033);
  PreprocessParams params;
  params.working_width_px = 180;
  params.working_height_px = 116;
  params.normalize_brightness = false;
  ImagePreprocessor with_dots(cam, params), without(cam, params);
  // The ground, and the same ground under gain 1 + 0.8 over discs (the dots; below saturation).
  cv::Mat raw0(480, 752, CV_8UC1), raw(480, 752, CV_8UC1);
  cv::Mat inv(480, 752, CV_16UC1, cv::Scalar(4096)), core(480, 752, CV_8UC1, cv::Scalar(0));
  cv::RNG rng(9);
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 752; ++x)
      raw0.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(90.0 + 30.0 * std::sin(0.05 * x) * std::cos(0.07 * y));
  raw0.copyTo(raw);
  for (int k = 0; k < 800; ++k) {
    const int cx = rng.uniform(4, 748), cy = rng.uniform(4, 476);
    for (int y = cy - 2; y <= cy + 2; ++y) {
      for (int x = cx - 2; x <= cx + 2; ++x) {
        raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(1.8 * raw0.at<uint8_t>(y, x));
        inv.at<uint16_t>(y, x) = static_cast<uint16_t>(std::lround(4096.0 / 1.8));
      }
    }
    core.at<uint8_t>(cy, cx) = 255;  // the centres filled, the rest divided
  }
  const int id0 = with_dots.dotFillId();
  with_dots.setDotGain(inv);
  EXPECT_TRUE(with_dots.dotGainOn());
  const int id1 = with_dots.dotFillId();
  EXPECT_NE(id1, id0);
  with_dots.setDotFill(core);
  EXPECT_NE(with_dots.dotFillId(), id1);
  PreprocessedFrame a, b;
  with_dots.process(raw, 0.0, &a);
  without.process(raw0, 0.0, &b);
  cv::Mat diff;
  cv::absdiff(a.gray8, b.gray8, diff);
  double worst = 0.0;
  cv::minMaxLoc(diff, nullptr, &worst);
  std::printf("[dot gain] working image divided and filled against the ground without dots: %.0f grey levels at most, "
              "%.3f mean\n", worst, cv::mean(diff)[0]);
  EXPECT_LE(worst, 2.0);  // rounding of the division, and the fill of the centres from divided neighbours
  EXPECT_LT(cv::mean(diff)[0], 0.05);
  // Without the division the dots stay: the same fill leaves them in the working image.
  ImagePreprocessor fill_only(cam, params);
  fill_only.setDotFill(core);
  PreprocessedFrame c;
  fill_only.process(raw, 0.0, &c);
  cv::absdiff(c.gray8, b.gray8, diff);
  cv::minMaxLoc(diff, nullptr, &worst);
  EXPECT_GT(worst, 10.0);
  // Switched off: a new fill id, the raw images as they come.
  with_dots.setDotGain(cv::Mat());
  EXPECT_FALSE(with_dots.dotGainOn());
  EXPECT_THROW(with_dots.setDotGain(cv::Mat(480, 752, CV_8UC1)), std::invalid_argument);
  EXPECT_THROW(with_dots.setDotGain(cv::Mat(10, 10, CV_16UC1)), std::invalid_argument);
}

}  // namespace
}  // namespace diekf
