// Per-frame image preprocessing: undistort-and-rescale to a pinhole working camera, blur, brightness
// normalisation and gradients. Buffers are reused between frames (no allocation after the first frame).
//
// Working camera (see image_preprocessor.cpp for the details):
//   width  W' = working_width_px; height H' = working_height_px, or, when that is 0,
//   H' = ceil(W' * height / width) (752x480 -> 90x58 as in the method's paper; the image then never loses
//   field of view, and its last row may lie up to one working pixel beyond the raw image's edge).
//   Scale s_x = W'/width, s_y = H'/height (s_y = s_x when working_height_px = 0, square pixels).
//   fx' = fx s_x, fy' = fy s_y, cx' = (cx + 0.5) s_x - 0.5, cy' = (cy + 0.5) s_y - 0.5
//   (pixel centres at integer coordinates in both images).
// Pixel values are area averages of the raw image over each working pixel's footprint (anti-aliased);
// working pixels that map outside the raw image take the nearest edge values.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/params.h"

namespace diekf {

class FixedPattern;

struct PreprocessedFrame {
  double t_s = 0.0;       ///< stamp on the IMU clock, s
  cv::Mat gray8;          ///< CV_8UC1 undistorted working image before blur (feature baseline, debug)
  cv::Mat intensity;      ///< CV_32FC1 blurred intensity: zero mean, unit variance when normalize_brightness,
                          ///< else grey level / 255 (0..1)
  cv::Mat grad_x;         ///< CV_32FC1 (I(x+1,y) - I(x-1,y)) / 2 of `intensity`, per pixel; 0 on the border
  cv::Mat grad_y;         ///< CV_32FC1 (I(x,y+1) - I(x,y-1)) / 2 of `intensity`, per pixel; 0 on the border
  double grey_per_unit = 255.0;  ///< grey levels per unit of `intensity` (the working image's std when
                                 ///< normalize_brightness, else 255): converts a sensor noise in grey levels
  /// `intensity + level_offset` is proportional to the grey levels (the working image's mean over its std when
  /// normalize_brightness, else 0): a gain on the light acts on it as a factor (brightness model kRows).
  double level_offset = 0.0;
  int dot_removal_px = 0;  ///< the opening the raw image went through (ImagePreprocessor::setDotRemoval; 0: none):
                           ///< two frames with different openings are not a pair
  int dot_fill_id = 0;  ///< the fill the raw image's projector dots went through (ImagePreprocessor::dotFillId;
                        ///< 0: none): two frames with different fills are not a pair
  int resample_id = 0;  ///< the resampling it went through (ImagePreprocessor::resampleId): two frames resampled for
                        ///< different focal lengths are not a pair
  bool valid = false;
};

/// Stage 1 of the preprocessing (ImagePreprocessor::resample): the raw image undistorted and resampled to the
/// working size, before blur. Depends on the raw image alone, so it can be made when the image arrives and the
/// raw image need not be kept (Estimator::addImage).
struct ResampledImage {
  cv::Mat padded;  ///< CV_32FC1 H x (W + 2 blur radius): grey levels, border columns replicated
  cv::Mat gray8;   ///< CV_8UC1 H x W: the same, rounded (PreprocessedFrame::gray8)
  int dot_removal_px = 0;  ///< the opening the raw image went through (PreprocessParams::dot_removal_px; 0: none)
  int dot_fill_id = 0;  ///< the fill the projector dots went through (ImagePreprocessor::dotFillId; 0: none)
  int resample_id = 0;  ///< the resampling it went through (ImagePreprocessor::resampleId)
  bool valid = false;
};

class ImagePreprocessor {
 public:
  /// Throws std::invalid_argument on a camera without resolution or a working size below 3x3 px.
  ImagePreprocessor(const CameraModel& camera, const PreprocessParams& params);

  /// Pinhole intrinsics of the working image (undistorted, rescaled).
  const PinholeK& workingK() const { return working_K_; }
  cv::Size workingSize() const { return cv::Size(working_K_.width, working_K_.height); }

  /// Noise propagation of the preprocessing (docs/noise_model.md), for white sensor noise of variance s^2 per raw
  /// pixel: the working pixel after area resampling and blur has variance s^2 * noiseVarianceGain(), and is
  /// correlated with its neighbours over noiseCorrelationAreaPx() working pixels (the area whose independent
  /// count equals the information: 1 / sum of the squared 2-D blur weights, >= 1).
  double noiseVarianceGain() const { return noise_variance_gain_; }
  double noiseCorrelationAreaPx() const { return noise_correlation_area_px_; }

