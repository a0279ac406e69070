// Feature-based baseline (the paper's "LK"): corners tracked with pyramidal Lucas-Kanade from the reference to
// the current image; innovation = tracked minus predicted reference position, Huber-robustified, iterated.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

#include "diekf/image_preprocessor.h"
#include "diekf/photometric_update.h"

namespace diekf {

class FeatureUpdate {
 public:
  FeatureUpdate(const FeatureParams& feature, const PhotometricParams& iteration);
  /// Same contract as PhotometricUpdate::update; uses the frames' gray8 images.
  UpdateStats update(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                     const Vec3& gyro_mean_C, double dt_s, State* x, ErrorCov* P, double state_lag_s = 0.0);

 private:
  FeatureParams feature_;
  PhotometricParams iteration_;
  std::vector<cv::Point2f> ref_pts_, cur_pts_;
  std::vector<unsigned char> status_;
  std::vector<float> err_;
};

}  // namespace diekf
