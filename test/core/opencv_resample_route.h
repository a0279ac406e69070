// The library routes for the preprocessor's resampling, for the comparison of docs/performance.md
// ("Resampling: hand-written tables or OpenCV"): cv::resize(INTER_AREA) and cv::remap (fixed-point maps,
// bilinear, edge replicated) in either order. The hand-written route is ImagePreprocessor's resampling tables (area average over each working pixel's own
// footprint through the distortion). Used by the accuracy test (test_image_preprocessor.cpp) and the benchmark
// (bench/bench_preprocess.cpp).
#pragma once

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "diekf/camera_model.h"

namespace diekf {
namespace testing_routes {

/// Area first: cv::resize(INTER_AREA) of the raw image to the working scale, then cv::remap (bilinear) through
/// the undistortion at working resolution. Cheap; the bilinear interpolation between area-averaged pixels blurs
/// a second time.
class OpenCvAreaThenRemap {
 public:
  /// raw: the calibration camera; K: the working camera (ImagePreprocessor::workingK()).
  OpenCvAreaThenRemap(const CameraModel& raw, const PinholeK& K) : size_(K.width, K.height) {
    const double sx = static_cast<double>(K.width) / raw.K.width;
    const double sy = static_cast<double>(K.height) / raw.K.height;
    cv::Mat map_x(size_, CV_32FC1), map_y(size_, CV_32FC1);
    for (int v = 0; v < K.height; ++v)
      for (int u = 0; u < K.width; ++u) {
        const Vec2 xd = raw.distort(Vec2((u - K.cx) / K.fx, (v - K.cy) / K.fy));
        const double rx = raw.K.fx * xd.x() + raw.K.cx, ry = raw.K.fy * xd.y() + raw.K.cy;  // raw px
        map_x.at<float>(v, u) = static_cast<float>((rx + 0.5) * sx - 0.5);  // in the resized image
        map_y.at<float>(v, u) = static_cast<float>((ry + 0.5) * sy - 0.5);
      }
    cv::convertMaps(map_x, map_y, map1_, map2_, CV_16SC2);
  }
  /// raw (CV_8UC1) -> working image (CV_8UC1); buffers reused.
  void run(const cv::Mat& raw, cv::Mat* out) {
    cv::resize(raw, small_, size_, 0.0, 0.0, cv::INTER_AREA);
    cv::remap(small_, *out, map1_, map2_, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  }

 private:
  cv::Size size_;
  cv::Mat map1_, map2_, small_;
};

/// Undistortion first: cv::remap (bilinear) of the raw image into the working camera scaled up by the integer
/// k = ceil(raw width / working width) (at least the raw resolution), then cv::resize(INTER_AREA) by exactly k:
/// the mean of k x k bilinear samples over each working pixel's footprint.
class OpenCvRemapThenArea {
 public:
  OpenCvRemapThenArea(const CameraModel& raw, const PinholeK& K)
      : k_((raw.K.width + K.width - 1) / K.width), size_(K.width, K.height), big_size_(K.width * k_, K.height * k_) {
    cv::Mat map_x(big_size_, CV_32FC1), map_y(big_size_, CV_32FC1);
    for (int v = 0; v < big_size_.height; ++v)
      for (int u = 0; u < big_size_.width; ++u) {
        const double uw = (u + 0.5) / k_ - 0.5, vw = (v + 0.5) / k_ - 0.5;  // working px
        const Vec2 xd = raw.distort(Vec2((uw - K.cx) / K.fx, (vw - K.cy) / K.fy));
        map_x.at<float>(v, u) = static_cast<float>(raw.K.fx * xd.x() + raw.K.cx);
        map_y.at<float>(v, u) = static_cast<float>(raw.K.fy * xd.y() + raw.K.cy);
      }
    cv::convertMaps(map_x, map_y, map1_, map2_, CV_16SC2);
  }
  void run(const cv::Mat& raw, cv::Mat* out) {
    cv::remap(raw, big_, map1_, map2_, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    cv::resize(big_, *out, size_, 0.0, 0.0, cv::INTER_AREA);
  }

 private:
  int k_;
  cv::Size size_, big_size_;
  cv::Mat map1_, map2_, big_;
};

/// Reference for the accuracy comparison: the mean of the scene `f(x, y)` (raw px; the raw image holds its point
/// samples) over each working pixel's square footprint mapped through the distortion, n x n sub-samples; NaN
/// where a sub-sample leaves the raw image.
template <class Scene>
cv::Mat footprintAverage(const CameraModel& raw, const PinholeK& K, const Scene& f, int n = 8) {
  cv::Mat ref(K.height, K.width, CV_64FC1);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      double sum = 0.0;
      bool inside = true;
      for (int j = 0; j < n && inside; ++j)
        for (int i = 0; i < n; ++i) {
          const double uu = u - 0.5 + (i + 0.5) / n, vv = v - 0.5 + (j + 0.5) / n;
          const Vec2 xd = raw.distort(Vec2((uu - K.cx) / K.fx, (vv - K.cy) / K.fy));
          const double rx = raw.K.fx * xd.x() + raw.K.cx, ry = raw.K.fy * xd.y() + raw.K.cy;
          if (!(rx >= 0.0 && ry >= 0.0 && rx <= raw.K.width - 1 && ry <= raw.K.height - 1)) {
            inside = false;
            break;
          }
          sum += f(rx, ry);
        }
      ref.at<double>(v, u) = inside ? sum / (n * n) : NAN;
    }
  return ref;
}

/// RMS and largest absolute difference (grey levels) of `img` (CV_8UC1) against `ref` where ref is finite.
inline void compareToReference(const cv::Mat& img, const cv::Mat& ref, double* rms, double* worst, int* count) {
  double sum2 = 0.0;
  *worst = 0.0;
  *count = 0;
  for (int v = 0; v < ref.rows; ++v)
    for (int u = 0; u < ref.cols; ++u) {
      const double r = ref.at<double>(v, u);
      if (!std::isfinite(r)) continue;
      const double e = img.at<uint8_t>(v, u) - r;
      sum2 += e * e;
      *worst = std::max(*worst, std::fabs(e));
      ++*count;
    }
  *rms = *count > 0 ? std::sqrt(sum2 / *count) : 0.0;
}

}  // namespace testing_routes
}  // namespace diekf
