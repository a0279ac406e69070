// ImagePreprocessor: working camera, geometry of the undistort-and-rescale, anti-aliasing, normalisation,
// gradient definition, input validation, buffer reuse.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "diekf/image_preprocessor.h"
#include "diekf/photometric_update.h"

#include "mynt_camera.h"
#include "opencv_resample_route.h"

namespace diekf {
namespace {


CameraModel pinhole(int w, int h) {
  CameraModel m;
  m.K = PinholeK{0.5 * w, 0.5 * w, 0.5 * w - 0.5, 0.5 * h - 0.5, w, h};
  return m;
}

cv::Mat texture(int w, int h, int seed) {
  cv::Mat img(h, w, CV_8UC1);
  cv::RNG rng(seed);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      img.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(
          120.0 + 60.0 * std::sin(0.045 * x + 0.02 * y) * std::cos(0.03 * y) + rng.gaussian(15.0));
  return img;
}

// A 752 x 480 raw image of sinusoidal stripes, amplitude 100 grey levels about 128.
cv::Mat stripes(double period_px, double angle_rad) {
  cv::Mat raw(480, 752, CV_8UC1);
  const double cx = std::cos(angle_rad), sy = std::sin(angle_rad);
  for (int y = 0; y < raw.rows; ++y)
    for (int x = 0; x < raw.cols; ++x)
      raw.at<uint8_t>(y, x) =
          cv::saturate_cast<uint8_t>(128.0 + 100.0 * std::sin(2.0 * M_PI * (cx * x + sy * y) / period_px));
  return raw;
}

double stdDev(const cv::Mat& m, int border) {
  cv::Scalar mean, sd;
  cv::meanStdDev(m(cv::Rect(border, border, m.cols - 2 * border, m.rows - 2 * border)), mean, sd);
  return sd[0];
}

TEST(ImagePreprocessor, WorkingCamera) {
  PreprocessParams p;
  p.working_width_px = 90;  // the paper's working width; height from the aspect ratio
  ImagePreprocessor pre(myntEyeCamera(), p);
  const PinholeK& K = pre.workingK();
  EXPECT_EQ(K.width, 90);
  EXPECT_EQ(K.height, 58);  // ceil(90 * 480 / 752) = ceil(57.45)
  const double s = 90.0 / 752.0;
  EXPECT_DOUBLE_EQ(K.fx, 364.91 * s);
  EXPECT_DOUBLE_EQ(K.fy, 364.97 * s);
  EXPECT_DOUBLE_EQ(K.cx, (379.91 + 0.5) * s - 0.5);
  EXPECT_DOUBLE_EQ(K.cy, (245.53 + 0.5) * s - 0.5);
  EXPECT_EQ(pre.workingSize(), cv::Size(90, 58));

  p.working_height_px = 57;
  ImagePreprocessor pre2(myntEyeCamera(), p);
  EXPECT_EQ(pre2.workingK().height, 57);
  EXPECT_DOUBLE_EQ(pre2.workingK().fy, 364.97 * 57.0 / 480.0);
  EXPECT_DOUBLE_EQ(pre2.workingK().cy, (245.53 + 0.5) * 57.0 / 480.0 - 0.5);

  p.working_width_px = 376;
  p.working_height_px = 0;
  EXPECT_EQ(ImagePreprocessor(myntEyeCamera(), p).workingK().height, 240);

  p.working_width_px = 2;
  EXPECT_THROW(ImagePreprocessor(myntEyeCamera(), p), std::invalid_argument);
}

// A small bright blob around the projection of a 3-D point in the raw (distorted) image must appear at
// K' p in the working image.
void checkBlobGeometry(int working_width, double max_err_px) {
  const CameraModel cam = myntEyeCamera();
  PreprocessParams p;
  p.working_width_px = working_width;
  ImagePreprocessor pre(cam, p);
  const PinholeK& K = pre.workingK();
  const double sigma_raw = 4.0;  // px
  double worst = 0.0;
  for (const Vec3& P : {Vec3(0.0, 0.0, 1.0), Vec3(0.31, -0.22, 1.3), Vec3(-0.55, 0.4, 1.1),
                        Vec3(0.8, 0.45, 1.0), Vec3(-0.75, -0.45, 1.0), Vec3(0.02, 0.51, 1.2)}) {
    Vec2 c_raw;
    ASSERT_TRUE(cam.project(P, &c_raw));
    cv::Mat raw(480, 752, CV_8UC1);
    for (int y = 0; y < raw.rows; ++y)
      for (int x = 0; x < raw.cols; ++x) {
        const double r2 = (x - c_raw.x()) * (x - c_raw.x()) + (y - c_raw.y()) * (y - c_raw.y());
        raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(10.0 + 240.0 * std::exp(-0.5 * r2 / (sigma_raw * sigma_raw)));
      }
    PreprocessedFrame f;
    pre.process(raw, 0.0, &f);
    const Vec2 expected(K.fx * P.x() / P.z() + K.cx, K.fy * P.y() / P.z() + K.cy);
    // Centroid of (I - background) in a window around the expected position.
    double min_v = 1e9;
    for (int y = 0; y < f.intensity.rows; ++y)
      for (int x = 0; x < f.intensity.cols; ++x) min_v = std::min(min_v, double(f.intensity.at<float>(y, x)));
    const int R = std::max(4, working_width / 15);
    double sw = 0, sx = 0, sy = 0;
    for (int y = int(expected.y()) - R; y <= int(expected.y()) + R + 1; ++y)
      for (int x = int(expected.x()) - R; x <= int(expected.x()) + R + 1; ++x) {
        ASSERT_TRUE(x >= 0 && y >= 0 && x < K.width && y < K.height) << "blob too close to the border";
        const double w = f.intensity.at<float>(y, x) - min_v;
        sw += w;
        sx += w * x;
        sy += w * y;
      }
    const Vec2 centroid(sx / sw, sy / sw);
    const double err = (centroid - expected).norm();
    worst = std::max(worst, err);
    EXPECT_LT(err, max_err_px) << "P = " << P.transpose() << " centroid " << centroid.transpose()
                               << " expected " << expected.transpose();
  }
  ::testing::Test::RecordProperty("worst_blob_error_px_w" + std::to_string(working_width), std::to_string(worst));
}

TEST(ImagePreprocessor, GeometryMatchesWorkingK90) { checkBlobGeometry(90, 0.15); }
TEST(ImagePreprocessor, GeometryMatchesWorkingK180) { checkBlobGeometry(180, 0.15); }

TEST(ImagePreprocessor, AntiAliasing) {
  // Stripes far above the working Nyquist frequency (0.5 cycle / working px = 1 cycle / 16.7 raw px at 90 px
  // wide) must come out nearly uniform; stripes well below it must survive.
  const CameraModel cam = myntEyeCamera();
  PreprocessParams p;
  p.working_width_px = 90;
  p.normalize_brightness = false;  // keep grey-level units (intensity = grey / 255)
  ImagePreprocessor pre(cam, p);
  const double in_std = 100.0 / std::sqrt(2.0);
  PreprocessedFrame f;
  double worst_ratio = 0.0;
  for (double period : {3.0, 3.7, 5.0, 6.5}) {
    for (double angle : {0.0, M_PI / 2, 0.6}) {
      pre.process(stripes(period, angle), 0.0, &f);
      const double out_std = 255.0 * stdDev(f.intensity, 2);
      // The default footprint (a Gaussian of 0.4 working px) leaves up to ~4 % of the amplitude (a box: ~15 %
      // for periods of 5-7 raw px even after the blur); point sampling keeps ~100 % (below).
      EXPECT_LT(out_std, 0.08 * in_std) << "period " << period << " angle " << angle;
      worst_ratio = std::max(worst_ratio, out_std / in_std);
    }
  }
  ::testing::Test::RecordProperty("worst_alias_amplitude_ratio", std::to_string(worst_ratio));
  // Plain point sampling at the same positions would keep the full amplitude: verify the test pattern
  // really aliases without the footprint average (nearest raw pixel at the working-pixel centres).
  {
    const cv::Mat raw = stripes(3.7, 0.0);
    const PinholeK& K = pre.workingK();
    cv::Mat nearest(K.height, K.width, CV_32FC1);
    for (int v = 0; v < K.height; ++v)
      for (int u = 0; u < K.width; ++u) {
        const Vec2 xd = cam.distort(Vec2((u - K.cx) / K.fx, (v - K.cy) / K.fy));
        const int x = std::clamp(int(std::lround(cam.K.fx * xd.x() + cam.K.cx)), 0, 751);
        const int y = std::clamp(int(std::lround(cam.K.fy * xd.y() + cam.K.cy)), 0, 479);
        nearest.at<float>(v, u) = raw.at<uint8_t>(y, x);
      }
    EXPECT_GT(stdDev(nearest, 2), 0.5 * in_std);
  }
  // Low frequency (period 60 raw px = 7.2 working px) keeps most of its amplitude.
  pre.process(stripes(60.0, 0.3), 0.0, &f);
  EXPECT_GT(255.0 * stdDev(f.intensity, 3), 0.5 * in_std);
}

// Texture between the working Nyquist frequency and the raw one folds to low working frequencies, where the
// photometric update reads it as motion the wrong way. At 180 px (4.2 raw px per working px) the Gaussian
// footprint must suppress stripes of 3-7 raw px period in every direction much more than a box does.
TEST(ImagePreprocessor, GaussianFootprintSuppressesAliasesAt180) {
  const CameraModel cam = myntEyeCamera();
  const double in_std = 100.0 / std::sqrt(2.0);
  double worst[2] = {0.0, 0.0};  // box, Gaussian
  for (int k = 0; k < 2; ++k) {
    PreprocessParams p;
    p.working_width_px = 180;
    p.normalize_brightness = false;
    p.antialias_sigma_px = k == 0 ? 0.0 : 0.4;
    ImagePreprocessor pre(cam, p);
    PreprocessedFrame f;
    for (double period : {3.0, 4.4, 5.5, 7.0}) {
      for (double angle : {0.0, M_PI / 2, 0.6}) {
        pre.process(stripes(period, angle), 0.0, &f);
        worst[k] = std::max(worst[k], 255.0 * stdDev(f.intensity, 2) / in_std);
      }
    }
    // Low frequency (period 60 raw px = 14 working px) keeps most of its amplitude.
    pre.process(stripes(60.0, 0.3), 0.0, &f);
    EXPECT_GT(255.0 * stdDev(f.intensity, 3), 0.75 * in_std) << "footprint " << k;
  }
  ::testing::Test::RecordProperty("worst_alias_box", std::to_string(worst[0]));
  ::testing::Test::RecordProperty("worst_alias_gaussian", std::to_string(worst[1]));
  // Measured: box 0.177 (vertical stripes of 4.4 px), Gaussian 0.098 (7 px, just above the working Nyquist
  // frequency; 0.066 at 4.4 px, the Gaussian's own response there).
  EXPECT_LT(worst[0], 0.2);
  EXPECT_LT(worst[1], 0.11);
  EXPECT_LT(worst[1], 0.6 * worst[0]);
}

// At 90 px (sigma 3.35 raw px) the footprint's rows are read as row pairs, 16 contiguous raw rows over +-2 sigma
// (until session 62: 8 single rows 2 raw px apart, which sampled texture along y at 2 px and folded stripes of a
// period just above 2 raw px to low frequencies: measured 0.26 of the amplitude, now 0.05). Stripes along y near the
// raw Nyquist period must come out nearly uniform. (The pairs' centroid: LinearRampGradients and
// ResamplingMatchesSmoothImageAtMappedCentre.)
TEST(ImagePreprocessor, RowPairsAt90PxAverageEveryRawRow) {
  const CameraModel cam = myntEyeCamera();
  PreprocessParams p;
  p.working_width_px = 90;
  p.normalize_brightness = false;
  ImagePreprocessor pre(cam, p);
  PreprocessedFrame f;
  const double in_std = 100.0 / std::sqrt(2.0);
  double worst = 0.0;
  for (double period : {2.1, 2.2, 2.4, 2.7}) {
    pre.process(stripes(period, M_PI / 2), 0.0, &f);
    worst = std::max(worst, 255.0 * stdDev(f.intensity, 2) / in_std);
  }
  ::testing::Test::RecordProperty("worst_row_alias_90", std::to_string(worst));
  EXPECT_LT(worst, 0.1);
}

// The noise figures the update's noise floor and correlation area come from (noiseVarianceGain,
// noiseCorrelationAreaPx, derived from the resampling tables and the blur) against a Monte-Carlo measurement on
// white raw noise, within 10 % and 15 %: the variance of a working pixel, and the sum of its autocorrelation
// over lags up to 6 px (the variance of a large area's sum over that of as many independent pixels). The box
// footprint's figures are checked too (antialias_sigma_px = 0).
TEST(ImagePreprocessor, NoiseFiguresMatchMonteCarlo) {
  const CameraModel cam = myntEyeCamera();
  cv::RNG rng(7);
  constexpr int kLag = 6;
  for (int width : {90, 180}) {
    for (double aa : {0.0, 0.4}) {
      PreprocessParams p;
      p.working_width_px = width;
      p.normalize_brightness = false;
      p.antialias_sigma_px = aa;
      ImagePreprocessor pre(cam, p);
      const PinholeK& K = pre.workingK();
      const double sigma_grey = 12.0;
      double cov[2 * kLag + 1][2 * kLag + 1] = {};
      long n = 0;
      cv::Mat raw(480, 752, CV_8UC1);
      PreprocessedFrame f;
      // The middle of the image, where the figures are derived (the distortion changes them across it).
      const int u0 = 3 * K.width / 8, u1 = 5 * K.width / 8, v0 = 3 * K.height / 8, v1 = 5 * K.height / 8;
      for (int frame = 0; frame < 100; ++frame) {
        for (int y = 0; y < raw.rows; ++y)
          for (int x = 0; x < raw.cols; ++x)
            raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(128.0 + rng.gaussian(sigma_grey));
        pre.process(raw, 0.0, &f);
        auto e = [&](int u, int v) { return 255.0 * f.intensity.at<float>(v, u) - 128.0; };
        for (int v = v0; v < v1; ++v)
          for (int u = u0; u < u1; ++u) {
            const double ep = e(u, v);
            for (int dv = -kLag; dv <= kLag; ++dv)
              for (int du = -kLag; du <= kLag; ++du) cov[dv + kLag][du + kLag] += ep * e(u + du, v + dv);
            ++n;
          }
      }
      const double var_pix = cov[kLag][kLag] / n;
      double area = 0.0;
      for (const auto& row : cov)
        for (double c : row) area += c / cov[kLag][kLag];
      const double gain_ratio = pre.noiseVarianceGain() * sigma_grey * sigma_grey / var_pix;
      const double area_ratio = pre.noiseCorrelationAreaPx() / area;
      EXPECT_NEAR(gain_ratio, 1.0, 0.1) << width << " px, aa " << aa;  // measured: 0.94-1.01
      EXPECT_NEAR(area_ratio, 1.0, 0.15) << width << " px, aa " << aa;  // measured: 0.99-1.13
      const std::string tag = std::to_string(width) + (aa > 0.0 ? "_gaussian" : "_box");
      ::testing::Test::RecordProperty("gain_ratio_" + tag, std::to_string(gain_ratio));
      ::testing::Test::RecordProperty("area_ratio_" + tag, std::to_string(area_ratio));
      ::testing::Test::RecordProperty("area_" + tag, std::to_string(area));
    }
  }
}

/// A smooth raw image (752 x 480) and its value at raw (x, y): the footprint average equals the value at the
/// footprint's centre to the grey levels' rounding.
double smoothRawValue(double x, double y) {
  return 128.0 + 90.0 * std::sin(0.011 * x + 0.006 * y) * std::cos(0.008 * y);
}
cv::Mat smoothRawImage() {
  cv::Mat raw(480, 752, CV_8UC1);
  for (int y = 0; y < raw.rows; ++y)
    for (int x = 0; x < raw.cols; ++x) raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(smoothRawValue(x, y));
  return raw;
}

// Every resampling path (8- and 16-column windows of the vectorised kernel, the scalar path for footprints
// wider than 16 raw px) against a plain double evaluation: on a smooth raw image the footprint average equals
// the image value at the mapped centre (a wrong weight, lane or row would be off by many grey levels).
TEST(ImagePreprocessor, ResamplingMatchesSmoothImageAtMappedCentre) {
  const CameraModel cam = myntEyeCamera();
  const auto f = smoothRawValue;
  const cv::Mat raw = smoothRawImage();
  for (int width : {30, 64, 90, 180, 376}) {
    PreprocessParams p;
    p.working_width_px = width;
    ImagePreprocessor pre(cam, p);
    const PinholeK& K = pre.workingK();
    PreprocessedFrame out;
    pre.process(raw, 0.0, &out);
    const double margin = 2.0 * 752.0 / width + 2.0;  // raw px: footprint half-width plus slack
    int checked = 0;
    double worst = 0.0;
    for (int v = 0; v < K.height; ++v)
      for (int u = 0; u < K.width; ++u) {
        const Vec2 xd = cam.distort(Vec2((u - K.cx) / K.fx, (v - K.cy) / K.fy));
        const double cx = cam.K.fx * xd.x() + cam.K.cx, cy = cam.K.fy * xd.y() + cam.K.cy;
        if (cx < margin || cy < margin || cx > 751 - margin || cy > 479 - margin) continue;
        ++checked;
        worst = std::max(worst, std::fabs(out.gray8.at<uint8_t>(v, u) - f(cx, cy)));
      }
    EXPECT_GT(checked, K.width * K.height / 2) << width;
    EXPECT_LT(worst, 1.2) << "working width " << width;  // u8 rounding of input and output, curvature
  }
}

// setFocalScale: the working image of a camera whose focal lengths are (1 + e) x the calibration's (distortion and
// principal point kept) is the pinhole image of scaledFocal(workingK(), e): each working pixel holds the raw image
// where that camera's projection puts the ray of the scaled working intrinsics. With the MYNT EYE's barrel distortion
// this is not the working intrinsics scaled alone (the raw image sampled through the calibration's focal lengths):
// at the corners the two differ by half of e again (docs/algorithm.md section 3.8). Frames carry the resampling's id.
TEST(ImagePreprocessor, FocalScaleResamplesForTheCamerasOwnFocalLengths) {
  const CameraModel cam = myntEyeCamera();
  const auto f = smoothRawValue;
  const cv::Mat raw = smoothRawImage();
  PreprocessParams p;
  p.working_width_px = 180;
  ImagePreprocessor pre(cam, p);
  EXPECT_EQ(pre.resampleId(), 0);
  EXPECT_EQ(pre.focalScale(), 0.0);
  PreprocessedFrame before;
  pre.process(raw, 0.0, &before);
  const double e = 0.03;
  pre.setFocalScale(e);
  EXPECT_EQ(pre.resampleId(), 1);
  pre.setFocalScale(e);  // unchanged: not re-made
  EXPECT_EQ(pre.resampleId(), 1);
  PreprocessedFrame out;
  pre.process(raw, 0.0, &out);
  EXPECT_EQ(before.resample_id, 0);
  EXPECT_EQ(out.resample_id, 1);
  const PinholeK K = pre.workingK();  // the calibration's working intrinsics, unchanged
  const PinholeK Ke = scaledFocal(K, e);
  const double margin = 2.0 * 752.0 / 180 + 2.0;
  int checked = 0, corners = 0;
  double worst = 0.0, corner_gap = 0.0;
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      // The scaled camera's raw pixel for the ray of the scaled working intrinsics.
      const Vec2 xd = cam.distort(Vec2((u - Ke.cx) / Ke.fx, (v - Ke.cy) / Ke.fy));
      const double cx = (1.0 + e) * cam.K.fx * xd.x() + cam.K.cx, cy = (1.0 + e) * cam.K.fy * xd.y() + cam.K.cy;
      if (cx < margin || cy < margin || cx > 751 - margin || cy > 479 - margin) continue;
      ++checked;
      worst = std::max(worst, std::fabs(out.gray8.at<uint8_t>(v, u) - f(cx, cy)));
      // The working intrinsics scaled alone: the raw image through the calibration's focal lengths.
      const double rx = cam.K.fx * xd.x() + cam.K.cx, ry = cam.K.fy * xd.y() + cam.K.cy;
      const double r2 = xd.squaredNorm();
      if (r2 > 0.5) {
        ++corners;
        corner_gap = std::max(corner_gap, std::hypot(cx - rx, cy - ry));
      }
    }
  EXPECT_GT(checked, K.width * K.height / 2);
  EXPECT_LT(worst, 1.2);
  ASSERT_GT(corners, 20);
  EXPECT_GT(corner_gap, 5.0);  // raw px: the two models are far apart at the corners
  // Back to 0: the first table again.
  pre.setFocalScale(0.0);
  EXPECT_EQ(pre.resampleId(), 2);
  PreprocessedFrame again;
  pre.process(raw, 0.0, &again);
  EXPECT_EQ(cv::norm(again.gray8, before.gray8, cv::NORM_INF), 0.0);
  EXPECT_THROW(pre.setFocalScale(0.6), std::invalid_argument);
}

// The hand-written resampling against the library routes (cv::resize INTER_AREA and cv::remap in either order;
// docs/performance.md, "Resampling: hand-written tables or OpenCV"), all against the mean of the scene over each
// working pixel's footprint through the distortion (8 x 8 sub-samples of the function the raw image samples), on
// a texture with detail down to a few raw pixels.
TEST(ImagePreprocessor, ResamplingAgainstOpenCvRoutes) {
  const CameraModel cam = myntEyeCamera();
  auto f = [](double x, double y) {
    return 128.0 + 50.0 * std::sin(0.031 * x + 0.017 * y) * std::cos(0.023 * y - 0.011 * x) +
           40.0 * std::sin(0.21 * x) * std::sin(0.17 * y) + 20.0 * std::sin(0.9 * x + 0.4 * y);
  };
  cv::Mat raw(480, 752, CV_8UC1);
  for (int y = 0; y < raw.rows; ++y)
    for (int x = 0; x < raw.cols; ++x) raw.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(f(x, y));
  for (int width : {90, 180, 376}) {
    PreprocessParams p;
    p.working_width_px = width;
    p.antialias_sigma_px = 0.0;  // the reference below is the mean over the footprint: the box
    ImagePreprocessor pre(cam, p);
    PreprocessedFrame out;
    pre.process(raw, 0.0, &out);
    cv::Mat area_remap, remap_area;
    testing_routes::OpenCvAreaThenRemap(cam, pre.workingK()).run(raw, &area_remap);
    testing_routes::OpenCvRemapThenArea(cam, pre.workingK()).run(raw, &remap_area);
    const cv::Mat ref = testing_routes::footprintAverage(cam, pre.workingK(), f);
    double rms_hand, worst_hand, rms_ar, worst_ar, rms_ra, worst_ra;
    int n;
    testing_routes::compareToReference(out.gray8, ref, &rms_hand, &worst_hand, &n);
    testing_routes::compareToReference(area_remap, ref, &rms_ar, &worst_ar, &n);
    testing_routes::compareToReference(remap_area, ref, &rms_ra, &worst_ra, &n);
    std::printf("width %d (%d px compared), RMS / max error in grey levels: hand-written %.3f / %.2f, "
                "area then remap %.3f / %.2f, remap then area %.3f / %.2f\n",
                width, n, rms_hand, worst_hand, rms_ar, worst_ar, rms_ra, worst_ra);
    EXPECT_GT(n, pre.workingK().width * pre.workingK().height / 2);
    // Measured (docs/performance.md): the hand-written tables are 5-7x closer to the footprint mean than area then
    // remap (which costs 8-27x the whole preprocessing at 90 and 180 px); remap then area is closer still at 90 and
    // 180 px but costs 20-50x the whole preprocessing there.
    EXPECT_LT(rms_hand, 0.5 * rms_ar) << "width " << width;
    EXPECT_LT(rms_hand, 2.0) << "width " << width;
    EXPECT_LT(rms_ra, rms_ar) << "width " << width;
  }
}

TEST(ImagePreprocessor, NormalisationZeroMeanUnitVariance) {
  ImagePreprocessor pre(myntEyeCamera(), PreprocessParams{});
  PreprocessedFrame f;
  pre.process(texture(752, 480, 3), 1.5, &f);
  ASSERT_TRUE(f.valid);
  EXPECT_DOUBLE_EQ(f.t_s, 1.5);
  cv::Scalar mean, sd;
  cv::meanStdDev(f.intensity, mean, sd);
  EXPECT_NEAR(mean[0], 0.0, 1e-5);
  EXPECT_NEAR(sd[0], 1.0, 1e-4);
  // Brightness and contrast changes of the raw image do not change the normalised output much.
  cv::Mat brighter;
  texture(752, 480, 3).convertTo(brighter, CV_8UC1, 0.6, 40.0);
  PreprocessedFrame f2;
  pre.process(brighter, 1.6, &f2);
  EXPECT_LT(cv::norm(f.intensity, f2.intensity, cv::NORM_INF), 0.1);
}

// Bright dots of an IR projector (Gaussian, sigma 1.2 raw px, +150 grey levels at the peak, one every ~14 x 14 raw px)
// on a smooth texture: the opening of dot_removal_px = 5 takes them out of the working image, and without it
// they stay; an even or negative size is refused with the key's name.
TEST(ImagePreprocessor, DotRemovalTakesProjectorDotsOut) {
  const cv::Mat ground = stripes(60.0, 0.4);
  cv::Mat dotted = ground.clone();
  cv::RNG rng(7);
  for (int k = 0; k < 1800; ++k) {
    const double cx = rng.uniform(0.0, 752.0), cy = rng.uniform(0.0, 480.0);
    for (int y = std::max(0, int(cy) - 4); y <= std::min(479, int(cy) + 4); ++y)
      for (int x = std::max(0, int(cx) - 4); x <= std::min(751, int(cx) + 4); ++x) {
        const double r2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
        dotted.at<uint8_t>(y, x) =
            cv::saturate_cast<uint8_t>(dotted.at<uint8_t>(y, x) + 150.0 * std::exp(-0.5 * r2 / (1.2 * 1.2)));
      }
  }
  auto working = [](const cv::Mat& raw, int dot_removal_px) {
    PreprocessParams p;
    p.normalize_brightness = false;
    p.dot_removal_px = dot_removal_px;
    ImagePreprocessor pre(myntEyeCamera(), p);
    PreprocessedFrame f;
    pre.process(raw, 0.0, &f);
    return f.intensity.clone();
  };
  const int b = 4;
  const cv::Rect inner(b, b, 180 - 2 * b, 116 - 2 * b);
  auto rms = [&](const cv::Mat& a, const cv::Mat& c) { return cv::norm(a(inner), c(inner), cv::NORM_L2) / std::sqrt(inner.area()); };
  const cv::Mat clean = working(ground, 0), opened = working(ground, 5);
  const double kept = rms(working(dotted, 0), clean);      // the dots in the working image
  const double removed = rms(working(dotted, 5), opened);  // what is left of them after the opening
  const double ground_change = rms(opened, clean);         // what the opening does to the ground alone
  std::printf("dots: kept %.4f, left %.4f, ground changed by %.4f (rms, grey / 255)\n", kept, removed, ground_change);
  EXPECT_GT(kept, 8.0 / 255.0);
  EXPECT_LT(removed, 0.5 * kept);  // 0.35: dots closer than the element to each other stay in part
  EXPECT_LT(ground_change, 0.1 * kept);
  // The opening is OpenCV's (a square element, the image's outside not counted), written without allocation.
  for (int side : {3, 5, 9}) {
    cv::Mat opened;
    cv::morphologyEx(dotted, opened, cv::MORPH_OPEN, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side)));
    EXPECT_EQ(cv::norm(working(dotted, side), working(opened, 0), cv::NORM_INF), 0.0) << "side " << side;
  }
  for (int bad : {-1, 4}) {
    PreprocessParams p;
    p.dot_removal_px = bad;
    try {
      ImagePreprocessor pre(myntEyeCamera(), p);
      FAIL() << "no exception for dot_removal_px = " << bad;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("dot_removal_px"), std::string::npos) << e.what();
    }
  }
}

