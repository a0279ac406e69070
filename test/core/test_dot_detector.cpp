// The projector-dot test on the raw images (DotDetector, docs/noise_model.md section 11) and the morphology it
// and the dot removal share: a ground of specks moving under a camera with and without fixed dots, a hovering
// camera, a periodic ground, an uncertain motion; the dilation against OpenCV's.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "../../src/core/dot_detector.h"
#include "../../src/core/morphology.h"

namespace diekf {
namespace {

using internal::DotDetector;

constexpr int kW = 752, kH = 480;

/// A ground larger than the view: smooth brightness 60..180 with small bright specks (2 x 2 px, 40 % brighter)
/// on 6 % of it, the kind of fine bright detail grass or gravel has.
cv::Mat specklyGround(int w, int h, int seed) {
  cv::RNG rng(seed);
  cv::Mat noise(h / 8, w / 8, CV_32FC1);
  rng.fill(noise, cv::RNG::UNIFORM, 60.0, 180.0);
  cv::Mat ground;
  cv::resize(noise, ground, cv::Size(w, h), 0, 0, cv::INTER_CUBIC);
  for (int k = 0; k < w * h / 66; ++k) {
    const int x = rng.uniform(0, w - 2), y = rng.uniform(0, h - 2);
    ground(cv::Rect(x, y, 2, 2)) *= 1.4;
  }
  return ground;
}

/// The same with the specks on a lattice of `period_px` (a checkerboard-like periodic ground).
cv::Mat periodicGround(int w, int h, int period_px) {
  cv::Mat ground(h, w, CV_32FC1, cv::Scalar(100.f));
  for (int y = 0; y + 2 < h; y += period_px)
    for (int x = 0; x + 2 < w; x += period_px) ground(cv::Rect(x, y, 2, 2)) *= 1.8f;
  return ground;
}

/// The simulator's projector (--projector-dots): gain 1 + strength x a Gaussian dot of sigma 1.2 px (or sigma_px).
cv::Mat projectorGain(int dots, double strength, double sigma_px = 1.2) {
  cv::RNG rng(7);
  cv::Mat g(kH, kW, CV_32FC1, cv::Scalar(0.f));
  const int reach = static_cast<int>(std::ceil(4.0 * sigma_px));
  for (int k = 0; k < dots; ++k) {
    const double cx = rng.uniform(0.0, kW - 1.0), cy = rng.uniform(0.0, kH - 1.0);
    for (int y = std::max(0, static_cast<int>(cy) - reach); y <= std::min(kH - 1, static_cast<int>(cy) + reach); ++y)
      for (int x = std::max(0, static_cast<int>(cx) - reach); x <= std::min(kW - 1, static_cast<int>(cx) + reach);
           ++x)
        g.at<float>(y, x) += static_cast<float>(
            std::exp(-0.5 * ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (sigma_px * sigma_px)));
  }
  return 1.0 + strength * g;
}

struct Outcome {
  DotDetector::Verdict verdict = DotDetector::Verdict::kUndecided;
  int frame = -1;  // the frame of the verdict
  int samples = 0;
  double share = 0.0;
  int level = 0;    // the contrast level deciding at the end
  int element = 0;  // the opening's side measured at a verdict of dots (removalElement(21))
  cv::Mat fill;     // the pixels the dots light, at a verdict of dots (fillMask)
  double fill_share = 0.0;
};

/// The camera looks at `ground` through a kW x kH window moving along `path(k)` (integer px), the images times
/// `gain` (empty: none); each frame's ground shift is given to the detector with 1-sigma `sigma_px`, as the
/// estimator does (sample, motion of the pair, position, verdict).
template <class Path>
Outcome fly(const cv::Mat& ground, const cv::Mat& gain, Path path, int frames, double sigma_px = 0.1,
            int levels = 1) {
  DotDetector det;
  det.configure(kW, kH, 5, 0.5, 0.01, levels);
  Outcome out;
  cv::Point prev = path(0);
  cv::Mat view, image;
  for (int k = 0; k < frames && det.armed(); ++k) {
    const cv::Point at = path(k);
    view = ground(cv::Rect(at.x, at.y, kW, kH)).clone();
    if (!gain.empty()) view = view.mul(gain);
    view.convertTo(image, CV_8UC1);
    const bool sampled = det.wantsImage();
    if (sampled) det.addImage(image);
    if (k > 0) {
      std::array<Vec2, DotDetector::kBlocks> shift, sigma;
      shift.fill(Vec2(prev.x - at.x, prev.y - at.y));  // the window moves on: the ground moves back
      sigma.fill(Vec2(sigma_px, sigma_px));
      det.addMotion(shift, sigma);
    }
    if (sampled) det.notePosition(true);
    prev = at;
    const DotDetector::Verdict v = det.decide();
    if (v != DotDetector::Verdict::kUndecided) {
      out.verdict = v;
      out.frame = k;
      if (v == DotDetector::Verdict::kDots) {
        out.element = det.removalElement(21);
        out.fill_share = det.fillMask(&out.fill);
      }
    }
    out.samples = det.samples();
    out.share = det.share();
    out.level = det.level();
  }
  return out;
}

/// A circle of 40 px radius, 3 px per frame, about the centre of a 1000 x 700 ground.
cv::Point circle(int k) {
  const double a = 3.0 * k / 40.0;
  return cv::Point(124 + static_cast<int>(std::lround(40.0 * std::cos(a))),
                   110 + static_cast<int>(std::lround(40.0 * std::sin(a))));
}

TEST(DotDetector, MorphologyEqualsOpenCv) {
  // The dilation and the opening against OpenCV's (rectangular element, default border) to the byte: sides whose
  // radius is unrolled (1-4) or taken by doubling (5-15: spans 8 and 16, windows just above and below a power of
  // two), rows and columns shorter than, equal to and longer than a vector of 16 with the window.
  cv::RNG rng(3);
  for (const cv::Size size : {cv::Size(101, 77), cv::Size(20, 9), cv::Size(35, 18), cv::Size(16, 5), cv::Size(7, 4),
                              cv::Size(64, 40), cv::Size(33, 31)}) {
    cv::Mat img(size, CV_8UC1);
    rng.fill(img, cv::RNG::UNIFORM, 0, 256);
    cv::Mat out(size, CV_8UC1), a(size, CV_8UC1), b(size, CV_8UC1);
    for (int r : {1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 15}) {
      const cv::Mat element = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 1, 2 * r + 1));
      cv::Mat expected;
      cv::dilate(img, expected, element);
      internal::dilateSquare(img.data, out.data, a.data, img.cols, img.rows, r);
      EXPECT_EQ(cv::norm(out, expected, cv::NORM_INF), 0.0) << size << " dilation r = " << r;
      cv::Mat in_place = img.clone();  // (src and dst may be the same buffer)
      internal::dilateSquare(in_place.data, in_place.data, a.data, img.cols, img.rows, r);
      EXPECT_EQ(cv::norm(in_place, expected, cv::NORM_INF), 0.0) << size << " in place, r = " << r;
      cv::morphologyEx(img, expected, cv::MORPH_OPEN, element);
      internal::openSquare(img.data, out.data, a.data, b.data, img.cols, img.rows, r);
      EXPECT_EQ(cv::norm(out, expected, cv::NORM_INF), 0.0) << size << " opening r = " << r;
    }
  }
}

