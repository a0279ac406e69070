// Cubic and quintic B-spline interpolation of the reference image (src/core/bspline.h, docs/algorithm.md
// section 3.3).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core/hal/intrin.hpp>

#include "../../src/core/bspline.h"

namespace diekf {
namespace {

using internal::bSplineCoefficients;
using internal::cubicBSplineCoefficients;
using internal::cubicBSplineWeights;
using internal::quinticBSplineWeights;

/// The spline's value and x-derivative at (x, y) from the coefficients, with the weights of bspline.h (cubic:
/// 4 taps from floor - 1; quintic: 6 from floor - 2).
void evaluate(const cv::Mat& c, double x, double y, double* value, double* dvalue_dx, int degree = 3) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const int taps = degree + 1, lead = degree / 2;
  float wx[6], dwx[6], wy[6], dwy[6];
  if (degree == 5) {
    quinticBSplineWeights(static_cast<float>(x - x0), wx, dwx);
    quinticBSplineWeights(static_cast<float>(y - y0), wy, dwy);
  } else {
    cubicBSplineWeights(static_cast<float>(x - x0), wx, dwx);
    cubicBSplineWeights(static_cast<float>(y - y0), wy, dwy);
  }
  *value = 0.0;
  *dvalue_dx = 0.0;
  for (int j = 0; j < taps; ++j) {
    for (int i = 0; i < taps; ++i) {
      const double ck = c.at<float>(y0 - lead + j, x0 - lead + i);
      *value += wy[j] * wx[i] * ck;
      *dvalue_dx += wy[j] * dwx[i] * ck;
    }
  }
}

/// The centred quintic B-spline in double precision, from its definition as a sum of truncated powers.
double beta5(double x) {
  double s = 0.0;
  const double binom[7] = {1, 6, 15, 20, 15, 6, 1};
  for (int k = 0; k <= 6; ++k) s += (k % 2 ? -1.0 : 1.0) * binom[k] * std::pow(std::max(0.0, x + 3.0 - k), 5);
  return s / 120.0;
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

/// The sweep's instantiation of spline weights of `taps` taps (four t per v_float32x4) against the scalar one.
template <int kTaps, class VectorWeights, class ScalarWeights>
void expectVectorWeightsEqualTheScalarOnes(VectorWeights vector_weights, ScalarWeights scalar_weights) {
  alignas(16) const float t[4] = {0.0f, 0.13f, 0.5f, 0.999f};
  cv::v_float32x4 w[kTaps], dw[kTaps];
  vector_weights(cv::v_load(t), w, dw);
  for (int l = 0; l < 4; ++l) {
    float ws[kTaps], dws[kTaps];
    scalar_weights(t[l], ws, dws);
    for (int i = 0; i < kTaps; ++i) {
      alignas(16) float lane_w[4], lane_dw[4];
      cv::v_store_aligned(lane_w, w[i]);
      cv::v_store_aligned(lane_dw, dw[i]);
      // Equal up to rounding (a compiler may fuse the scalar multiply-adds and not the vector ones).
      EXPECT_NEAR(lane_w[l], ws[i], 1e-6f) << "t " << t[l] << " tap " << i;
      EXPECT_NEAR(lane_dw[l], dws[i], 1e-6f) << "t " << t[l] << " tap " << i;
    }
  }
}

/// The x-derivative of the spline of `degree` at random points against finite differences of its value.
void expectDerivativeOfTheInterpolantMatchesFiniteDifferences(int degree) {
  const cv::Mat f = randomImage(24, 16, 5);
  cv::Mat c;
  bSplineCoefficients(f, degree, &c);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> ux(3.0, 20.0), uy(3.0, 12.0);  // the taps inside the image
  const double h = 1e-3;
  for (int n = 0; n < 50; ++n) {
    const double x = ux(rng), y = uy(rng);
    if (std::abs(x - std::round(x)) < 2 * h) continue;  // the finite difference must not straddle a knot
    double v, d, vp, vm, unused;
    evaluate(c, x, y, &v, &d, degree);
    evaluate(c, x + h, y, &vp, &unused, degree);
    evaluate(c, x - h, y, &vm, &unused, degree);
    EXPECT_NEAR(d, (vp - vm) / (2.0 * h), 2e-3 * (1.0 + std::abs(d))) << "degree " << degree;
  }
}

const auto kSplat = [](float v) { return cv::v_setall_f32(v); };

TEST(CubicBSpline, VectorWeightsEqualTheScalarOnes) {
  expectVectorWeightsEqualTheScalarOnes<4>(
      [](const cv::v_float32x4& t, cv::v_float32x4* w, cv::v_float32x4* dw) {
        internal::cubicBSplineWeights(t, w, dw, kSplat);
      },
      [](float t, float* w, float* dw) { cubicBSplineWeights(t, w, dw); });
}

TEST(CubicBSpline, DerivativeOfTheInterpolantMatchesFiniteDifferences) {
  expectDerivativeOfTheInterpolantMatchesFiniteDifferences(3);
}

TEST(QuinticBSpline, CoefficientsReproduceTheSamples) {
  // At a whole pixel the spline is (c(k-2) + 26 c(k-1) + 66 c(k) + 26 c(k+1) + c(k+2)) / 120 per axis; mirror
  // boundaries. Sizes with rows left over from the row blocks of four, and the 90 px working image's.
  for (const cv::Size size : {cv::Size(37, 23), cv::Size(90, 57), cv::Size(180, 116)}) {
    const cv::Mat f = randomImage(size.width, size.height, 7);
    cv::Mat c;
    std::vector<float> scratch;
    bSplineCoefficients(f, 5, &c, &scratch);
    ASSERT_EQ(c.size(), f.size());
    const int W = f.cols, H = f.rows;
    auto at = [&](int y, int x) {
      x = x < 0 ? -x : (x >= W ? 2 * W - 2 - x : x);
      y = y < 0 ? -y : (y >= H ? 2 * H - 2 - y : y);
      return static_cast<double>(c.at<float>(y, x));
    };
    const double k[5] = {1.0 / 120.0, 26.0 / 120.0, 66.0 / 120.0, 26.0 / 120.0, 1.0 / 120.0};
    double worst = 0.0;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        double v = 0.0;
        for (int j = -2; j <= 2; ++j)
          for (int i = -2; i <= 2; ++i) v += k[j + 2] * k[i + 2] * at(y + j, x + i);
        worst = std::max(worst, std::abs(v - f.at<float>(y, x)));
      }
    }
    EXPECT_LT(worst, 1e-4) << size;  // unit-variance samples, float recursions
  }
  // Degree 3 through the general function is the cubic one, bit for bit.
  const cv::Mat f = randomImage(37, 23, 3);
  cv::Mat c3, c;
  cubicBSplineCoefficients(f, &c3);
  bSplineCoefficients(f, 3, &c);
  EXPECT_EQ(cv::norm(c, c3, cv::NORM_INF), 0.0);
}

