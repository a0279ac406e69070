// Cubic B-spline interpolation of the reference image (src/core/bspline.h, docs/algorithm.md section 3.3).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core/hal/intrin.hpp>

#include "../../src/core/bspline.h"

namespace diekf {
namespace {

using internal::cubicBSplineCoefficients;
using internal::cubicBSplineWeights;

/// The spline's value and x-derivative at (x, y) from the coefficients, with the weights of bspline.h.
void evaluate(const cv::Mat& c, double x, double y, double* value, double* dvalue_dx) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  float wx[4], dwx[4], wy[4], dwy[4];
  cubicBSplineWeights(static_cast<float>(x - x0), wx, dwx);
  cubicBSplineWeights(static_cast<float>(y - y0), wy, dwy);
  *value = 0.0;
  *dvalue_dx = 0.0;
  for (int j = 0; j < 4; ++j) {
    for (int i = 0; i < 4; ++i) {
      const double ck = c.at<float>(y0 - 1 + j, x0 - 1 + i);
      *value += wy[j] * wx[i] * ck;
      *dvalue_dx += wy[j] * dwx[i] * ck;
    }
  }
}

cv::Mat randomImage(int w, int h, unsigned seed) {
  cv::Mat m(h, w, CV_32FC1);
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) m.at<float>(y, x) = n(rng);
  return m;
}

TEST(CubicBSpline, CoefficientsReproduceTheSamples) {
  // At a whole pixel the spline is (c(k-1) + 4 c(k) + c(k+1)) / 6 per axis; with mirror boundaries at the edges.
  const cv::Mat f = randomImage(37, 23, 3);
  cv::Mat c;
  cubicBSplineCoefficients(f, &c);
  ASSERT_EQ(c.size(), f.size());
  ASSERT_EQ(c.type(), CV_32FC1);
  const int W = f.cols, H = f.rows;
  auto at = [&](int y, int x) {
    x = x < 0 ? -x : (x >= W ? 2 * W - 2 - x : x);
    y = y < 0 ? -y : (y >= H ? 2 * H - 2 - y : y);
    return static_cast<double>(c.at<float>(y, x));
  };
  const double k[3] = {1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0};
  double worst = 0.0;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double v = 0.0;
      for (int j = -1; j <= 1; ++j)
        for (int i = -1; i <= 1; ++i) v += k[j + 1] * k[i + 1] * at(y + j, x + i);
      worst = std::max(worst, std::abs(v - f.at<float>(y, x)));
    }
  }
  EXPECT_LT(worst, 5e-5);  // unit-variance samples, float recursions
  // The coefficients are not the samples (the prefilter sharpens): a check that it ran at all.
  EXPECT_GT(cv::norm(c, f, cv::NORM_INF), 0.5);
  // Reused buffer: same size and type, no reallocation.
  const float* data = c.ptr<float>(0);
  cubicBSplineCoefficients(f, &c);
  EXPECT_EQ(c.ptr<float>(0), data);
}

TEST(CubicBSpline, RowBlocksGiveExactlyTheRowByRowFilter) {
  // The row pass filters four rows at a time with the rows as SIMD lanes; it must give bit for bit what one row
  // at a time gives (a 1-row image takes that path, a 1-column image the column pass alone). Sizes with rows and
  // columns left over from the blocks of four, and the scratch buffer reused between sizes.
  std::vector<float> scratch;
  for (const cv::Size size : {cv::Size(37, 23), cv::Size(40, 16), cv::Size(5, 9), cv::Size(180, 116)}) {
    const cv::Mat f = randomImage(size.width, size.height, 11);
    cv::Mat c;
    cubicBSplineCoefficients(f, &c, &scratch);
    cv::Mat rows(f.size(), CV_32FC1);
    for (int y = 0; y < f.rows; ++y) {
      cv::Mat r;
      cubicBSplineCoefficients(f.row(y).clone(), &r);
      r.copyTo(rows.row(y));
    }
    cv::Mat expected(f.size(), CV_32FC1);
    for (int x = 0; x < f.cols; ++x) {
      cv::Mat col;
      cubicBSplineCoefficients(rows.col(x).clone(), &col);
      col.copyTo(expected.col(x));
    }
    EXPECT_EQ(cv::norm(c, expected, cv::NORM_INF), 0.0) << size;
  }
}

TEST(CubicBSpline, WeightsPartitionUnityAndTheirDerivativesMatchFiniteDifferences) {
  const float h = 1e-3f;
  for (float t : {0.0f, 0.13f, 0.5f, 0.77f, 0.999f}) {
    float w[4], dw[4], wp[4], dwp[4], wm[4], dwm[4];
    cubicBSplineWeights(t, w, dw);
    EXPECT_NEAR(w[0] + w[1] + w[2] + w[3], 1.0f, 1e-6f);
    EXPECT_NEAR(dw[0] + dw[1] + dw[2] + dw[3], 0.0f, 1e-6f);
    // Linear functions are reproduced: sum_i w_i (i - 1) = t.
    EXPECT_NEAR(-w[0] + w[2] + 2.0f * w[3], t, 1e-6f);
    if (t > h && t < 1.0f - h) {
      cubicBSplineWeights(t + h, wp, dwp);
      cubicBSplineWeights(t - h, wm, dwm);
      for (int i = 0; i < 4; ++i) EXPECT_NEAR(dw[i], (wp[i] - wm[i]) / (2.0f * h), 2e-3f) << "t " << t << " tap " << i;
    }
  }
}