TEST(DotDetector, DiamondOpeningEqualsOpenCv) {
  // The opening by the diamond of L1 radius r against OpenCV's: r erosions, then r dilations, by the 3 x 3 cross.
  cv::RNG rng(5);
  const cv::Mat cross = cv::getStructuringElement(cv::MORPH_CROSS, cv::Size(3, 3));
  for (const cv::Size size : {cv::Size(101, 77), cv::Size(20, 9), cv::Size(7, 4), cv::Size(1, 5), cv::Size(6, 1)}) {
    cv::Mat img(size, CV_8UC1);
    rng.fill(img, cv::RNG::UNIFORM, 0, 256);
    cv::Mat out(size, CV_8UC1), a(size, CV_8UC1), b(size, CV_8UC1);
    for (int r : {0, 1, 2, 3, 5}) {
      cv::Mat expected = img.clone();
      if (r > 0) cv::morphologyEx(img, expected, cv::MORPH_OPEN, cross, cv::Point(-1, -1), r);
      internal::openDiamond(img.data, out.data, a.data, b.data, img.cols, img.rows, r);
      EXPECT_EQ(cv::norm(out, expected, cv::NORM_INF), 0.0) << size << " r = " << r;
    }
  }
}

TEST(DotDetector, AFineTurnedCheckerboardHasSpecksButNoBlobs) {
  // Squares of 8 px turned 45 degrees (the simulator's checkerboard at half resolution): no 5 px square fits in
  // them, so most of their pixels are specks; the diamond does, so none is a blob. The simulator's projector dots on
  // a flat ground: about half of their specks are blobs.
  cv::Mat board(kH, kW, CV_8UC1);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const int u = static_cast<int>(std::floor((x + y) / 11.3)), v = static_cast<int>(std::floor((x - y) / 11.3));
      board.at<uint8_t>(y, x) = ((u + v) & 1) != 0 ? 200 : 40;
    }
  DotDetector checker;
  checker.configure(kW, kH, 5, 0.5, 0.01);
  checker.addImage(board);
  EXPECT_GT(checker.wholeShare(), 0.2);
  EXPECT_LT(checker.blobShare(), 0.01);
  cv::Mat lit;
  cv::Mat(projectorGain(1500, 1.5) * 100.0).convertTo(lit, CV_8UC1);
  DotDetector dots;
  dots.configure(kW, kH, 5, 0.5, 0.01);
  dots.addImage(lit);
  EXPECT_GT(dots.wholeShare(), 0.02);
  EXPECT_GT(dots.blobShare(), 0.3 * dots.wholeShare());
}