// The same kind of dots as a projector makes them (a gain on the ground's light: 1 + 1.5 x a Gaussian of sigma
// 1.2 raw px), filled from the ground around them (setDotFill) with a mask of where they add more than 3 %: the
// working image is then closer to the ground's than the 11 px opening's (which the detector measures for such
// dots) and, unlike the opening's, not brighter on average (an opening only rises where a dot lit a window's
// minimum: remains fixed in the image); pixels whose footprint does not reach the mask are the ground's exactly;
// an empty mask switches the fill off; a mask of the wrong size is refused.
TEST(ImagePreprocessor, DotFillTakesProjectorDotsOutWithoutRemains) {
  const cv::Mat ground = stripes(60.0, 0.4);
  cv::Mat gain(480, 752, CV_32FC1, cv::Scalar(0.f));
  cv::RNG rng(7);
  for (int k = 0; k < 1500; ++k) {
    const double cx = rng.uniform(0.0, 752.0), cy = rng.uniform(0.0, 480.0);
    for (int y = std::max(0, int(cy) - 5); y <= std::min(479, int(cy) + 5); ++y)
      for (int x = std::max(0, int(cx) - 5); x <= std::min(751, int(cx) + 5); ++x) {
        const double r2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
        gain.at<float>(y, x) += static_cast<float>(std::exp(-0.5 * r2 / (1.2 * 1.2)));
      }
  }
  gain = 1.0 + 1.5 * gain;
  cv::Mat ground_f, dotted;
  ground.convertTo(ground_f, CV_32FC1);
  cv::Mat(ground_f.mul(gain)).convertTo(dotted, CV_8UC1);
  const cv::Mat mask = gain > 1.03f;
  PreprocessParams p;
  p.normalize_brightness = false;
  auto working = [&](const cv::Mat& raw, int dot_removal_px, const cv::Mat& fill) {
    PreprocessParams q = p;
    q.dot_removal_px = dot_removal_px;
    ImagePreprocessor pre(myntEyeCamera(), q);
    pre.setDotFill(fill);
    PreprocessedFrame f;
    pre.process(raw, 0.0, &f);
    EXPECT_EQ(f.dot_fill_id != 0, !fill.empty());
    return f.intensity.clone();
  };
  const int b = 4;
  const cv::Rect inner(b, b, 180 - 2 * b, 116 - 2 * b);
  auto rms = [&](const cv::Mat& a, const cv::Mat& c) {
    return cv::norm(a(inner), c(inner), cv::NORM_L2) / std::sqrt(inner.area());
  };
  auto mean_diff = [&](const cv::Mat& a, const cv::Mat& c) { return cv::mean(cv::Mat(a(inner) - c(inner)))[0]; };
  const cv::Mat clean = working(ground, 0, cv::Mat()), none = working(dotted, 0, cv::Mat());
  const cv::Mat filled = working(dotted, 0, mask), opened = working(dotted, 11, cv::Mat());
  const cv::Mat ground_opened = working(ground, 11, cv::Mat());
  const double kept = rms(none, clean), left_fill = rms(filled, clean), left_open = rms(opened, ground_opened);
  const double bias_fill = mean_diff(filled, clean), bias_open = mean_diff(opened, ground_opened);
  std::printf("dots: kept %.4f; filled: left %.4f, mean %+.4f; opened (11 px): left %.4f, mean %+.4f (grey / 255)\n",
              kept, left_fill, bias_fill, left_open, bias_open);
  EXPECT_GT(kept, 8.0 / 255.0);
  EXPECT_LT(left_fill, 0.25 * kept);
  EXPECT_LT(left_fill, left_open);
  EXPECT_GT(bias_open, 0.5 / 255.0);                  // the opening's remains: brighter
  EXPECT_LT(std::abs(bias_fill), 0.25 * bias_open);   // the fill's: about even
  // Untouched where the footprint (a few raw px) does not reach the mask: a mask only in the left half.
  cv::Mat half = mask.clone();
  half(cv::Rect(376, 0, 376, 480)).setTo(0);
  cv::Mat half_dotted = ground.clone();
  dotted(cv::Rect(0, 0, 376, 480)).copyTo(half_dotted(cv::Rect(0, 0, 376, 480)));
  const cv::Mat half_filled = working(half_dotted, 0, half);
  const cv::Rect right(100, b, 180 - 100 - b, 116 - 2 * b);
  EXPECT_EQ(cv::norm(half_filled(right), clean(right), cv::NORM_INF), 0.0);
  // An empty mask: no fill.
  EXPECT_EQ(cv::norm(working(dotted, 0, cv::Mat()), none, cv::NORM_INF), 0.0);
  ImagePreprocessor pre(myntEyeCamera(), p);
  EXPECT_THROW(pre.setDotFill(cv::Mat(240, 376, CV_8UC1, cv::Scalar(0))), std::invalid_argument);
  EXPECT_THROW(pre.setDotFill(cv::Mat(480, 752, CV_32FC1, cv::Scalar(0))), std::invalid_argument);
  pre.setDotFill(mask);
  EXPECT_NEAR(pre.dotFillShare(), cv::countNonZero(mask) / (752.0 * 480.0), 1e-12);
}