TEST(QuinticBSpline, WeightsAreTheBasisFunctionAndTheirDerivativesMatchFiniteDifferences) {
  const double h = 1e-4;
  for (float t : {0.0f, 0.13f, 0.5f, 0.77f, 0.999f}) {
    float w[6], dw[6];
    quinticBSplineWeights(t, w, dw);
    float sum = 0.0f, dsum = 0.0f, first = 0.0f;
    for (int i = 0; i < 6; ++i) {
      // Tap i sits at floor(x) + i - 2: its weight is beta5(t - (i - 2)).
      EXPECT_NEAR(w[i], beta5(t - (i - 2)), 2e-7) << "t " << t << " tap " << i;
      const double fd = (beta5(t + h - (i - 2)) - beta5(t - h - (i - 2))) / (2.0 * h);
      EXPECT_NEAR(dw[i], fd, 1e-5) << "t " << t << " tap " << i;
      sum += w[i];
      dsum += dw[i];
      first += w[i] * static_cast<float>(i - 2);
    }
    EXPECT_NEAR(sum, 1.0f, 1e-6f);
    EXPECT_NEAR(dsum, 0.0f, 1e-6f);
    EXPECT_NEAR(first, t, 1e-6f);  // linear functions are reproduced
  }
  expectVectorWeightsEqualTheScalarOnes<6>(
      [](const cv::v_float32x4& t, cv::v_float32x4* w, cv::v_float32x4* dw) {
        internal::quinticBSplineWeights(t, w, dw, kSplat);
      },
      [](float t, float* w, float* dw) { quinticBSplineWeights(t, w, dw); });
}