TEST(DotDetector, SpeckMaskIsTheDefinitionExactly) {
  // 16 bytes at a time against the definition in plain integers, over random images with saturated pixels and an
  // opening below them (an opening never exceeds its image), for several contrasts and a length with a tail.
  cv::RNG rng(11);
  const size_t n = 16 * 70 + 7;
  std::vector<uint8_t> img(n), opened(n), out(n);
  for (int contrast_q8 : {1, 128, 256, 333, 700, 2560}) {
    for (size_t i = 0; i < n; ++i) {
      img[i] = rng.uniform(0, 10) == 0 ? 255 : static_cast<uint8_t>(rng.uniform(0, 256));
      opened[i] = static_cast<uint8_t>(std::min<int>(img[i], rng.uniform(0, 256)));
    }
    internal::speckMask(img.data(), opened.data(), n, contrast_q8, out.data());
    int specks = 0;
    for (size_t i = 0; i < n; ++i) {
      const int top = img[i] - opened[i];
      const bool speck = 256 * top > contrast_q8 * opened[i] + 256 * DotDetector::kNoiseFloorGrey ||
                         (img[i] == 255 && top > DotDetector::kNoiseFloorGrey);
      ASSERT_EQ(out[i], speck ? 255 : 0) << "contrast " << contrast_q8 << ", byte " << i;
      specks += speck;
    }
    EXPECT_GT(specks, 0);
  }
}

TEST(DotDetector, SpeckLevelsCountTheSpeckMasksPassed) {
  // The levels' test in one pass equals the number of single-contrast masks a pixel is in, for 1-3 levels whose
  // contrasts halve (as configure() makes them) and a length with a tail.
  cv::RNG rng(12);
  const size_t n = 16 * 70 + 7;
  std::vector<uint8_t> img(n), opened(n), out(n), mask(n);
  for (int first_q8 : {128, 256, 700}) {
    for (int levels = 1; levels <= DotDetector::kMaxLevels; ++levels) {
      for (size_t i = 0; i < n; ++i) {
        img[i] = rng.uniform(0, 10) == 0 ? 255 : static_cast<uint8_t>(rng.uniform(0, 256));
        opened[i] = static_cast<uint8_t>(std::min<int>(img[i], rng.uniform(0, 256)));
      }
      std::vector<int> q8;
      for (int l = 0; l < levels; ++l) q8.push_back(first_q8 >> l);
      internal::speckLevels(img.data(), opened.data(), n, q8.data(), levels, out.data());
      std::vector<int> count(n, 0);
      for (int l = 0; l < levels; ++l) {
        internal::speckMask(img.data(), opened.data(), n, q8[static_cast<size_t>(l)], mask.data());
        for (size_t i = 0; i < n; ++i) count[i] += mask[i] != 0;
      }
      std::array<int, DotDetector::kMaxLevels + 1> seen{};
      for (size_t i = 0; i < n; ++i) {
        ASSERT_EQ(out[i], count[i]) << first_q8 << " / 256, " << levels << " levels, byte " << i;
        ++seen[static_cast<size_t>(count[i])];
      }
      for (int c = 0; c <= levels; ++c) EXPECT_GT(seen[static_cast<size_t>(c)], 0) << c << " of " << levels;
    }
  }
}

