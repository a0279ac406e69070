#include "diekf/photometric_update.h"

#include <algorithm>
#include <cmath>

#include "gauss_newton.h"

namespace diekf {

// -------------------------------------------------------------------------------------------------------------
// Warp (ALGORITHM.md §3). With q = K^-1 p, G = [w]x + vartheta mu^T, m = G q and
// D = (I - p e_z^T)_{2x3} K = [[fx, 0, cx - x], [0, fy, cy - y]]:   p_r = p + dt D m.
// Derivatives (each checked against finite differences of this function in test_photometric_update.cpp):
//   d p_r / d vartheta = dt (mu . q) D
//   d p_r / d mu       = dt (D vartheta) q^T M(mu)
//   d p_r / d b_w      = dt D [q]x           (w = gyro - b_w, w x q = -[q]x w)
// -------------------------------------------------------------------------------------------------------------
Vec2 warpToReference(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double px,
                     double py, WarpJacobian* J) {
  const Vec3 w = gyro_mean_C - x.b_w;  // rad/s
  const Vec3 mu = x.mu.vector();
  const Vec3 q((px - K.cx) / K.fx, (py - K.cy) / K.fy, 1.0);
  const double s_q = mu.dot(q);
  const Vec3 m = w.cross(q) + x.vartheta * s_q;  // 1/s
  Mat23 D;
  D << K.fx, 0.0, K.cx - px, 0.0, K.fy, K.cy - py;
  const Vec2 p_r = Vec2(px, py) + dt_s * (D * m);
  if (J != nullptr) {
    J->block<2, 3>(0, 0) = (dt_s * s_q) * D;
    J->block<2, 2>(0, 3) = (dt_s * (D * x.vartheta)) * (q.transpose() * x.mu.M());
    J->block<2, 3>(0, 5) = dt_s * (D * skew(q));
  }
  return p_r;
}

namespace {

/// The warp of one state in single precision, laid out for the pixel loop.
struct PixelWarp {
  float fx, fy, cx, cy, ifx, ify;
  float G[3][3];  // [w]x + vartheta mu^T, 1/s
  float mu[3];
  float th[3];    // vartheta, 1/s
  float M[3][2];  // M(mu)

  PixelWarp(const State& x, const PinholeK& K, const Vec3& gyro_mean_C) {
    fx = static_cast<float>(K.fx);
    fy = static_cast<float>(K.fy);
    cx = static_cast<float>(K.cx);
    cy = static_cast<float>(K.cy);
    ifx = static_cast<float>(1.0 / K.fx);
    ify = static_cast<float>(1.0 / K.fy);
    const Vec3 w = gyro_mean_C - x.b_w;
    const Vec3 n = x.mu.vector();
    const Mat3 Gd = skew(w) + x.vartheta * n.transpose();
    const Mat32 Md = x.mu.M();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) G[r][c] = static_cast<float>(Gd(r, c));
      mu[r] = static_cast<float>(n(r));
      th[r] = static_cast<float>(x.vartheta(r));
      M[r][0] = static_cast<float>(Md(r, 0));
      M[r][1] = static_cast<float>(Md(r, 1));
    }
  }
};

struct SweepConfig {
  int border = 1;             // px excluded at the current image's border (>= 1: gradients are 0 there)
  int stride = 1;             // use every stride-th pixel in x and y
  float dt = 0.0f;            // s
  float huber_abs = 0.0f;     // Huber threshold on |r| in intensity units (0 = off)
  bool gradient_weighting = false;
};

/// Sums of one sweep. The 36 entries of the upper triangle of A are packed row by row.
struct SweepSums {
  int candidates = 0;
  int valid = 0;
  double sum_r2 = 0.0;
  double grad_sum = 0.0;  // sum of |grad I_c| over valid pixels (gradient weighting normalisation)
  double A[36] = {};
  double b[8] = {};
};

enum class SweepMode { kAccumulate, kResidual };

