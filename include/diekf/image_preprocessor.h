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

struct PreprocessedFrame {
  double t_s = 0.0;       ///< stamp on the IMU clock, s
  cv::Mat gray8;          ///< CV_8UC1 undistorted working image before blur (feature baseline, debug)
  cv::Mat intensity;      ///< CV_32FC1 blurred intensity: zero mean, unit variance when normalize_brightness,
                          ///< else grey level / 255 (0..1)
  cv::Mat grad_x;         ///< CV_32FC1 (I(x+1,y) - I(x-1,y)) / 2 of `intensity`, per pixel; 0 on the border
  cv::Mat grad_y;         ///< CV_32FC1 (I(x,y+1) - I(x,y-1)) / 2 of `intensity`, per pixel; 0 on the border
  bool valid = false;
};

class ImagePreprocessor {
 public:
  /// Throws std::invalid_argument on a camera without resolution or a working size below 3x3 px.
  ImagePreprocessor(const CameraModel& camera, const PreprocessParams& params);

  /// Pinhole intrinsics of the working image (undistorted, rescaled).
  const PinholeK& workingK() const { return working_K_; }
  cv::Size workingSize() const { return cv::Size(working_K_.width, working_K_.height); }

  /// `raw`: CV_8UC1 at the calibration resolution. Throws std::invalid_argument on a wrong size or type.
  /// The Mats of `out` are written in place when they already have the right size and type (no allocation);
  /// do not keep a shallow copy of a frame you pass here again (swap frames or clone instead).
  void process(const cv::Mat& raw, double t_s, PreprocessedFrame* out);

 private:
  // Resampling lookup table: working pixel k = sum_j wy[j] sum_i wx[i] raw[base + yoff[j] + xoff[i]].
  // Tap sets are shared between pixels (centroid offsets quantised to 1/16 raw pixel).
  static constexpr int kMaxTaps = 8;
  struct TapSet {
    int n = 0;
    int32_t off[kMaxTaps] = {};  // byte offsets: i*step (x) or j*step*raw_stride (y)
    float w[kMaxTaps] = {};
  };
  struct PixelTaps {
    int32_t out = 0;   // working pixel index (row-major)
    int32_t base = 0;  // byte offset of the first tap in the (continuous) raw image
    uint16_t tx = 0, ty = 0;
  };
  // Pixels grouped by tap counts (nx, ny), so each group runs a kernel with compile-time loop bounds.
  struct TapGroup {
    int nx = 0, ny = 0;
    std::vector<PixelTaps> pixels;
  };

  static void resampleGroup(int nx, int ny, const PixelTaps* pix, std::size_t count, const TapSet* sets,
                            const uint8_t* src, float* dst, uint8_t* g8);

  PreprocessParams params_;
  PinholeK raw_K_;
  PinholeK working_K_;
  std::vector<TapSet> tapsets_;
  std::vector<TapGroup> groups_;   // every working pixel appears in exactly one group
  std::vector<float> blur_kernel_;  // odd length, sums to 1 (empty: no blur)
  cv::Mat raw_copy_;                // continuous copy of a non-continuous input
  cv::Mat resampled_;               // CV_32FC1 working image before blur, grey levels
  cv::Mat blur_tmp_;                // CV_32FC1 horizontal pass of the blur
};

}  // namespace diekf