TEST(DotDetector, FindsFixedDotsWithinTheFirstMotion) {
  const cv::Mat ground = specklyGround(1000, 700, 1);
  const Outcome dots = fly(ground, projectorGain(1500, 1.5), circle, 120);
  EXPECT_EQ(dots.verdict, DotDetector::Verdict::kDots);
  EXPECT_LT(dots.frame, 60);  // within two seconds at 30 Hz of a motion of 3 px per frame
  EXPECT_GT(dots.share, 0.02);
  EXPECT_LT(dots.share, 0.25);
  // 500 dots: fewer, still found.
  const Outcome fewer = fly(ground, projectorGain(500, 1.5), circle, 120);
  EXPECT_EQ(fewer.verdict, DotDetector::Verdict::kDots);
  EXPECT_LT(fewer.share, dots.share);
}

TEST(DotDetector, TheOpeningCoversTheDotsTails) {
  // The side measured at the verdict takes the dots out down to their tails: opened with it, the image with the
  // dots is within a few grey levels of the same view without them where the dots are (what is left: the tails of
  // the neighbouring dots inside the window), against ~19 with the detector's own side of 5 px; wider dots get a
  // wider side, and the side stays within its bounds.
  const cv::Mat ground = specklyGround(1000, 700, 1);
  auto remnant = [&](const cv::Mat& gain, int frame, int side) {
    const cv::Point at = circle(frame);
    cv::Mat plain, dotted, opened_plain(kH, kW, CV_8UC1), opened_dotted(kH, kW, CV_8UC1), a(kH, kW, CV_8UC1),
        b(kH, kW, CV_8UC1);
    ground(cv::Rect(at.x, at.y, kW, kH)).convertTo(plain, CV_8UC1);
    cv::Mat(ground(cv::Rect(at.x, at.y, kW, kH)).mul(gain)).convertTo(dotted, CV_8UC1);
    internal::openSquare(plain.data, opened_plain.data, a.data, b.data, kW, kH, side / 2);
    internal::openSquare(dotted.data, opened_dotted.data, a.data, b.data, kW, kH, side / 2);
    const cv::Mat cores = gain > 1.5;  // where a dot adds more than half the brightness
    cv::Mat diff;
    cv::absdiff(opened_dotted, opened_plain, diff);
    return cv::mean(diff, cores)[0];
  };
  const cv::Mat gain = projectorGain(1500, 1.5);
  const Outcome dots = fly(ground, gain, circle, 120);
  ASSERT_EQ(dots.verdict, DotDetector::Verdict::kDots);
  EXPECT_GE(dots.element, 9);  // a dot of sigma 1.2 px at 2.5x the brightness reaches 1 % at 3.9 px
  EXPECT_LE(dots.element, 21);
  EXPECT_EQ(dots.element % 2, 1);
  const double left = remnant(gain, dots.frame, dots.element), left5 = remnant(gain, dots.frame, 5);
  std::printf("side %d: dots' remnant %.2f grey levels (side 5: %.2f)\n", dots.element, left, left5);
  EXPECT_LT(left, 5.0);
  EXPECT_GT(left5, 3.0 * left);
  const Outcome wide = fly(ground, projectorGain(1500, 1.5, 1.5), circle, 120);
  ASSERT_EQ(wide.verdict, DotDetector::Verdict::kDots);
  EXPECT_GT(wide.element, dots.element);
  const Outcome narrow = fly(ground, projectorGain(1500, 1.5, 0.8), circle, 120);
  ASSERT_EQ(narrow.verdict, DotDetector::Verdict::kDots);
  EXPECT_LT(narrow.element, dots.element);
  std::printf("sides for dots of sigma 0.8, 1.2, 1.5 px: %d, %d, %d\n", narrow.element, dots.element, wide.element);
}

