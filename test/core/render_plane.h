// Test and benchmark helper (header-only, no ROS, no file I/O): renders a smoothly textured plane seen by a
// pinhole camera, builds PreprocessedFrames from the rendered images without the ImagePreprocessor, and
// computes the filter's ground-truth quantities (d, mu, vartheta; docs/conventions.md §1-2) for a given pose.
//
// Typical use:
//   test_util::PlaneTexture tex(7);                       // random-phase sinusoids, fixed seed
//   test_util::Plane ground;                              // z = 0 in W, normal (0, 0, 1)
//   PinholeK K = test_util::makeK(180, 116);              // square pixels, principal point at the centre
//   test_util::CameraPose c1 = test_util::lookDownPose(Vec3(0, 0, 1.0));
//   test_util::CameraPose c0 = test_util::propagate(c1, v_W, w_C, -dt);   // earlier (reference) pose
//   PreprocessedFrame ref = test_util::makeFrame(test_util::toGray8(renderPlane(tex, ground, K, c0)), 0.0);
//   test_util::PlaneTruth truth = test_util::planeTruth(ground, c1, v_W);
//
// Frames: W is the world (z up), C the camera optical frame (x right, y down, z forward); R_WC maps C to W.
// The texture is defined in metric coordinates on the plane, so it moves consistently between poses.
#pragma once

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "diekf/camera_model.h"
#include "diekf/image_preprocessor.h"
#include "diekf/types.h"

namespace diekf {
namespace test_util {

/// Smooth procedural texture: a sum of sinusoids with random directions, phases and wavelengths (log-uniform
/// in [min, max] metres), amplitude proportional to the wavelength (a 1/f, "natural" spectrum).
/// Values lie in [0, 1]; deterministic for a given seed on a given standard library.
class PlaneTexture {
 public:
  explicit PlaneTexture(unsigned seed = 1, int components = 24, double min_wavelength_m = 0.05,
                        double max_wavelength_m = 0.5) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    double amp_sum = 0.0;
    for (int i = 0; i < components; ++i) {
      Wave w;
      const double lambda =
          min_wavelength_m * std::pow(max_wavelength_m / min_wavelength_m, unit(rng));
      const double dir = 2.0 * M_PI * unit(rng);
      const double k = 2.0 * M_PI / lambda;  // rad/m
      w.kx = k * std::cos(dir);
      w.ky = k * std::sin(dir);
      w.phase = 2.0 * M_PI * unit(rng);
      w.amp = lambda;
      amp_sum += w.amp;
      waves_.push_back(w);
    }
    // Sum of amplitudes bounds |sum|; sinusoids rarely align, so 0.5 of it keeps good contrast.
    scale_ = amp_sum > 0.0 ? 1.0 / (0.5 * amp_sum) : 0.0;
  }

  /// Texture value at plane coordinates (u, v), metres. In [0, 1].
  double operator()(double u_m, double v_m) const {
    double s = 0.0;
    for (const Wave& w : waves_) s += w.amp * std::sin(w.kx * u_m + w.ky * v_m + w.phase);
    return std::clamp(0.5 + 0.5 * scale_ * s, 0.0, 1.0);
  }