TEST(CubicBSpline, VectorWeightsEqualTheScalarOnes) {
  // The sweep's instantiation (four t per v_float32x4) against the scalar one tested above.
  alignas(16) const float t[4] = {0.0f, 0.13f, 0.5f, 0.999f};
  cv::v_float32x4 w[4], dw[4];
  internal::cubicBSplineWeights(cv::v_load(t), w, dw, [](float v) { return cv::v_setall_f32(v); });
  for (int l = 0; l < 4; ++l) {
    float ws[4], dws[4];
    cubicBSplineWeights(t[l], ws, dws);
    for (int i = 0; i < 4; ++i) {
      alignas(16) float lane_w[4], lane_dw[4];
      cv::v_store_aligned(lane_w, w[i]);
      cv::v_store_aligned(lane_dw, dw[i]);
      // Equal up to rounding (a compiler may fuse the scalar multiply-adds and not the vector ones).
      EXPECT_NEAR(lane_w[l], ws[i], 1e-6f) << "t " << t[l] << " tap " << i;
      EXPECT_NEAR(lane_dw[l], dws[i], 1e-6f) << "t " << t[l] << " tap " << i;
    }
  }
}

TEST(CubicBSpline, DerivativeOfTheInterpolantMatchesFiniteDifferences) {
  const cv::Mat f = randomImage(24, 16, 5);
  cv::Mat c;
  cubicBSplineCoefficients(f, &c);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> ux(2.0, 20.0), uy(2.0, 12.0);
  const double h = 1e-3;
  for (int n = 0; n < 50; ++n) {
    const double x = ux(rng), y = uy(rng);
    if (std::abs(x - std::round(x)) < 2 * h) continue;  // the finite difference must not straddle a knot
    double v, d, vp, vm, unused;
    evaluate(c, x, y, &v, &d);
    evaluate(c, x + h, y, &vp, &unused);
    evaluate(c, x - h, y, &vm, &unused);
    EXPECT_NEAR(d, (vp - vm) / (2.0 * h), 2e-3 * (1.0 + std::abs(d)));
  }
}

/// The shift u of one row as the photometric update estimates it: Gauss-Newton on
/// sum_x (I_c(x) - I_r~(x + u))^2 with the efficient second-order gradient (the mean of the current image's central
/// difference and the interpolated reference's gradient), until sum_x g(x) r(x) = 0. I_r~ is the bilinear
/// interpolation of the reference (gradient: bilinear of its central differences, as before the spline) or the
/// cubic B-spline (gradient: the spline's derivative). A sinusoid of frequency w (rad/px) moved by `shift` px.
double estimatedShift(double w, double shift, bool spline) {
  const int n = 160;
  cv::Mat ref(5, n, CV_32FC1), cur(5, n, CV_32FC1);
  for (int y = 0; y < 5; ++y) {
    for (int x = 0; x < n; ++x) {
      ref.at<float>(y, x) = static_cast<float>(std::sin(w * x + 0.3));
      cur.at<float>(y, x) = static_cast<float>(std::sin(w * (x + shift) + 0.3));  // cur(x) = ref(x + shift)
    }
  }
  cv::Mat c;
  cubicBSplineCoefficients(ref, &c);
  auto central = [](const cv::Mat& m, int x) { return 0.5 * (m.at<float>(2, x + 1) - m.at<float>(2, x - 1)); };
  double u = 0.0;
  for (int it = 0; it < 30; ++it) {
    double num = 0.0, den = 0.0;
    for (int x = 8; x < n - 8; ++x) {
      double v, d;
      const double xr = x + u;
      if (spline) {
        evaluate(c, xr, 2.0, &v, &d);
      } else {
        const int x0 = static_cast<int>(std::floor(xr));
        const double a = xr - x0;
        v = (1 - a) * ref.at<float>(2, x0) + a * ref.at<float>(2, x0 + 1);
        d = (1 - a) * central(ref, x0) + a * central(ref, x0 + 1);
      }
      const double g = 0.5 * (central(cur, x) + d);
      const double r = cur.at<float>(2, x) - v;
      num += g * r;
      den += g * g;
    }
    u += num / den;
  }
  return u;
}

TEST(CubicBSpline, SubPixelShiftIsReadWithoutTheBilinearBias) {
  // A 4.6 px period (w = 1.36 rad/px: a 5 cm checkerboard at 0.95 m seen at 90 px) moved by a twentieth of a
  // pixel, as between two frames of a slow flight. With bilinear interpolation the update reads 1.32 times the
  // shift (the phase of the interpolant moves slowly near whole pixels: w / sin(w) = 1.39 in the limit), 1.12 at
  // a quarter pixel, exactly at half a pixel, 0.96 at three quarters; the spline reads 1.02, 1.01, 1.00, 0.995.
  const double w = 1.36, shift = 0.05;
  const double bilinear = estimatedShift(w, shift, false);
  const double spline = estimatedShift(w, shift, true);
  EXPECT_GT(bilinear / shift, 1.25);
  EXPECT_NEAR(spline / shift, 1.0, 0.03);
  // Over a whole pixel of shifts, and a finer texture (w = 1.93, 3.3 px period, where the bilinear update does
  // not even get the sign right at a quarter pixel): the spline's error stays small.
  for (double s : {0.05, 0.25, 0.5, 0.75}) {
    EXPECT_NEAR(estimatedShift(w, s, true), s, 0.02 * std::max(s, 0.25)) << "shift " << s;
    EXPECT_NEAR(estimatedShift(1.93, s, true), s, 0.1 * std::max(s, 0.25)) << "shift " << s;
  }
}

}  // namespace
}  // namespace diekf