TEST(DotDetector, TheFillMaskCoversTheDotsDownToTheirTails) {
  // The mask the dots are filled over (fillMask): nearly every pixel a dot brightens by more than 5 % (and every
  // core), little beyond where a dot adds 1 %, and more than M itself (the cores); wider dots a wider mask.
  const cv::Mat ground = specklyGround(1000, 700, 1);
  auto check = [&](double sigma_px) {
    const cv::Mat gain = projectorGain(1500, 1.5, sigma_px);
    const Outcome dots = fly(ground, gain, circle, 120);
    EXPECT_EQ(dots.verdict, DotDetector::Verdict::kDots);
    if (dots.verdict != DotDetector::Verdict::kDots) return 0.0;
    EXPECT_EQ(dots.fill.size(), cv::Size(kW, kH));
    const cv::Mat lit5 = gain > 1.05f, cores = gain > 1.5f, dark = gain < 1.01f;
    const double covered5 = cv::countNonZero(dots.fill & lit5) / static_cast<double>(cv::countNonZero(lit5));
    const double covered_cores = cv::countNonZero(dots.fill & cores) / static_cast<double>(cv::countNonZero(cores));
    const double beyond = cv::countNonZero(dots.fill & dark) / static_cast<double>(kW * kH);
    std::printf("sigma %.1f px: fill %.1f %% of the image (M %.1f %%); 5 %% tails covered %.1f %%, cores %.1f %%, "
                "beyond 1 %%: %.1f %% of the image\n",
                sigma_px, 100.0 * dots.fill_share, 100.0 * dots.share, 100.0 * covered5, 100.0 * covered_cores,
                100.0 * beyond);
    EXPECT_NEAR(dots.fill_share, cv::countNonZero(dots.fill) / static_cast<double>(kW * kH), 1e-12);
    EXPECT_GT(dots.fill_share, dots.share);
    EXPECT_GT(covered5, 0.9);
    EXPECT_GT(covered_cores, 0.99);
    EXPECT_LT(beyond, 0.03);
    return dots.fill_share;
  };
  const double normal = check(1.2), wide = check(1.5);
  EXPECT_GT(wide, normal);
}

TEST(DotDetector, GroundSpecksAloneAreNoDots) {
  const Outcome none = fly(specklyGround(1000, 700, 2), cv::Mat(), circle, 200);
  EXPECT_EQ(none.verdict, DotDetector::Verdict::kNoDots);
  EXPECT_LT(none.share, 0.01);
  // A periodic ground brings its specks back onto the same pixels now and then: no dots either.
  const Outcome lattice = fly(periodicGround(1000, 700, 12), cv::Mat(), circle, 200);
  EXPECT_NE(lattice.verdict, DotDetector::Verdict::kDots);
}

