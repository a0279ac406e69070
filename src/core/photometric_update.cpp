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

using Vec4f = Eigen::Matrix<float, 4, 1>;
using Mat4f = Eigen::Matrix<float, 4, 4>;
using Mat4d = Eigen::Matrix<double, 4, 4>;
using Vec4d = Eigen::Matrix<double, 4, 1>;

/// Sums of one sweep. A (8x8, symmetric) is kept as its upper block triangle of 4x4 blocks,
/// A = [[A00, A01], [A01^T, A11]]: the lower off-diagonal block is never accumulated. 4x4 blocks map onto
/// 4-float SIMD registers, so this costs 48 multiply-adds per pixel in 12 vector operations, fewer
/// instructions than the 36 scalar multiply-adds of the exact upper triangle.
struct SweepSums {
  int candidates = 0;
  int valid = 0;
  double sum_r2 = 0.0;
  double grad_sum = 0.0;  // sum of |grad I_c| over valid pixels (gradient weighting normalisation)
  Mat4d A00 = Mat4d::Zero(), A01 = Mat4d::Zero(), A11 = Mat4d::Zero();
  Vec4d b0 = Vec4d::Zero(), b1 = Vec4d::Zero();
};

enum class SweepMode { kAccumulate, kResidual };

/// The reference image as the sweeps read it. Strides in floats per row.
struct RefView {
  const float* packed = nullptr;  // (I, dI/dx, dI/dy, 0) interleaved: one 4-float load per bilinear corner
  std::ptrdiff_t packed_stride = 0;
  const float* intensity = nullptr;  // plain intensity, for the residual-only sweep (scalar bilinear)
  std::ptrdiff_t intensity_stride = 0;
};

RefView makeRefView(const cv::Mat& packed, const cv::Mat* intensity) {
  RefView v;
  v.packed = packed.ptr<float>(0);
  v.packed_stride = static_cast<std::ptrdiff_t>(packed.step1());
  if (intensity != nullptr) {
    v.intensity = intensity->ptr<float>(0);
    v.intensity_stride = static_cast<std::ptrdiff_t>(intensity->step1());
  }
  return v;
}

