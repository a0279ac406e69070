// The warp of one image pair (docs/algorithm.md section 3.2): the state-dependent, pixel-independent part of it,
// shared by the pixel-wise functions of interval_warp.cpp, the photometric update's single-precision sweep and the
// dots' gain learner's grid (Estimator).
// Internal to the core.
#pragma once

#include "diekf/camera_model.h"
#include "diekf/photometric_update.h"  // WarpJacobian
#include "diekf/state.h"
#include "diekf/types.h"

namespace diekf {
namespace internal {

constexpr double kMinDepthRatio = 0.1;  // Q_z: depth in the reference over depth in the current view, unitless
constexpr double kMinKappa = 0.1;       // 1 - lag (mu . vartheta), unitless

/// The state-dependent, pixel-independent part of the warp of one update interval (interval_warp.cpp's header
/// comment has the equations).
struct IntervalWarp {
  Mat3 E, Ea;      // rotations current -> reference and current -> state
  Mat3 J, Ja, Jb;  // left Jacobians of exp at dt w, lag w, (dt - lag) w
  Vec3 a, b, mu;   // E_b vartheta (1/s), E_a^T mu, mu
  Mat3 H;          // E + c a b^T: Q = H q
  Mat3 N;          // d Q / d vartheta = c s_b N
  Mat32 P;         // d Q / d mu = c a q^T P
  double c = 0.0;  // dt / kappa, s
  double kappa = 1.0;
  double dt = 0.0, lag = 0.0;  // s
  bool ok = false;

  /// The interval's warp for state x, the interval's mean gyro rate, its length dt_s and the state's time
  /// state_lag_s before the current image (clamped to [0, dt_s]).
  IntervalWarp(const State& x, const Vec3& gyro_mean_C, double dt_s, double state_lag_s);
};

/// The warp of pixel (px, py) with the interval's part `iw` built once for all pixels: the reference pixel, its
/// Jacobian over the observed columns (J, may be null) and its derivative over the focal-length scale (d_focal, may be
/// null; `translation_only`: less the rotation's part). NaN where the ray leaves the reference camera.
Vec2 warpWith(const IntervalWarp& iw, const PinholeK& K, double px, double py, WarpJacobian* J, Vec2* d_focal = nullptr,
              bool translation_only = false);

}  // namespace internal
}  // namespace diekf