/// One sweep over the current image. kAccumulate: A, b with the Jacobian scaled by 1/dt (the caller rescales).
/// kResidual: writes the residual image (0 where invalid) and sum of squares only.
template <SweepMode kMode>
void sweep(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PixelWarp& wp,
           const SweepConfig& cfg, SweepSums* sums, cv::Mat* residual) {
  const int W = cur.intensity.cols;
  const int H = cur.intensity.rows;
  // The reference sample needs its 2x2 neighbourhood inside the 1-px border where gradients are defined:
  // x0 = floor(rx) in [1, W-3]  <=>  rx in [1, W-2).
  const float rx_lo = 1.0f, rx_hi = static_cast<float>(W - 2);
  const float ry_lo = 1.0f, ry_hi = static_cast<float>(H - 2);
  const float dt = cfg.dt;

  const float* Ir = ref.intensity.ptr<float>(0);
  const float* Gxr = ref.grad_x.ptr<float>(0);
  const float* Gyr = ref.grad_y.ptr<float>(0);
  const std::ptrdiff_t sI = static_cast<std::ptrdiff_t>(ref.intensity.step1());
  const std::ptrdiff_t sGx = static_cast<std::ptrdiff_t>(ref.grad_x.step1());
  const std::ptrdiff_t sGy = static_cast<std::ptrdiff_t>(ref.grad_y.step1());

  for (int y = cfg.border; y < H - cfg.border; y += cfg.stride) {
    const float* Ic_row = cur.intensity.ptr<float>(y);
    const float* Gxc_row = cur.grad_x.ptr<float>(y);
    const float* Gyc_row = cur.grad_y.ptr<float>(y);
    float* res_row = kMode == SweepMode::kResidual ? residual->ptr<float>(y) : nullptr;

    // Terms constant along the row: q = (qx, qy, 1), m = G q = qx G_col0 + m_row, etc.
    const float yf = static_cast<float>(y);
    const float qy = (yf - wp.cy) * wp.ify;
    const float ey = wp.cy - yf;  // D(1, 2)
    const float m_row[3] = {wp.G[0][1] * qy + wp.G[0][2], wp.G[1][1] * qy + wp.G[1][2],
                            wp.G[2][1] * qy + wp.G[2][2]};
    const float s_row = wp.mu[1] * qy + wp.mu[2];
    const float qM_row[2] = {wp.M[1][0] * qy + wp.M[2][0], wp.M[1][1] * qy + wp.M[2][1]};

    // Single-precision row accumulators (<= a few hundred terms), added to double at the row's end.
    float acc[36] = {};
    float bacc[8] = {};
    float r2_row = 0.0f, grad_row = 0.0f;
    int valid_row = 0, cand_row = 0;

    for (int x = cfg.border; x < W - cfg.border; x += cfg.stride) {
      ++cand_row;
      const float xf = static_cast<float>(x);
      const float qx = (xf - wp.cx) * wp.ifx;
      const float ex = wp.cx - xf;  // D(0, 2)
      const float mx = wp.G[0][0] * qx + m_row[0];
      const float my = wp.G[1][0] * qx + m_row[1];
      const float mz = wp.G[2][0] * qx + m_row[2];
      const float rx = xf + dt * (wp.fx * mx + ex * mz);
      const float ry = yf + dt * (wp.fy * my + ey * mz);
      // Written so that NaN fails the test.
      if (!(rx >= rx_lo && rx < rx_hi && ry >= ry_lo && ry < ry_hi)) continue;

      // Bilinear weights of the 2x2 neighbourhood.
      const int x0 = static_cast<int>(rx);
      const int y0 = static_cast<int>(ry);
      const float ax = rx - static_cast<float>(x0);
      const float ay = ry - static_cast<float>(y0);
      const float w00 = (1.0f - ax) * (1.0f - ay), w01 = ax * (1.0f - ay);
      const float w10 = (1.0f - ax) * ay, w11 = ax * ay;
      const float* i0 = Ir + y0 * sI + x0;
      const float Ir_s = w00 * i0[0] + w01 * i0[1] + w10 * i0[sI] + w11 * i0[sI + 1];
      const float r = Ic_row[x] - Ir_s;
      ++valid_row;

      if (kMode == SweepMode::kResidual) {
        res_row[x] = r;
        r2_row += r * r;
        continue;
      }

      const float* gx0 = Gxr + y0 * sGx + x0;
      const float* gy0 = Gyr + y0 * sGy + x0;
      const float gxr = w00 * gx0[0] + w01 * gx0[1] + w10 * gx0[sGx] + w11 * gx0[sGx + 1];
      const float gyr = w00 * gy0[0] + w01 * gy0[1] + w10 * gy0[sGy] + w11 * gy0[sGy + 1];
      // Efficient second-order gradient: mean of current and warped reference gradients.
      const float gx = 0.5f * (Gxc_row[x] + gxr);
      const float gy = 0.5f * (Gyc_row[x] + gyr);

      // gD = grad^T D (1x3); S = grad^T dp_r/dx / dt.
      const float gD0 = gx * wp.fx, gD1 = gy * wp.fy, gD2 = gx * ex + gy * ey;
      const float s_q = wp.mu[0] * qx + s_row;
      const float u = gD0 * wp.th[0] + gD1 * wp.th[1] + gD2 * wp.th[2];
      float S[8];
      S[0] = s_q * gD0;
      S[1] = s_q * gD1;
      S[2] = s_q * gD2;
      S[3] = u * (wp.M[0][0] * qx + qM_row[0]);
      S[4] = u * (wp.M[0][1] * qx + qM_row[1]);
      // gD [q]x = (gD x q)^T
      S[5] = gD1 - gD2 * qy;
      S[6] = gD2 * qx - gD0;
      S[7] = gD0 * qy - gD1 * qx;

      float w = 1.0f;
      if (cfg.gradient_weighting) {
        const float gmag = std::sqrt(Gxc_row[x] * Gxc_row[x] + Gyc_row[x] * Gyc_row[x]);
        grad_row += gmag;
        w = gmag;
      }
      if (cfg.huber_abs > 0.0f) {
        const float ar = std::fabs(r);
        if (ar > cfg.huber_abs) w *= cfg.huber_abs / ar;
      }

      float wS[8];
      for (int i = 0; i < 8; ++i) wS[i] = w * S[i];
      int k = 0;
      for (int i = 0; i < 8; ++i) {
        for (int j = i; j < 8; ++j) acc[k++] += wS[i] * S[j];
        bacc[i] += wS[i] * r;
      }
      r2_row += r * r;
    }

    sums->candidates += cand_row;
    sums->valid += valid_row;
    sums->sum_r2 += r2_row;
    if (kMode == SweepMode::kAccumulate) {
      sums->grad_sum += grad_row;
      for (int k = 0; k < 36; ++k) sums->A[k] += acc[k];
      for (int i = 0; i < 8; ++i) sums->b[i] += bacc[i];
    }
  }
}