/// One sweep over the current image. kAccumulate: A, b with the Jacobian scaled by 1/dt (the caller rescales).
/// kResidual: writes the residual image (0 where invalid) and sum of squares only. The weighting options are
/// template parameters so that the common case compiles without their branches.
template <SweepMode kMode, bool kHuber = false, bool kGradientWeighting = false>
void sweep(const RefView& ref, const PreprocessedFrame& cur, const PixelWarp& wp, const SweepConfig& cfg,
           SweepSums* sums, cv::Mat* residual) {
  const int W = cur.intensity.cols;
  const int H = cur.intensity.rows;
  // The reference sample needs its 2x2 neighbourhood inside the 1-px border where gradients are defined:
  // x0 = floor(rx) in [1, W-3]  <=>  rx in [1, W-2).
  const float rx_lo = 1.0f, rx_hi = static_cast<float>(W - 2);
  const float ry_lo = 1.0f, ry_hi = static_cast<float>(H - 2);
  const float dt = cfg.dt;

  const float* R = ref.packed;
  const std::ptrdiff_t sR = ref.packed_stride;
  const float* Ir = ref.intensity;
  const std::ptrdiff_t sI = ref.intensity_stride;

  for (int y = cfg.border; y < H - cfg.border; y += cfg.stride) {
    const float* Ic_row = cur.intensity.ptr<float>(y);
    const float* Gxc_row = cur.grad_x.ptr<float>(y);
    const float* Gyc_row = cur.grad_y.ptr<float>(y);
    float* res_row = nullptr;
    if constexpr (kMode == SweepMode::kResidual) res_row = residual->ptr<float>(y);

    // Terms constant along the row: q = (qx, qy, 1), m = G q = qx G_col0 + m_row, etc.
    const float yf = static_cast<float>(y);
    const float qy = (yf - wp.cy) * wp.ify;
    const float ey = wp.cy - yf;  // D(1, 2)
    const float m_row[3] = {wp.G[0][1] * qy + wp.G[0][2], wp.G[1][1] * qy + wp.G[1][2],
                            wp.G[2][1] * qy + wp.G[2][2]};
    const float s_row = wp.mu[1] * qy + wp.mu[2];
    const float qM_row[2] = {wp.M[1][0] * qy + wp.M[2][0], wp.M[1][1] * qy + wp.M[2][1]};

    // Single-precision row accumulators (<= a few hundred terms), added to double at the row's end.
    Mat4f A00 = Mat4f::Zero(), A01 = Mat4f::Zero(), A11 = Mat4f::Zero();
    Vec4f b0 = Vec4f::Zero(), b1 = Vec4f::Zero();
    float r2_row = 0.0f, grad_row = 0.0f;
    int valid_row = 0, cand_row = 0;

    const float stride_f = static_cast<float>(cfg.stride);
    float xf = static_cast<float>(cfg.border) - stride_f;  // exact: small integers
    for (int x = cfg.border; x < W - cfg.border; x += cfg.stride) {
      ++cand_row;
      xf += stride_f;
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
      ++valid_row;

      if constexpr (kMode == SweepMode::kResidual) {
        const float* i00 = Ir + y0 * sI + x0;
        const float r = Ic_row[x] - (w00 * i00[0] + w01 * i00[1] + w10 * i00[sI] + w11 * i00[sI + 1]);
        res_row[x] = r;
        r2_row += r * r;
        continue;
      }

      const float* c00 = R + y0 * sR + 4 * x0;
      const Vec4f ref_s = w00 * Eigen::Map<const Vec4f>(c00) + w01 * Eigen::Map<const Vec4f>(c00 + 4) +
                          w10 * Eigen::Map<const Vec4f>(c00 + sR) + w11 * Eigen::Map<const Vec4f>(c00 + sR + 4);
      const float r = Ic_row[x] - ref_s[0];

      // Efficient second-order gradient: mean of current and warped reference gradients; the factor 1/2 is
      // applied to A and b by the caller (here g = sum, S = 2 x the true row / dt).
      const float gx = Gxc_row[x] + ref_s[1];
      const float gy = Gyc_row[x] + ref_s[2];

      // gD = grad^T D (1x3); S = grad^T dp_r/dx / dt.
      const float gD0 = gx * wp.fx, gD1 = gy * wp.fy, gD2 = gx * ex + gy * ey;
      const float s_q = wp.mu[0] * qx + s_row;
      const float u = gD0 * wp.th[0] + gD1 * wp.th[1] + gD2 * wp.th[2];
      // S = [vartheta (3), mu (2), b_w (3)]; the b_w part is gD [q]x = (gD x q)^T.
      const Vec4f S0(s_q * gD0, s_q * gD1, s_q * gD2, u * (wp.M[0][0] * qx + qM_row[0]));
      const Vec4f S1(u * (wp.M[0][1] * qx + qM_row[1]), gD1 - gD2 * qy, gD2 * qx - gD0, gD0 * qy - gD1 * qx);

      float w = 1.0f;
      if constexpr (kGradientWeighting) {
        const float gmag = std::sqrt(Gxc_row[x] * Gxc_row[x] + Gyc_row[x] * Gyc_row[x]);
        grad_row += gmag;
        w = gmag;
      }
      if constexpr (kHuber) {
        const float ar = std::fabs(r);
        if (ar > cfg.huber_abs) w *= cfg.huber_abs / ar;
      }

      const Vec4f wS0 = w * S0, wS1 = w * S1;
      A00.noalias() += S0 * wS0.transpose();
      A01.noalias() += S0 * wS1.transpose();
      A11.noalias() += S1 * wS1.transpose();
      b0 += r * wS0;
      b1 += r * wS1;
    }

    sums->candidates += cand_row;
    sums->valid += valid_row;
    sums->sum_r2 += r2_row;
    if constexpr (kMode == SweepMode::kAccumulate) {
      sums->grad_sum += grad_row;
      sums->A00 += A00.cast<double>();
      sums->A01 += A01.cast<double>();
      sums->A11 += A11.cast<double>();
      sums->b0 += b0.cast<double>();
      sums->b1 += b1.cast<double>();
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

/// (I, dI/dx, dI/dy, 0) of the reference frame interleaved into a CV_32FC4 buffer (reallocated only when the
/// size changes).
void packReference(const PreprocessedFrame& ref, cv::Mat* packed) {
  packed->create(ref.intensity.size(), CV_32FC4);
  for (int y = 0; y < ref.intensity.rows; ++y) {
    const float* I = ref.intensity.ptr<float>(y);
    const float* gx = ref.grad_x.ptr<float>(y);
    const float* gy = ref.grad_y.ptr<float>(y);
    float* out = packed->ptr<float>(y);
    for (int x = 0; x < ref.intensity.cols; ++x) {
      out[4 * x + 0] = I[x];
      out[4 * x + 1] = gx[x];
      out[4 * x + 2] = gy[x];
      out[4 * x + 3] = 0.0f;
    }
  }
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
                                 ObservedVec* b, int* candidates) {
  packReference(ref, &ref_packed_);
  return accumulate(cur, K, gyro_mean_C, dt_s, x, A, b, candidates);
}

int PhotometricUpdate::accumulate(const PreprocessedFrame& cur, const PinholeK& K, const Vec3& gyro_mean_C,
                                  double dt_s, const State& x, ObservedInfo* A, ObservedVec* b,
                                  int* candidates) const {
  const SweepConfig cfg = makeConfig(params_, preprocess_, dt_s);
  const PixelWarp wp(x, K, gyro_mean_C);
  SweepSums sums;
  constexpr SweepMode kAcc = SweepMode::kAccumulate;
  const RefView ref = makeRefView(ref_packed_, nullptr);
  const bool huber = cfg.huber_abs > 0.0f;
  if (huber && cfg.gradient_weighting) {
    sweep<kAcc, true, true>(ref, cur, wp, cfg, &sums, nullptr);
  } else if (huber) {
    sweep<kAcc, true, false>(ref, cur, wp, cfg, &sums, nullptr);
  } else if (cfg.gradient_weighting) {
    sweep<kAcc, false, true>(ref, cur, wp, cfg, &sums, nullptr);
  } else {
    sweep<kAcc, false, false>(ref, cur, wp, cfg, &sums, nullptr);
  }

  // Scale: the sweep's rows are 2/dt times the true S (gradient sum instead of mean, Jacobian without dt);
  // weights 1/sigma^2, times the gradient normalisation (weights |grad I_c| / mean |grad I_c| over the valid
  // pixels) when enabled.
  double scale = 1.0 / (params_.intensity_noise_sigma * params_.intensity_noise_sigma);
  if (cfg.gradient_weighting) scale *= sums.grad_sum > 0.0 ? sums.valid / sums.grad_sum : 0.0;
  const double half_dt = 0.5 * dt_s;
  const double sA = scale * half_dt * half_dt;
  const double sb = scale * half_dt;
  // Upper triangle from the blocks, mirrored (the float diagonal blocks are symmetric only to rounding).
  A->topLeftCorner<4, 4>() = sA * sums.A00;
  A->topRightCorner<4, 4>() = sA * sums.A01;
  A->bottomRightCorner<4, 4>() = sA * sums.A11;
  A->triangularView<Eigen::StrictlyLower>() = A->transpose();
  b->head<4>() = sb * sums.b0;
  b->tail<4>() = sb * sums.b1;
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
  packReference(ref, &ref_packed_);                   // once per update, shared by every pass

  auto linearize_at = [&](const State& x_j, internal::ObsMat* A, internal::ObsVec* b) {
    int candidates = 0;
    const int valid = accumulate(cur, K, gyro_mean_C, dt_s, x_j, A, b, &candidates);
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
  sweep<SweepMode::kResidual>(makeRefView(ref_packed_, &ref.intensity), cur, PixelWarp(*x, K, gyro_mean_C), cfg,
                              &sums, &residual_);
  if (sums.valid > 0) stats.rms_residual = std::sqrt(sums.sum_r2 / sums.valid);
  if (stats.applied && sums.candidates > 0) {
    stats.valid_ratio = static_cast<double>(sums.valid) / sums.candidates;
  }
  return stats;
}

}  // namespace diekf
