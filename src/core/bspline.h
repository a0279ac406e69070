// Cubic B-spline interpolation of the reference image (docs/algorithm.md section 3.3).
//
// Why not bilinear: for a texture component of frequency w (rad/px), bilinear interpolation at a fraction phi of
// a pixel moves its phase by atan(phi sin w / (1 - phi + phi cos w)), not by phi w: slower than the true shift
// near whole pixels and faster near half pixels. The photometric update matches phases, so a sub-pixel motion
// reads w / sin w times too large near whole pixels (x1.35 at w = 1.36, a 4.6 px period) and the error changes
// sign over each pixel. Cubic B-spline interpolation (the image's coefficients, then a 4x4 cubic B-spline sum)
// reproduces the samples and moves the phase almost linearly (x1.02 at w = 1.36), at 16 taps instead of 4.
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

inline void cubicBSplineWeights(float t, float w[4], float dw[4]) {
  cubicBSplineWeights(t, w, dw, [](float v) { return v; });
}

}  // namespace internal
}  // namespace diekf