  /// `raw`: CV_8UC1 at the calibration resolution. Throws std::invalid_argument on a wrong size or type.
  /// The Mats of `out` are written in place when they already have the right size and type (no allocation);
  /// do not keep a shallow copy of a frame you pass here again (swap frames or clone instead).
  /// `pattern` (optional): the camera-fixed pattern model, applied to the blurred image before the brightness
  /// normalisation (FixedPattern::apply; it also keeps the uncorrected image for FixedPattern::learn).
  void process(const cv::Mat& raw, double t_s, PreprocessedFrame* out, FixedPattern* pattern = nullptr);
  /// process() in two stages: resample() needs only the raw image (same contract for `raw`; the buffers of
  /// `stage` are reused), finish() the rest (blur, pattern, normalisation, gradients) and marks `stage`
  /// used (finish() again without a new resample() throws). Same results and buffers as process().
  void resample(const cv::Mat& raw, ResampledImage* stage);
  void finish(ResampledImage* stage, double t_s, PreprocessedFrame* out, FixedPattern* pattern = nullptr);
  /// `frame` (the last one process() gave `pattern`) corrected again with the pattern's current fields
  /// (FixedPattern::reapply), normalised and differentiated again: after the fields changed, so that the next
  /// pair sees one correction in both images. No-op when the pattern cannot (nothing kept, or disabled).
  void reapplyPattern(FixedPattern* pattern, PreprocessedFrame* frame) const;

  /// Re-makes the resampling for a camera whose focal lengths are (1 + focal_scale) x the calibration's, the
  /// distortion and the principal point kept (the focal-length state, docs/algorithm.md section 3.8): each working
  /// pixel then samples the raw pixel its ray reaches in that camera, so the working image is the pinhole image of
  /// intrinsics scaledFocal(workingK(), focal_scale). With a lens distortion this is not the same as scaling the
  /// working intrinsics alone: the calibration's focal lengths multiply the distorted coordinates. Allocates (a rare
  /// event); the images resampled from now on carry a new resampleId(). Throws std::invalid_argument outside
  /// (-0.5, 0.5).
  void setFocalScale(double focal_scale);
  /// The focal scale the resampling is made for (setFocalScale; 0 at construction).
  double focalScale() const { return focal_scale_; }
  /// Which resampling the images resampled from now on go through: 0 at construction, one more per setFocalScale
  /// that changed it (PreprocessedFrame::resample_id).
  int resampleId() const { return resample_id_; }

  /// Switches the bright-dot opening of the raw images (PreprocessParams::dot_removal_px) to a square of side px
  /// (odd, <= 31; 0 or 1 = off) for the images resampled from now on. Throws std::invalid_argument otherwise.
  void setDotRemoval(int px);
  /// Whether px is a side setDotRemoval accepts: 0, or odd in [1, 31].
  static bool validDotRemovalPx(int px);
  int dotRemovalPx() const { return dot_removal_px_; }
  /// Fills the raw pixels of `mask` (CV_8UC1 at the calibration's resolution, nonzero: lit by an IR projector's
  /// dots; DotDetector::fillMask) in the images resampled from now on: each from the nearest pixels outside the
  /// mask along the row and the column (at most kMaxFillReachPx away each way), weighted by the inverse distance;
  /// a pixel with none of them within reach keeps its value. Replaces the opening (setDotRemoval) when both are
  /// set. An empty mask switches the fill off. Builds the taps once (allocates); no allocation per image. Throws
  /// std::invalid_argument for a mask of another size or type. docs/noise_model.md section 11.
  void setDotFill(const cv::Mat& mask);
  /// Share of the raw image filled (setDotFill; 0: no fill).
  double dotFillShare() const { return dot_fill_share_; }
  /// Which fill the images resampled from now on go through: a new number for every setDotFill with a mask and every
  /// setDotGain, 0 for neither (PreprocessedFrame::dot_fill_id).
  int dotFillId() const { return fill_.empty() && dot_gain_.empty() ? 0 : fill_id_; }
  /// Per working pixel (CV_32FC1, working size), the share of its resampling footprint on filled raw pixels (0..1;
  /// empty without a fill): what of it is the fill's interpolation, not the ground's own texture.
  const cv::Mat& dotFillCoverage() const { return dot_fill_coverage_; }
  static constexpr int kMaxFillReachPx = 12;
  /// Divides the raw images resampled from now on by an IR projector's dots' learned gain (docs/noise_model.md
  /// section 11, "Dots divided out"): `inv_gain_q12` (CV_16UC1 at the calibration's resolution) holds per raw pixel
  /// 4096 / gain (4096: unchanged); applied before the fill (setDotFill), whose taps then read divided pixels. An
  /// empty Mat switches it off. Copies the table (allocates); no allocation per image. Each call starts a new
  /// dotFillId() (images divided differently are not a pair). Throws std::invalid_argument for a table of another
  /// size or type.
  void setDotGain(const cv::Mat& inv_gain_q12);
  /// Whether the raw images are divided by a learned gain (setDotGain).
  bool dotGainOn() const { return !dot_gain_.empty(); }
  /// Share of the raw image divided by a gain other than 1 (setDotGain; 0: none).
  double dotGainShare() const { return dot_gain_share_; }