TEST(QuinticBSpline, DerivativeOfTheInterpolantMatchesFiniteDifferences) {
  expectDerivativeOfTheInterpolantMatchesFiniteDifferences(5);
}

/// The shift u of one row as the photometric update estimates it: Gauss-Newton on
/// sum_x (I_c(x) - I_r~(x + u))^2 with the efficient second-order gradient (the mean of the current image's central
/// difference and the interpolated reference's gradient), until sum_x g(x) r(x) = 0. I_r~ is the bilinear
/// interpolation of the reference (gradient: bilinear of its central differences, as before the spline) or the
/// cubic B-spline (gradient: the spline's derivative). A sinusoid of frequency w (rad/px) moved by `shift` px.
double estimatedShift(double w, double shift, bool spline, int degree = 3) {
  // Seven equal rows, the middle one evaluated: the quintic's six taps reach rows 1-6 (the cubic's 2-5).
  const int n = 160;
  cv::Mat ref(7, n, CV_32FC1), cur(7, n, CV_32FC1);
  for (int y = 0; y < 7; ++y) {
    for (int x = 0; x < n; ++x) {
      ref.at<float>(y, x) = static_cast<float>(std::sin(w * x + 0.3));
      cur.at<float>(y, x) = static_cast<float>(std::sin(w * (x + shift) + 0.3));  // cur(x) = ref(x + shift)
    }
  }
  cv::Mat c;
  bSplineCoefficients(ref, degree, &c);
  auto central = [](const cv::Mat& m, int x) { return 0.5 * (m.at<float>(3, x + 1) - m.at<float>(3, x - 1)); };
  double u = 0.0;
  for (int it = 0; it < 30; ++it) {
    double num = 0.0, den = 0.0;
    for (int x = 8; x < n - 8; ++x) {
      double v, d;
      const double xr = x + u;
      if (spline) {
        evaluate(c, xr, 3.0, &v, &d, degree);
      } else {
        const int x0 = static_cast<int>(std::floor(xr));
        const double a = xr - x0;
        v = (1 - a) * ref.at<float>(3, x0) + a * ref.at<float>(3, x0 + 1);
        d = (1 - a) * central(ref, x0) + a * central(ref, x0 + 1);
      }
      const double g = 0.5 * (central(cur, x) + d);
      const double r = cur.at<float>(3, x) - v;
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

TEST(QuinticBSpline, SubPixelShiftNearTheNyquistLimitIsRead) {
  // The cubic spline's phase is not linear in a fraction of a pixel for texture near the working Nyquist limit:
  // a small shift of a 3 px period (w = 2.09 rad/px: a 5 cm checkerboard seen from 1.1 m at 90 px, its squares
  // foreshortened by the tilt) reads 1.2 times too large, a 2.5 px period 1.7 times; the quintic reads 1.05 and
  // 1.25 (docs/algorithm.md section 3.3). Over a whole pixel of shifts the quintic's error stays within the
  // cubic's at the periods where the cubic is good.
  for (double period : {3.0, 2.5}) {
    const double w = 2.0 * M_PI / period, shift = 0.02;
    const double cubic = estimatedShift(w, shift, true, 3) / shift;
    const double quintic = estimatedShift(w, shift, true, 5) / shift;
    EXPECT_GT(cubic, period == 3.0 ? 1.15 : 1.6) << "period " << period;
    EXPECT_LT(quintic - 1.0, 0.4 * (cubic - 1.0)) << "period " << period;
    EXPECT_GT(quintic, 1.0) << "period " << period;
  }
  EXPECT_NEAR(estimatedShift(2.0 * M_PI / 3.0, 0.02, true, 5) / 0.02, 1.05, 0.02);
  for (double s : {0.05, 0.25, 0.5, 0.75}) {
    EXPECT_NEAR(estimatedShift(1.36, s, true, 5), s, 0.005 * std::max(s, 0.25)) << "shift " << s;
    EXPECT_NEAR(estimatedShift(1.93, s, true, 5), s, 0.03 * std::max(s, 0.25)) << "shift " << s;
  }
}

}  // namespace
}  // namespace diekf