TEST(ImagePreprocessor, UniformImagesGiveFiniteZeros) {
  ImagePreprocessor pre(myntEyeCamera(), PreprocessParams{});
  PreprocessedFrame f;
  for (int value : {0, 1, 128, 255}) {
    pre.process(cv::Mat(480, 752, CV_8UC1, cv::Scalar(value)), 0.0, &f);
    EXPECT_TRUE(cv::checkRange(f.intensity)) << value;
    EXPECT_TRUE(cv::checkRange(f.grad_x));
    EXPECT_TRUE(cv::checkRange(f.grad_y));
    EXPECT_EQ(cv::norm(f.intensity, cv::NORM_INF), 0.0) << value;
    EXPECT_EQ(cv::norm(f.grad_x, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(f.grad_y, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(f.gray8, cv::Mat(f.gray8.size(), CV_8UC1, cv::Scalar(value)), cv::NORM_INF), 0.0);
  }
}

TEST(ImagePreprocessor, GradientsAreCentralDifferences) {
  ImagePreprocessor pre(myntEyeCamera(), PreprocessParams{});
  PreprocessedFrame f;
  pre.process(texture(752, 480, 5), 0.0, &f);
  const cv::Mat& I = f.intensity;
  ASSERT_GT(stdDev(f.grad_x, 1), 0.05);  // non-trivial texture
  for (int y = 0; y < I.rows; ++y)
    for (int x = 0; x < I.cols; ++x) {
      const bool border = x == 0 || y == 0 || x == I.cols - 1 || y == I.rows - 1;
      const float ex = border ? 0.f : 0.5f * (I.at<float>(y, x + 1) - I.at<float>(y, x - 1));
      const float ey = border ? 0.f : 0.5f * (I.at<float>(y + 1, x) - I.at<float>(y - 1, x));
      ASSERT_FLOAT_EQ(f.grad_x.at<float>(y, x), ex) << x << "," << y;
      ASSERT_FLOAT_EQ(f.grad_y.at<float>(y, x), ey) << x << "," << y;
    }
}

TEST(ImagePreprocessor, LinearRampGradients) {
  // Undistorted camera, exact 8x downscale: a raw ramp of a grey levels per raw px along x and b along y is a
  // working ramp of 8a, 8b per working px (the footprint average of a linear function is exact).
  const CameraModel cam = pinhole(752, 480);
  PreprocessParams p;
  p.working_width_px = 94;  // 752 / 8
  p.normalize_brightness = false;
  p.blur_sigma_px = 0.8;
  ImagePreprocessor pre(cam, p);
  ASSERT_EQ(pre.workingK().height, 60);
  const double a = 0.25, b = 0.0625;
  cv::Mat raw(480, 752, CV_8UC1);
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 752; ++x) raw.at<uint8_t>(y, x) = static_cast<uint8_t>(10 + a * x + b * y);  // <= 228
  PreprocessedFrame f;
  pre.process(raw, 0.0, &f);
  const int r = 4;  // beyond the blur radius ceil(3 * 0.8) = 3 and the border
  for (int y = r; y < 60 - r; ++y)
    for (int x = r; x < 94 - r; ++x) {
      // Raw values are floor(20 + a x + b y), a staircase that the sparse footprint taps see slightly
      // unevenly: allow 1 % of the slope (a wrong scale or definition would be off by 50 % or more).
      EXPECT_NEAR(255.0 * f.grad_x.at<float>(y, x), 8 * a, 2e-2) << x << "," << y;
      EXPECT_NEAR(255.0 * f.grad_y.at<float>(y, x), 8 * b, 1e-2) << x << "," << y;
    }
}

TEST(ImagePreprocessor, InvalidInput) {
  ImagePreprocessor pre(myntEyeCamera(), PreprocessParams{});
  PreprocessedFrame f;
  auto expectMessage = [&](const cv::Mat& img, const std::string& got) {
    try {
      pre.process(img, 0.0, &f);
      FAIL() << "no exception for " << got;
    } catch (const std::invalid_argument& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("CV_8UC1 752x480"), std::string::npos) << msg;
      EXPECT_NE(msg.find(got), std::string::npos) << msg;
    }
  };
  expectMessage(cv::Mat(480, 640, CV_8UC1, cv::Scalar(0)), "CV_8UC1 640x480");
  expectMessage(cv::Mat(480, 752, CV_8UC3, cv::Scalar(0)), "CV_8UC3 752x480");
  expectMessage(cv::Mat(480, 752, CV_16UC1, cv::Scalar(0)), "CV_16UC1 752x480");
  expectMessage(cv::Mat(), "0x0");
  EXPECT_FALSE(f.valid);
}

