// The projector dots' gain per raw pixel, learned from the ground's motion (docs/noise_model.md section 11,
// "Dots divided out").
//
// A projector's dots multiply the light the ground reflects: raw pixel x reads I(x) = G(x) rho(X), with G fixed
// in the image (1 away from the dots) and rho the ground point X's brightness. The ground point the current image
// sees at x is at x_r in the reference image (the filter's warp after the pair's update); where x_r lies away from
// the dots (G = 1 there), I_c(x) / I_r(x_r) is G(x) itself: the ground's texture cancels, leaving the sensor noise,
// the interpolation of the reference at x_r and the warp's error, all of which change from pair to pair. So per
// pixel of the dots' region G = sum I_c(x) / sum (I_r(x_r) / G(x_r)) over the pairs (the reference's samples scaled
// by the pair's brightness ratio away from the dots: an exposure change is not a gain). A pixel's samples count only
// where the reference's four pixels around x_r have a known gain: outside the region, or learned already (a pixel
// is learned at kMinSamples). Between two images the ground moves a few pixels, less than a dot's radius, so the
// gain is learned from the region's rim inwards, each ring from the one before, until kReadyShare of the region
// is learned.
//
// The temporal mean of each pixel against its surroundings would also give G, but its error is the ground's texture
// averaged along the flight path (2 % r.m.s. per pixel after 300 images on grass, streaks along the motion), which
// biases the distance by 2-3 %; a white 2 % error does not (docs/results.md).
//
// The region: the fill's mask (the dots and their tails, DotDetector::fillMask) grown by kRegionRingsPx. Once
// learned, the estimator divides the raw images by G over the region (ImagePreprocessor::setDotGain) and fills only
// the core: pixels whose gain exceeds kCoreGain (a dot's centre saturates on bright ground) or that saturated in
// more than kCoreClipShare of their samples, or that have too few samples. All buffers are allocated by start().
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/types.h"

namespace diekf {
namespace internal {

class DotGainLearner {
 public:
  /// The raw-to-raw map is given at grid points this far apart (raw px), bilinear in between.
  static constexpr int kGridPx = 16;
  /// The region is the fill's mask grown by this many raw px (the dots' faint tails).
  static constexpr int kRegionRingsPx = 2;
  /// Pairs per pixel before its gain counts: one pair's ratio is off by about 2.5 % (sensor noise, the reference's
  /// interpolation, the warp), so 12 leave about 0.7 %; a white per-pixel error of 2 % in the gain costs nothing
  /// measurable (docs/results.md), a slower start costs the fill's bias meanwhile.
  static constexpr int kMinSamples = 12;
  /// Share of the region's pixels that must have kMinSamples before the gains are used (the rest stays filled:
  /// pixels whose pairs keep landing on the dots' cores, or beyond the image's edge).
  static constexpr double kReadyShare = 0.9;
  /// ...or kMinReadyShare after kMaxPairs pairs (15 s at 30 Hz: a flight that keeps the same few directions).
  static constexpr int kMaxPairs = 450;
  static constexpr double kMinReadyShare = 0.5;
  /// Pixels the dots brighten more than this, or that saturated in more than kCoreClipShare of their pairs, stay
  /// filled (a dot's centre clips on bright ground; the division would darken it).
  static constexpr double kCoreGain = 2.0;
  static constexpr double kCoreClipShare = 0.02;
  /// Samples darker than this (grey levels) are not used: the ratio is noise there.
  static constexpr int kMinGrey = 8;
  /// Gains are bounded to [1 / kMaxGain, kMaxGain].
  static constexpr double kMaxGain = 8.0;

  /// Starts learning for raw images of `fill_mask`'s size (CV_8UC1, nonzero: the dots and their tails). Allocates.
  /// Throws std::invalid_argument on an empty or non-8-bit mask.
  void start(const cv::Mat& fill_mask);
  /// Stops (and frees): after the result was taken, or when the dots are gone.
  void stop();
  /// Learning: started and not stopped.
  bool learning() const { return learning_; }

  /// The grid of the map: columns x rows of points (i kGridPx, j kGridPx), covering the image (the last ones may
  /// lie beyond its edge).
  int gridCols() const { return grid_cols_; }
  int gridRows() const { return grid_rows_; }
  /// Where the caller writes, for grid point (i, j), its position in the reference image (raw px); non-finite: not
  /// seen there. Filled before each observe().
  Vec2* gridTargets() { return grid_.data(); }

  /// One image pair (raw 8-bit images at the calibration size, contiguous; `cur` the current, `ref` the reference,
  /// both undivided), with gridTargets() filled for this pair. No allocation.
  void observe(const uint8_t* cur, const uint8_t* ref);

  /// Share of the region's pixels with kMinSamples pairs.
  double readyShare() const;
  /// Learned: kReadyShare of the region's pixels have their samples, or kMinReadyShare after kMaxPairs pairs (the
  /// rest stays filled).
  bool ready() const;
  /// Pairs observed so far.
  int pairs() const { return pairs_; }
  /// Share of the raw image in the region.
  double regionShare() const;

  /// The learned gains as inverse gains in 1/4096 (CV_16UC1, raw size: 4096 outside the region and in the core)
  /// and the core to fill (CV_8UC1, 255: fill). Returns the core's share of the image. Allocates the outputs.
  double result(cv::Mat* inv_gain_q12, cv::Mat* core) const;
  /// The learned gain of raw pixel (x, y) (1 outside the region; 0 where it has no sample yet).
  double gainAt(int x, int y) const;

 private:
  int width_ = 0, height_ = 0;
  int grid_cols_ = 0, grid_rows_ = 0;
  bool learning_ = false;
  int pairs_ = 0;
  size_t learned_ = 0;              // region pixels with kMinSamples (readyShare)
  cv::Mat region_;                  // CV_8UC1: 1 in the region
  cv::Mat inv_gain_;                // CV_32FC1: 1 / the gain where known (1 outside the region)
  cv::Mat known_;                   // CV_8UC1: 1 where the gain is known (outside the region, or kMinSamples)
  std::vector<int32_t> at_;         // region pixels (y width + x), row by row
  std::vector<int32_t> row_start_;  // per row, its first entry in at_ (and at_.size() at the end)
  std::vector<float> sum_cur_;      // per region pixel: the current images' values summed
  std::vector<float> sum_ref_;      // the reference's interpolated values (scaled by the pair's brightness ratio)
  std::vector<uint16_t> samples_;   // pairs used
  std::vector<uint16_t> clipped_;   // pairs whose current value was saturated
  std::vector<Vec2> grid_;          // gridTargets()
  std::vector<float> row_map_;      // one row's map at the grid columns (x, y interleaved), interpolated vertically
};

/// out = min(255, round(src inv_q12 / 4096)) for n pixels (the raw image divided by a gain given as 4096 / gain).
/// Exact in integers; 16 pixels at a time.
void divideByGain(const uint8_t* src, const uint16_t* inv_q12, size_t n, uint8_t* out);

}  // namespace internal
}  // namespace diekf
