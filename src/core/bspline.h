// Cubic B-spline interpolation of the reference image (docs/algorithm.md section 3.3).
//
// Why not bilinear: for a texture component of frequency w (rad/px), bilinear interpolation at a fraction phi of
// a pixel moves its phase by atan(phi sin w / (1 - phi + phi cos w)), not by phi w: slower than the true shift
// near whole pixels and faster near half pixels. The photometric update matches phases, so a sub-pixel motion
// reads w / sin w times too large near whole pixels (x1.35 at w = 1.36, a 4.6 px period) and the error changes
// sign over each pixel. Cubic B-spline interpolation (the image's coefficients, then a 4x4 cubic B-spline sum)
// reproduces the samples and moves the phase almost linearly (x1.02 at w = 1.36), at 16 taps instead of 4.
// Nearer the Nyquist limit it does not: a small shift of a 3 px period reads x1.2, of 2.5 px x1.7. The quintic
// B-spline (36 taps) reads x1.05 and x1.25 there (docs/algorithm.md section 3.3, PhotometricParams::spline_degree).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace diekf {
namespace internal {

/// Cubic B-spline coefficients c of a CV_32FC1 image f, mirror boundaries: the spline sum_k c_k beta3(x - k)
/// equals f at every pixel. Separable: a causal and an anti-causal first-order recursion with the pole
/// z = sqrt(3) - 2 along the rows, then along the columns (Unser, Aldroubi, Eden 1991). `coeff` is (re)created
/// as CV_32FC1 of f's size only when its size or type differs (it must not share f's data). An image narrower or
/// lower than 2 px is copied unchanged along that axis. `scratch` (optional): a buffer of 4 x width floats for the
/// row pass, kept by the caller so that no call allocates (null: a local one).
void cubicBSplineCoefficients(const cv::Mat& image, cv::Mat* coeff, std::vector<float>* scratch = nullptr);

/// The same for the B-spline of `degree` 3 (cubicBSplineCoefficients) or 5 (quintic: the two poles of its inverse
/// filter one after the other, Unser 1999).
void bSplineCoefficients(const cv::Mat& image, int degree, cv::Mat* coeff, std::vector<float>* scratch = nullptr);

/// The four cubic B-spline weights of the taps at floor(x) - 1 ... floor(x) + 2 for t = x - floor(x) in [0, 1),
/// and their derivatives d w / d x (they sum to 1 and to 0). T is float or a SIMD vector of them (the sweep's
/// v_float32x4, one t per lane); `c` makes a T of a constant (the identity for float, v_setall_f32 for vectors).
template <class T, class Constant>
inline void cubicBSplineWeights(const T& t, T* w, T* dw, Constant c) {
  const T s = c(1.0f) - t, t2 = t * t, s2 = s * s;
  w[0] = s2 * s * c(1.0f / 6.0f);
  w[3] = t2 * t * c(1.0f / 6.0f);
  w[1] = c(0.5f) * t2 * t + (c(2.0f / 3.0f) - t2);
  w[2] = c(1.0f) - w[0] - w[1] - w[3];
  dw[0] = c(0.0f) - c(0.5f) * s2;
  dw[3] = c(0.5f) * t2;
  dw[1] = c(1.5f) * t2 + (c(0.0f) - c(2.0f) * t);
  dw[2] = c(0.0f) - (dw[0] + dw[1] + dw[3]);
}

/// The six quintic B-spline weights of the taps at floor(x) - 2 ... floor(x) + 3 for t = x - floor(x) in [0, 1),
/// and their derivatives d w / d x. The centred quintic B-spline is (66 - 60 x^2 + 30 x^4 - 10 |x|^5) / 120 for
/// |x| < 1, (51 + 75 |x| - 210 x^2 + 150 |x|^3 - 45 x^4 + 5 |x|^5) / 120 for 1 <= |x| < 2 and (3 - |x|)^5 / 120
/// for 2 <= |x| < 3; the tap at floor(x) + j (j = -2 ... 3, in w[j + 2]) weighs B5(t - j).
template <class T, class Constant>
inline void quinticBSplineWeights(const T& t, T* w, T* dw, Constant c) {
  const T s = c(1.0f) - t;
  const T t2 = t * t, s2 = s * s;
  const T t4 = t2 * t2, s4 = s2 * s2;
  // |x| < 1 at x = t (j = 0) and x = s (j = 1); 1 <= |x| < 2 at x = 1 + t (j = -1) and x = 1 + s (j = 2).
  const auto inner = [&](const T& x, const T& x2) {
    return c(66.0f / 120.0f) + x2 * (c(-60.0f / 120.0f) + x2 * (c(30.0f / 120.0f) - c(10.0f / 120.0f) * x));
  };
  const auto inner_d = [&](const T& x, const T& x2) { return x * (x2 - c(1.0f) - c(5.0f / 12.0f) * x2 * x); };
  const auto outer = [&](const T& u) {  // u = x - 1 in [0, 1): the middle piece expanded about 1
    return c(26.0f / 120.0f) +
           u * (c(-50.0f / 120.0f) + u * (c(20.0f / 120.0f) + u * (c(20.0f / 120.0f) + u * (c(-20.0f / 120.0f) +
                                                                                           c(5.0f / 120.0f) * u))));
  };
  const auto outer_d = [&](const T& u) {
    return c(-50.0f / 120.0f) +
           u * (c(40.0f / 120.0f) + u * (c(60.0f / 120.0f) + u * (c(-80.0f / 120.0f) + c(25.0f / 120.0f) * u)));
  };
  w[0] = s4 * s * c(1.0f / 120.0f);
  w[5] = t4 * t * c(1.0f / 120.0f);
  w[1] = outer(t);
  w[4] = outer(s);
  w[3] = inner(s, s2);
  w[2] = c(1.0f) - (w[0] + w[1] + w[3] + w[4] + w[5]);
  dw[0] = c(0.0f) - s4 * c(5.0f / 120.0f);
  dw[5] = t4 * c(5.0f / 120.0f);
  dw[1] = outer_d(t);
  dw[4] = c(0.0f) - outer_d(s);
  dw[3] = c(0.0f) - inner_d(s, s2);
  dw[2] = c(0.0f) - (dw[0] + dw[1] + dw[3] + dw[4] + dw[5]);
}

inline void quinticBSplineWeights(float t, float w[6], float dw[6]) {
  quinticBSplineWeights(t, w, dw, [](float v) { return v; });
}

inline void cubicBSplineWeights(float t, float w[4], float dw[4]) {
  cubicBSplineWeights(t, w, dw, [](float v) { return v; });
}

}  // namespace internal
}  // namespace diekf
