// Per-frame image preprocessing: undistort-and-rescale to a pinhole working camera, blur, brightness
// normalisation and gradients. Buffers are reused between frames (no allocation after the first frame).
#pragma once

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/params.h"

namespace diekf {

struct PreprocessedFrame {
  double t_s = 0.0;       ///< stamp on the IMU clock, s
  cv::Mat gray8;          ///< CV_8UC1 undistorted working image before blur (feature baseline, debug)
  cv::Mat intensity;      ///< CV_32FC1 blurred, brightness-normalised intensity
  cv::Mat grad_x;         ///< CV_32FC1 d intensity / d x, per pixel
  cv::Mat grad_y;         ///< CV_32FC1 d intensity / d y, per pixel
  bool valid = false;
};

class ImagePreprocessor {
 public:
  ImagePreprocessor(const CameraModel& camera, const PreprocessParams& params);

  /// Pinhole intrinsics of the working image (undistorted, rescaled).
  const PinholeK& workingK() const { return working_K_; }

  /// `raw`: CV_8UC1 at the calibration resolution. Throws std::invalid_argument on a wrong size or type.
  void process(const cv::Mat& raw, double t_s, PreprocessedFrame* out);

 private:
  PreprocessParams params_;
  PinholeK working_K_;
  cv::Mat map_x_, map_y_;  // remap tables (fixed point or float) from working pixel to raw pixel
  cv::Mat scratch_;
};

}  // namespace diekf