 private:
  // ---- Resampling lookup table (built once in the constructor; see image_preprocessor.cpp). ----
  // Fast path: working pixel k = sum_j wy[j] sum_i wx[i] raw[base + off[j] + i], i over a window of kWindow
  // contiguous raw pixels (8 or 16), j over an even number of raw rows. Integer row pairs (Q14 weights) and
  // float column weights, evaluated with OpenCV's portable 128-bit universal intrinsics.
  static constexpr int kMaxRows = 8;
  static constexpr int kMaxWindow = 16;
  // The footprint's vertical sigma (raw px, at the image's middle) from which the fast path reads row pairs: about
  // one pair in sigma on the pairs (image_preprocessor.cpp).
  static constexpr double kPairRowsMinSigmaRaw = 2.0;
  struct alignas(16) ColumnWeights {
    float w[kMaxWindow] = {};  // weight of raw column base + i (already divided by the Q14 row scale)
  };
  struct alignas(16) RowTaps {
    int16_t wpair[kMaxRows / 2][8] = {};  // (w_2k, w_2k+1) repeated 4x, Q14 (sum over rows = 16384)
    int32_t off[kMaxRows] = {};           // offset of row j from the pixel's base, in source elements
    int n = 0;                            // rows (even)
  };
  struct FastPixel {
    int32_t dst = 0;   // index into the (blur-padded) float buffer
    int32_t out8 = 0;  // index into gray8 (row-major)
    int32_t base = 0;  // offset of the first tap in the source: the raw image, or the row pairs (row_pairs_)
    uint16_t cols = 0, rows = 0;  // ColumnWeights / RowTaps indices
  };
  struct FastGroup {
    int window = 8, rows = 2;
    std::vector<FastPixel> pixels;
  };
  // Generic path (footprints wider than 16 raw px, raw images narrower than 16 px): sparse taps,
  // k = sum_j wy[j] sum_i wx[i] raw[base + yoff[j] + xoff[i]], scalar.
  static constexpr int kMaxTaps = 8;
  struct TapSet {
    int n = 0;
    int32_t off[kMaxTaps] = {};  // byte offsets: i*step (x) or j*step*raw_stride (y)
    float w[kMaxTaps] = {};
  };
  struct SlowPixel {
    int32_t dst = 0, out8 = 0, base = 0;
    uint16_t tx = 0, ty = 0;
  };

  /// The resampling table for focal_scale_ (constructor, setFocalScale).
  void buildResampling();
  /// dot_fill_coverage_ from fill_mask_ through the current table.
  void updateFillCoverage();
  void resampleTable(const uint8_t* src, float* dst, uint8_t* g8);
  /// Steps 3 and 4 of process(): brightness normalisation from the moments of intensity - pivot, gradients.
  void normalizeAndGradients(double sum, double sum_sq, float pivot, PreprocessedFrame* out) const;

  PreprocessParams params_;
  CameraModel camera_;  // the calibration (its focal lengths scaled by 1 + focal_scale_ in the table)
  PinholeK raw_K_;
  PinholeK working_K_;     // the calibration's (focal_scale_ 0)
  double focal_scale_ = 0.0;
  int resample_id_ = 0;
  std::vector<ColumnWeights> columns_;
  std::vector<RowTaps> rows_;
  std::vector<FastGroup> fast_groups_;  // with slow_pixels_, every working pixel appears exactly once
  std::vector<TapSet> tapsets_;
  std::vector<SlowPixel> slow_pixels_;
  // Whether the fast path reads the raw rows summed in pairs (row_pairs_: row k = raw rows 2k and 2k + 1, 16 bit)
  // instead of the raw rows: for footprints several raw rows tall (buildResampling).
  bool pair_rows_ = false;
  cv::Mat row_pairs_;               // CV_16UC1, (h / 2) x w: the source of the fast path when pair_rows_
  std::vector<float> blur_kernel_;  // symmetric Gaussian, taps 0..radius (empty: no blur)
  double noise_variance_gain_ = 1.0;
  double noise_correlation_area_px_ = 1.0;
  int pad_ = 0;                     // blur radius, px: columns of replicated border on each side of the padded stage
  cv::Mat raw_copy_;                // continuous copy of a non-continuous input
  int dot_removal_px_ = 0;          // side of the bright-dot opening (0: off)
  struct FillPixel {
    int32_t at = 0;              // raw pixel filled (byte offset)
    int32_t tap[4] = {};         // raw pixels outside the mask it is filled from (byte offsets)
    int32_t w[4] = {};           // their weights, Q15 (sum exactly 2^15; an unused tap: 0, on the pixel itself)
  };
  std::vector<FillPixel> fill_;     // setDotFill's taps (empty: no fill)
  double dot_fill_share_ = 0.0;
  int fill_id_ = 0;                 // setDotFill's calls with a mask
  cv::Mat dot_fill_coverage_;       // see dotFillCoverage()
  cv::Mat fill_mask_;               // setDotFill's mask as 0 / 1 (empty: no fill), for its coverage
  cv::Mat dot_gain_;                // setDotGain's inverse gains, Q12 (empty: none)
  double dot_gain_share_ = 0.0;     // see dotGainShare()
  cv::Mat dots_removed_;            // the raw image opened by it, or with its dots divided and filled
  cv::Mat dots_scratch_;            // two raw-size scratch images of the opening
  ResampledImage stage_;            // process()'s own stage-1 buffers
  cv::Mat blur_tmp_;                // CV_32FC1 H x W: horizontal pass of the blur
};

}  // namespace diekf