 private:
  struct Wave {
    double kx, ky, phase, amp;
  };
  std::vector<Wave> waves_;
  double scale_ = 0.0;
};

/// Plane {X in W : n . X + e = 0}, n unit and pointing to the camera's side (as /ground_truth/plane).
struct Plane {
  Vec3 n = Vec3::UnitZ();
  double e = 0.0;
};

struct CameraPose {
  Mat3 R_WC = Mat3::Identity();  ///< camera-to-world rotation
  Vec3 p_WC = Vec3::Zero();      ///< camera centre in W, m
};

/// Pinhole intrinsics with square pixels, fx = focal_over_width * width, principal point at the centre.
inline PinholeK makeK(int width_px, int height_px, double focal_over_width = 0.5) {
  PinholeK K;
  K.width = width_px;
  K.height = height_px;
  K.fx = K.fy = focal_over_width * width_px;
  K.cx = 0.5 * (width_px - 1);
  K.cy = 0.5 * (height_px - 1);
  return K;
}

/// Camera at p_WC looking straight down (z_C = -z_W), rotated by `yaw_rad` about the vertical, then tilted
/// by `tilt_x_rad` about its own x axis.
inline CameraPose lookDownPose(const Vec3& p_WC, double yaw_rad = 0.0, double tilt_x_rad = 0.0) {
  Mat3 down;  // columns: x_C, y_C, z_C in W
  down << 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0;
  CameraPose pose;
  pose.R_WC = expSO3(Vec3(0.0, 0.0, yaw_rad)) * down * expSO3(Vec3(tilt_x_rad, 0.0, 0.0));
  pose.p_WC = p_WC;
  return pose;
}

/// Constant-twist motion: the pose `t_s` seconds later (negative: earlier) for world velocity v_W (m/s) and
/// body angular rate w_C (rad/s, what a gyro in C measures): p(t) = p + v_W t, R(t) = R exp([w_C]x t).
inline CameraPose propagate(const CameraPose& pose, const Vec3& v_W, const Vec3& w_C, double t_s) {
  CameraPose out;
  out.p_WC = pose.p_WC + v_W * t_s;
  out.R_WC = pose.R_WC * expSO3(w_C * t_s);
  return out;
}

/// Filter ground truth (docs/conventions.md §2): d = n . p_WC + e, mu = -R_WC^T n, vartheta = R_WC^T v_W / d.
struct PlaneTruth {
  double d_m = 0.0;
  Vec3 mu = Vec3::UnitZ();
  Vec3 vartheta_inv_s = Vec3::Zero();
};

inline PlaneTruth planeTruth(const Plane& plane, const CameraPose& pose, const Vec3& v_W) {
  PlaneTruth t;
  t.d_m = plane.n.dot(pose.p_WC) + plane.e;
  t.mu = -pose.R_WC.transpose() * plane.n;
  t.vartheta_inv_s = pose.R_WC.transpose() * v_W / t.d_m;
  return t;
}

/// Renders the textured plane: CV_32FC1 in [0, 1], `supersample` x `supersample` rays per pixel (box filter).
/// Rays that miss the plane (parallel or behind the camera) give 0.5.
inline cv::Mat renderPlane(const PlaneTexture& texture, const Plane& plane, const PinholeK& K,
                           const CameraPose& pose, int supersample = 3) {
  cv::Mat img(K.height, K.width, CV_32FC1);
  // Orthonormal basis (t1, t2) of the plane for texture coordinates.
  const Vec3 t1 = plane.n.unitOrthogonal();
  const Vec3 t2 = plane.n.cross(t1);
  const int ss = std::max(1, supersample);
  const double dist = plane.n.dot(pose.p_WC) + plane.e;  // signed distance camera -> plane, m
  for (int y = 0; y < K.height; ++y) {
    float* row = img.ptr<float>(y);
    for (int x = 0; x < K.width; ++x) {
      double sum = 0.0;
      for (int sy = 0; sy < ss; ++sy) {
        for (int sx = 0; sx < ss; ++sx) {
          const double u = x - 0.5 + (sx + 0.5) / ss;
          const double v = y - 0.5 + (sy + 0.5) / ss;
          const Vec3 ray_W = pose.R_WC * Vec3((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
          const double denom = plane.n.dot(ray_W);
          const double lambda = denom != 0.0 ? -dist / denom : -1.0;
          if (lambda <= 0.0) {
            sum += 0.5;
            continue;
          }
          const Vec3 X = pose.p_WC + lambda * ray_W;
          sum += texture(t1.dot(X), t2.dot(X));
        }
      }
      row[x] = static_cast<float>(sum / (ss * ss));
    }
  }
  return img;
}

/// [0, 1] float image -> CV_8UC1 (rounded, saturated).
inline cv::Mat toGray8(const cv::Mat& image_01) {
  cv::Mat out;
  image_01.convertTo(out, CV_8UC1, 255.0);
  return out;
}

/// Central differences (I(x+1) - I(x-1)) / 2 and (I(y+1) - I(y-1)) / 2, 0 on the 1-px border (the
/// PreprocessedFrame contract).
inline void centralGradients(const cv::Mat& intensity, cv::Mat* gx, cv::Mat* gy) {
  gx->create(intensity.size(), CV_32FC1);
  gy->create(intensity.size(), CV_32FC1);
  gx->setTo(0.0f);
  gy->setTo(0.0f);
  for (int y = 1; y + 1 < intensity.rows; ++y) {
    const float* up = intensity.ptr<float>(y - 1);
    const float* mid = intensity.ptr<float>(y);
    const float* down = intensity.ptr<float>(y + 1);
    float* ox = gx->ptr<float>(y);
    float* oy = gy->ptr<float>(y);
    for (int x = 1; x + 1 < intensity.cols; ++x) {
      ox[x] = 0.5f * (mid[x + 1] - mid[x - 1]);
      oy[x] = 0.5f * (down[x] - up[x]);
    }
  }
}

/// PreprocessedFrame from an undistorted working image: gray8 kept as is; intensity = optional Gaussian blur
/// (sigma in px, 0 = off), then zero mean and unit variance; gradients by central differences.
inline PreprocessedFrame makeFrame(const cv::Mat& gray8, double t_s, double blur_sigma_px = 0.8) {
  PreprocessedFrame f;
  f.t_s = t_s;
  f.gray8 = gray8.clone();
  gray8.convertTo(f.intensity, CV_32FC1, 1.0 / 255.0);
  if (blur_sigma_px > 0.0) {
    cv::GaussianBlur(f.intensity, f.intensity, cv::Size(0, 0), blur_sigma_px, blur_sigma_px,
                     cv::BORDER_REFLECT101);
  }
  cv::Scalar mean, stddev;
  cv::meanStdDev(f.intensity, mean, stddev);
  const double s = stddev[0] > 1e-9 ? 1.0 / stddev[0] : 1.0;
  f.intensity.convertTo(f.intensity, CV_32FC1, s, -mean[0] * s);
  centralGradients(f.intensity, &f.grad_x, &f.grad_y);
  f.valid = true;
  return f;
}

}  // namespace test_util
}  // namespace diekf