TEST(DotDetector, FaintDotsAreFoundAtTheNextContrastLevel) {
  // Dots adding 70 % at their peak stand about 40 % above the 5 px opening (their tails raise it): below the first
  // level's contrast (50 %), one level finds no dots. With two levels the second (25 %) finds them, after the first
  // level's verdict (its ground specks, 40 % brighter here, are counted by chance for longer), and fills them.
  // Bright dots are still decided by the first level, with the same frame and fill as with one level; ground specks
  // alone, or on a lattice, are no dots at every level.
  const cv::Mat ground = specklyGround(1000, 700, 1);
  const cv::Mat faint_gain = projectorGain(1500, 0.7);
  const Outcome one = fly(ground, faint_gain, circle, 200, 0.1, 1);
  EXPECT_EQ(one.verdict, DotDetector::Verdict::kNoDots);
  const Outcome two = fly(ground, faint_gain, circle, 200, 0.1, 2);
  ASSERT_EQ(two.verdict, DotDetector::Verdict::kDots);
  EXPECT_EQ(two.level, 1);
  EXPECT_GT(two.frame, one.frame);
  const cv::Mat lit = faint_gain > 1.25f;  // where a dot adds more than half its peak
  const double covered = cv::countNonZero(two.fill & lit) / static_cast<double>(cv::countNonZero(lit));
  std::printf("faint dots: no dots at frame %d with one level; dots at frame %d at level 1, share %.3f, fill %.1f %% "
              "of the image covering %.1f %% of the pixels a dot brightens by 25 %%\n",
              one.frame, two.frame, two.share, 100.0 * two.fill_share, 100.0 * covered);
  EXPECT_GT(covered, 0.95);
  const Outcome bright1 = fly(ground, projectorGain(1500, 1.5), circle, 200, 0.1, 1);
  const Outcome bright2 = fly(ground, projectorGain(1500, 1.5), circle, 200, 0.1, 2);
  ASSERT_EQ(bright2.verdict, DotDetector::Verdict::kDots);
  EXPECT_EQ(bright2.level, 0);
  EXPECT_EQ(bright2.frame, bright1.frame);
  EXPECT_EQ(cv::countNonZero(bright2.fill != bright1.fill), 0);
  for (int levels = 2; levels <= DotDetector::kMaxLevels; ++levels) {
    const Outcome none = fly(specklyGround(1000, 700, 2), cv::Mat(), circle, 200, 0.1, levels);
    EXPECT_EQ(none.verdict, DotDetector::Verdict::kNoDots) << levels << " levels";
    EXPECT_EQ(none.level, levels - 1);
    const Outcome lattice = fly(periodicGround(1000, 700, 12), cv::Mat(), circle, 200, 0.1, levels);
    EXPECT_NE(lattice.verdict, DotDetector::Verdict::kDots) << levels << " levels";
  }
}

TEST(DotDetector, AHoveringCameraCostsOneSampleAndGivesNoVerdict) {
  const Outcome hover = fly(specklyGround(1000, 700, 3), projectorGain(1500, 1.5),
                            [](int) { return cv::Point(120, 110); }, 150);
  EXPECT_EQ(hover.verdict, DotDetector::Verdict::kUndecided);
  EXPECT_EQ(hover.samples, 1);
}

TEST(DotDetector, AnUncertainMotionDelaysTheVerdict) {
  // 1-sigma of 2 px per frame: the positions start again before they span the required motion.
  const Outcome uncertain = fly(specklyGround(1000, 700, 1), projectorGain(1500, 1.5), circle, 120, 2.0);
  EXPECT_EQ(uncertain.verdict, DotDetector::Verdict::kUndecided);
  const Outcome certain = fly(specklyGround(1000, 700, 1), projectorGain(1500, 1.5), circle, 120, 0.1);
  EXPECT_EQ(certain.verdict, DotDetector::Verdict::kDots);
}

TEST(DotDetector, RejectsBadArguments) {
  DotDetector det;
  EXPECT_THROW(det.configure(kW, kH, 4, 0.5, 0.01), std::invalid_argument);   // even element
  EXPECT_THROW(det.configure(kW, kH, 5, 0.0, 0.01), std::invalid_argument);   // no contrast
  EXPECT_THROW(det.configure(kW, kH, 5, 0.5, 0.0), std::invalid_argument);    // no share
  EXPECT_THROW(det.configure(100, 60, 5, 0.5, 0.01), std::invalid_argument);  // too small
  EXPECT_THROW(det.configure(kW, kH, 5, 0.5, 0.01, 0), std::invalid_argument);  // no level
  EXPECT_THROW(det.configure(kW, kH, 5, 0.5, 0.01, DotDetector::kMaxLevels + 1), std::invalid_argument);
  EXPECT_FALSE(det.armed());
  det.configure(kW, kH, 5, 0.5, 0.01);
  EXPECT_TRUE(det.armed());
  EXPECT_THROW(det.addImage(cv::Mat(kH, kW - 1, CV_8UC1, cv::Scalar(0))), std::invalid_argument);
}

}  // namespace
}  // namespace diekf