SweepConfig makeConfig(const PhotometricParams& params, const PreprocessParams& preprocess, double dt_s) {
  SweepConfig cfg;
  cfg.border = std::max(1, preprocess.border_px);
  cfg.stride = std::max(1, params.pixel_stride);
  cfg.dt = static_cast<float>(dt_s);
  cfg.huber_abs = params.huber_threshold > 0.0
                      ? static_cast<float>(params.huber_threshold * params.intensity_noise_sigma)
                      : 0.0f;
  cfg.gradient_weighting = params.gradient_weighting;
  return cfg;
}

bool framesUsable(const PreprocessedFrame& ref, const PreprocessedFrame& cur, int border) {
  const cv::Mat* mats[6] = {&ref.intensity, &ref.grad_x, &ref.grad_y,
                            &cur.intensity, &cur.grad_x, &cur.grad_y};
  for (const cv::Mat* m : mats) {
    if (m->empty() || m->type() != CV_32FC1 || m->size() != cur.intensity.size()) return false;
  }
  return cur.intensity.cols > 2 * border + 3 && cur.intensity.rows > 2 * border + 3;
}

}  // namespace

PhotometricUpdate::PhotometricUpdate(const PhotometricParams& params, const PreprocessParams& preprocess)
    : params_(params), preprocess_(preprocess) {}