TEST(ImagePreprocessor, ReusesBuffersAndAcceptsRoi) {
  ImagePreprocessor pre(myntEyeCamera(), PreprocessParams{});
  PreprocessedFrame f;
  const cv::Mat img = texture(752, 480, 9);
  pre.process(img, 0.0, &f);
  const void* ptrs[4] = {f.gray8.data, f.intensity.data, f.grad_x.data, f.grad_y.data};
  const cv::Mat first = f.intensity.clone();
  pre.process(texture(752, 480, 10), 0.1, &f);
  EXPECT_GT(cv::norm(first, f.intensity, cv::NORM_INF), 0.1);  // new content...
  EXPECT_EQ(ptrs[0], static_cast<const void*>(f.gray8.data));  // ...in the same buffers
  EXPECT_EQ(ptrs[1], static_cast<const void*>(f.intensity.data));
  EXPECT_EQ(ptrs[2], static_cast<const void*>(f.grad_x.data));
  EXPECT_EQ(ptrs[3], static_cast<const void*>(f.grad_y.data));
  // A non-continuous view of a larger image gives the same result as the continuous image.
  cv::Mat big(500, 800, CV_8UC1, cv::Scalar(0));
  img.copyTo(big(cv::Rect(20, 10, 752, 480)));
  pre.process(big(cv::Rect(20, 10, 752, 480)), 0.2, &f);
  EXPECT_EQ(cv::norm(first, f.intensity, cv::NORM_INF), 0.0);
}

