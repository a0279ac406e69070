// The lens's radial vignetting learned from the ground's motion (docs/noise_model.md section 11, "Vignetting
// from the motion").
//
// A lens darkens the image towards its rim: working pixel x reads u(x) = V(r(x)) rho(X) c, with V fixed in the
// image, rho the brightness of the ground point X it sees and c the image's exposure over its mean. After a
// pair's update the filter knows where the ground point that the current image sees at x lies in the reference:
// x_r (the warp at the update's time). So
//
//   ln u_c(x) - ln u_r(x_r) = ln V(x) - ln V(x_r) + ln (c_c / c_r)
//
// and the ground's texture cancels: what is left is the sensor noise, the reference's interpolation at x_r and
// the warp's error, none of them fixed in the image. With ln V = a1 s + a2 s^2 (s = r^2, 1 at the farthest
// corner) every sample is a linear equation in (a1, a2) plus one constant per pair (the exposure ratio), which a
// weighted regression with an intercept per pair removes. The temporal mean of each pixel (FixedPattern's
// statistics) also holds V, but with the ground's large-scale structure that the path flown has not averaged out:
// on simulated flights rendered without vignetting it read 10 % of darkening at the corner, and that false field
// biased the distance and the focal-length state (docs/results.md).
//
// Weights: a sample's error is the reference's noise and interpolation plus the warp's error times the texture's
// gradient, so w = 1 / (kNoiseVar + |grad ln u_r|^2 kWarpVarPx2); then once more with Huber weights at kHuberSigma
// robust sigmas of the pair's residuals (a shadow's edge, a projector's dot, a glossy patch). The pairs' normal
// equations are summed with exponential forgetting (kPairMemory pairs); the coefficients' covariance is the
// sandwich N^-1 G N^-1 over pairs (G: the sum of each pair's score at the estimate before it, outer product), so
// the correlation of neighbouring samples (blur, texture) does not make it overconfident.
//
// All buffers are allocated by configure(); observe() does not allocate.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "diekf/types.h"

namespace diekf {

class VignettingLearner {
 public:
  /// The current-to-reference map is given at grid points this far apart (working px), bilinear in between.
  static constexpr int kGridPx = 8;
  /// Samples every kStridePx working px in x and y.
  static constexpr int kStridePx = 3;
  /// Forgetting time constant, pairs (about 10 s at 30 Hz: a lens's vignetting changes with the aperture only).
  static constexpr double kPairMemory = 300.0;
  /// Variance of a sample's ln ratio from noise (a working pixel of a standardised 8-bit image: about 1 %).
  static constexpr double kNoiseVar = 1e-4;
  /// Variance of the warp's error and the interpolation, working px^2.
  static constexpr double kWarpVarPx2 = 0.09;
  /// Huber threshold in robust sigmas of the pair's residuals.
  static constexpr double kHuberSigma = 2.0;
  /// Pairs before an estimate is given.
  static constexpr int kMinPairs = 20;
  /// Least information (the smaller eigenvalue of the normal equations, 1 / ln^2) for an estimate: each
  /// coefficient known to 1 in ln units from the noise alone. A still camera's pairs hold only rounding (the map's
  /// interpolation one ulp off the pixels, as with fused multiply-adds on ARM): about 1e-10 there, about 1e3 after
  /// kMinPairs pairs of ordinary motion.
  static constexpr double kMinInformation = 1.0;
  /// Once the corner's ln V is known to this 1-sigma, only every kSettledEvery-th pair is observed (due()).
  static constexpr double kSettledSigmaLn = 0.01;
  static constexpr int kSettledEvery = 4;

  /// For working images of width x height, radius about (cx, cy) in px; s = r^2 / r_max^2 with r_max the
  /// farthest corner. Allocates.
  void configure(int width, int height, double cx_px, double cy_px);
  /// Forgets every pair (the configuration is kept).
  void reset();

  int gridCols() const { return grid_cols_; }
  int gridRows() const { return grid_rows_; }
  /// Where the caller writes, for grid point (i, j) at working px (i kGridPx, j kGridPx), its position in the
  /// reference (working px); non-finite: not seen there. Filled before each observe().
  Vec2* gridTargets() { return grid_.data(); }
  /// Whether the caller should give the next accepted pair: every pair until the corner's ln V is known to
  /// kSettledSigmaLn, then every kSettledEvery-th (a lens's vignetting changes with its aperture only). Counts the
  /// call.
  bool due();
  /// One pair: the current and the reference working images (CV_32FC1 data, width x height, contiguous, before
  /// any vignetting or pattern correction; any scale), with gridTargets() filled for this pair. Returns false
  /// when the pair had too few samples to count.
  bool observe(const float* cur, const float* ref);

  int pairs() const { return pairs_; }
  /// ln V = a1 s + a2 s^2 and the 1-sigma of the corner's ln V = a1 + a2. False before kMinPairs pairs or when the
  /// motion so far does not determine both coefficients.
  bool estimate(double* a1, double* a2, double* sigma_corner_ln) const;
  /// s at working pixel (x, y).
  double radius2(double x, double y) const {
    return ((x - cx_) * (x - cx_) + (y - cy_) * (y - cy_)) * inv_r2max_;
  }

 private:
  int width_ = 0, height_ = 0;
  double cx_ = 0.0, cy_ = 0.0, inv_r2max_ = 1.0;
  int grid_cols_ = 0, grid_rows_ = 0;
  std::vector<Vec2> grid_;
  // One pair's samples: ln ratio, the two regressors, the weight.
  std::vector<float> d_, z1_, z2_, w_;
  std::vector<float> scratch_, median_;  // normalised residuals and their copy for the median
  std::array<uint32_t, 2048> select_counts_{};  // scratch of the median (internal::kthSmallest)
  // Normal equations (centred per pair) summed with forgetting, and the scores' outer products.
  Mat2 N_ = Mat2::Zero();
  Vec2 b_ = Vec2::Zero();
  Mat2 G_ = Mat2::Zero();
  int pairs_ = 0;
  long calls_ = 0;        // due() calls
  bool settled_ = false;  // the corner's 1-sigma below kSettledSigmaLn after the last pair
};

}  // namespace diekf