int PhotometricUpdate::linearize(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                                 const Vec3& gyro_mean_C, double dt_s, const State& x, ObservedInfo* A,
                                 ObservedVec* b, int* candidates) const {
  const SweepConfig cfg = makeConfig(params_, preprocess_, dt_s);
  const PixelWarp wp(x, K, gyro_mean_C);
  SweepSums sums;
  sweep<SweepMode::kAccumulate>(ref, cur, wp, cfg, &sums, nullptr);

  // Scale: Jacobian was accumulated divided by dt; weights 1/sigma^2, times the gradient normalisation
  // (weights |grad I_c| / mean |grad I_c| over the valid pixels) when enabled.
  double scale = 1.0 / (params_.intensity_noise_sigma * params_.intensity_noise_sigma);
  if (cfg.gradient_weighting) scale *= sums.grad_sum > 0.0 ? sums.valid / sums.grad_sum : 0.0;
  const double sA = scale * dt_s * dt_s;
  const double sb = scale * dt_s;
  int k = 0;
  for (int i = 0; i < 8; ++i) {
    for (int j = i; j < 8; ++j) {
      (*A)(i, j) = sA * sums.A[k++];
      (*A)(j, i) = (*A)(i, j);
    }
    (*b)(i) = sb * sums.b[i];
  }
  if (candidates != nullptr) *candidates = sums.candidates;
  return sums.valid;
}

UpdateStats PhotometricUpdate::update(const PreprocessedFrame& ref, const PreprocessedFrame& cur,
                                      const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, State* x,
                                      ErrorCov* P) {
  UpdateStats stats;
  const SweepConfig cfg = makeConfig(params_, preprocess_, dt_s);
  if (x == nullptr || P == nullptr || !framesUsable(ref, cur, cfg.border) || !(dt_s > 0.0) ||
      !std::isfinite(dt_s) || !gyro_mean_C.allFinite() || !x->allFinite() || !P->allFinite() ||
      !(params_.intensity_noise_sigma > 0.0)) {
    return stats;
  }
  residual_.create(cur.intensity.size(), CV_32FC1);  // no-op after the first call at this size

  auto linearize_at = [&](const State& x_j, internal::ObsMat* A, internal::ObsVec* b) {
    int candidates = 0;
    const int valid = linearize(ref, cur, K, gyro_mean_C, dt_s, x_j, A, b, &candidates);
    stats.valid_ratio = candidates > 0 ? static_cast<double>(valid) / candidates : 0.0;
    return valid > 0 && stats.valid_ratio >= params_.min_valid_ratio;
  };
  const internal::IterationResult it = internal::iterateInformationForm(
      params_.max_passes, params_.stop_threshold, linearize_at, x, P);
  stats.applied = it.ok;
  stats.passes = it.passes;
  stats.last_step_norm = it.last_step_norm;

  // Residual image and RMS at the final estimate (the prior when skipped): warp + one bilinear sample.
  residual_.setTo(0.0f);
  SweepSums sums;
  sweep<SweepMode::kResidual>(ref, cur, PixelWarp(*x, K, gyro_mean_C), cfg, &sums, &residual_);
  if (sums.valid > 0) stats.rms_residual = std::sqrt(sums.sum_r2 / sums.valid);
  if (stats.applied && sums.candidates > 0) {
    stats.valid_ratio = static_cast<double>(sums.valid) / sums.candidates;
  }
  return stats;
}

}  // namespace diekf