TEST(ImagePreprocessor, TwoStagesGiveTheSameFrameAsProcess) {
  // Estimator::addImage resamples on arrival and finishes when the IMU covers the image: bit-identical to
  // process(), with several staged images in flight (the estimator's queue).
  PreprocessParams pp;
  pp.working_width_px = 180;
  ImagePreprocessor pre(myntEyeCamera(), pp);
  ImagePreprocessor staged(myntEyeCamera(), pp);
  ResampledImage a, b;
  staged.resample(texture(752, 480, 11), &a);
  staged.resample(texture(752, 480, 12), &b);
  for (int k = 0; k < 2; ++k) {
    PreprocessedFrame ref, got;
    pre.process(texture(752, 480, 11 + k), 0.1 * k, &ref);
    staged.finish(k == 0 ? &a : &b, 0.1 * k, &got);
    EXPECT_EQ(cv::norm(ref.intensity, got.intensity, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(ref.grad_x, got.grad_x, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(ref.grad_y, got.grad_y, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(ref.gray8, got.gray8, cv::NORM_INF), 0.0);
    EXPECT_EQ(ref.grey_per_unit, got.grey_per_unit);
    EXPECT_TRUE(got.valid);
    EXPECT_DOUBLE_EQ(got.t_s, 0.1 * k);
  }
  PreprocessedFrame again;
  EXPECT_THROW(staged.finish(&a, 0.2, &again), std::invalid_argument);  // a stage is finished once
  EXPECT_THROW(staged.resample(cv::Mat(480, 752, CV_8UC3), &a), std::invalid_argument);
}

}  // namespace
}  // namespace diekf
