#include "diekf/photometric_update.h"

#include <algorithm>
#include <cmath>

#include <opencv2/core/hal/intrin.hpp>

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

/// Sums of one sweep in double: G = [A | b] (A upper triangle, i <= j < 8; b in column 8).
struct SweepSums {
  int candidates = 0;
  int valid = 0;
  double sum_r2 = 0.0;
  double grad_sum = 0.0;  // sum of |grad I_c| over valid pixels (gradient weighting normalisation)
  double G[8][9] = {};
};

/// Row buffers of one sweep (structure of arrays, length padded to a multiple of 4):
/// T_k = sqrt(w) S_k (k = 0..7) and t = sqrt(w) r, zero for invalid pixels, and the current image's samples.
struct RowBuffers {
  float* T[9];
  float* cur[3];  // I_c, dI_c/dx, dI_c/dy at the row's candidates (strided rows only)
};

/// Gram sums of one block of pairs over a row: G[i][j] += sum_k T_i[k] T_j[k] for i in [I0, I0 + NI), j in
/// [J0, J0 + NJ) (j >= i when kUpper). Compile-time bounds: the accumulators stay in registers.
template <int I0, int NI, int J0, int NJ, bool kUpper>
void gramBlock(float* const* T, int n_pad, double (*G)[9]) {
  using namespace cv;
  v_float32x4 acc[NI][NJ];
  for (int i = 0; i < NI; ++i)
    for (int j = 0; j < NJ; ++j) acc[i][j] = v_setzero_f32();
  for (int k = 0; k < n_pad; k += 4) {
    v_float32x4 a[NI], b[NJ];
    for (int i = 0; i < NI; ++i) a[i] = v_load(T[I0 + i] + k);
    for (int j = 0; j < NJ; ++j) b[j] = v_load(T[J0 + j] + k);
    for (int i = 0; i < NI; ++i)
      for (int j = 0; j < NJ; ++j)
        if (!kUpper || J0 + j >= I0 + i) acc[i][j] = v_muladd(a[i], b[j], acc[i][j]);
  }
  for (int i = 0; i < NI; ++i)
    for (int j = 0; j < NJ; ++j)
      if (!kUpper || J0 + j >= I0 + i) G[I0 + i][J0 + j] += v_reduce_sum(acc[i][j]);
}

/// Gram sums of one row over [T_0..T_7 | t]: A_ij += sum T_i T_j (i <= j < 8), b_i += sum T_i t, in blocks of
/// at most 10 accumulators (4 lanes each) so that nothing spills.
void accumulateRow(float* const* T, int n_pad, double (*G)[9]) {
  gramBlock<0, 4, 0, 4, true>(T, n_pad, G);
  gramBlock<4, 4, 4, 4, true>(T, n_pad, G);
  gramBlock<0, 4, 4, 2, false>(T, n_pad, G);
  gramBlock<0, 4, 6, 2, false>(T, n_pad, G);
  gramBlock<0, 8, 8, 1, false>(T, n_pad, G);
}

/// One linearisation sweep over the current image against the packed reference (I, dI/dx, dI/dy, 0 per
/// pixel). Per row: (1) 4 pixels at a time, warp, bilinear reference sample (4 corner loads + transpose per
/// lane group), residual, Jacobian row S (2/dt times the true row: gradient sum instead of mean, Jacobian
/// without dt; the caller rescales), weight; the results go to the row buffers; (2) the row's Gram sums.
/// The residual r (0 where invalid) is written to `residual`. The weighting options are template parameters.
template <bool kHuber, bool kGradientWeighting>
void sweep(const cv::Mat& ref_packed, const PreprocessedFrame& cur, const PixelWarp& wp, const SweepConfig& cfg,
           RowBuffers buf, SweepSums* sums, cv::Mat* residual) {
  using namespace cv;
  const int W = cur.intensity.cols;
  const int H = cur.intensity.rows;
  const float* R = ref_packed.ptr<float>(0);
  const int sR = static_cast<int>(ref_packed.step1());  // floats per packed row
  // The reference sample needs its 2x2 neighbourhood inside the 1-px border where gradients are defined:
  // x0 = floor(rx) in [1, W-3]  <=>  rx in [1, W-2).
  const v_float32x4 rx_lo = v_setall_f32(1.0f), rx_hi = v_setall_f32(static_cast<float>(W - 2));
  const v_float32x4 ry_lo = v_setall_f32(1.0f), ry_hi = v_setall_f32(static_cast<float>(H - 2));
  const v_float32x4 one = v_setall_f32(1.0f), zero = v_setzero_f32();
  const v_float32x4 dt = v_setall_f32(cfg.dt);
  const v_float32x4 fx = v_setall_f32(wp.fx), fy = v_setall_f32(wp.fy), cx = v_setall_f32(wp.cx);
  const v_float32x4 ifx = v_setall_f32(wp.ifx);
  const v_float32x4 huber = v_setall_f32(cfg.huber_abs);
  const int n = (W - 2 * cfg.border + cfg.stride - 1) / cfg.stride;  // candidates per row
  if (n <= 0) return;
  const int n_pad = (n + 3) & ~3;
  alignas(16) int32_t idx[4];
  alignas(16) float xs_init[4];
  for (int l = 0; l < 4; ++l) xs_init[l] = static_cast<float>(cfg.border + l * cfg.stride);
  const v_float32x4 x_step = v_setall_f32(static_cast<float>(4 * cfg.stride));

  for (int y = cfg.border; y < H - cfg.border; y += cfg.stride) {
    const float* Ic;
    const float* Gxc;
    const float* Gyc;
    if (cfg.stride == 1) {
      // Reading up to 3 values past the last candidate stays inside the image (row y + 1 exists).
      Ic = cur.intensity.ptr<float>(y) + cfg.border;
      Gxc = cur.grad_x.ptr<float>(y) + cfg.border;
      Gyc = cur.grad_y.ptr<float>(y) + cfg.border;
    } else {
      const float* src[3] = {cur.intensity.ptr<float>(y), cur.grad_x.ptr<float>(y), cur.grad_y.ptr<float>(y)};
      for (int c = 0; c < 3; ++c) {
        for (int k = 0; k < n_pad; ++k) buf.cur[c][k] = src[c][cfg.border + std::min(k, n - 1) * cfg.stride];
      }
      Ic = buf.cur[0];
      Gxc = buf.cur[1];
      Gyc = buf.cur[2];
    }
    float* res_row = residual->ptr<float>(y);

    // Terms constant along the row: q = (qx, qy, 1), m = G q = qx G_col0 + m_row, etc.
    const float yf = static_cast<float>(y);
    const float qy_s = (yf - wp.cy) * wp.ify;
    const v_float32x4 yv = v_setall_f32(yf);
    const v_float32x4 qy = v_setall_f32(qy_s);
    const v_float32x4 ey = v_setall_f32(wp.cy - yf);  // D(1, 2)
    const v_float32x4 m0 = v_setall_f32(wp.G[0][1] * qy_s + wp.G[0][2]);
    const v_float32x4 m1 = v_setall_f32(wp.G[1][1] * qy_s + wp.G[1][2]);
    const v_float32x4 m2 = v_setall_f32(wp.G[2][1] * qy_s + wp.G[2][2]);
    const v_float32x4 s_row = v_setall_f32(wp.mu[1] * qy_s + wp.mu[2]);
    const v_float32x4 qM0 = v_setall_f32(wp.M[1][0] * qy_s + wp.M[2][0]);
    const v_float32x4 qM1 = v_setall_f32(wp.M[1][1] * qy_s + wp.M[2][1]);

    v_float32x4 r2 = v_setzero_f32(), gsum = v_setzero_f32(), vcount = v_setzero_f32();
    v_float32x4 xv = v_load(xs_init);
    for (int k = 0; k < n_pad; k += 4, xv += x_step) {
      const v_float32x4 qx = (xv - cx) * ifx;
      const v_float32x4 ex = cx - xv;  // D(0, 2)
      const v_float32x4 mx = v_muladd(v_setall_f32(wp.G[0][0]), qx, m0);
      const v_float32x4 my = v_muladd(v_setall_f32(wp.G[1][0]), qx, m1);
      const v_float32x4 mz = v_muladd(v_setall_f32(wp.G[2][0]), qx, m2);
      const v_float32x4 rx = v_muladd(dt, v_muladd(fx, mx, ex * mz), xv);
      const v_float32x4 ry = v_muladd(dt, v_muladd(fy, my, ey * mz), yv);
      // Comparisons are false for NaN: such pixels are invalid.
      v_float32x4 valid = (rx >= rx_lo) & (rx < rx_hi) & (ry >= ry_lo) & (ry < ry_hi);
      if (k + 4 > n) {
        alignas(16) float lane_ok[4];
        for (int l = 0; l < 4; ++l) lane_ok[l] = k + l < n ? 1.0f : 0.0f;
        valid = valid & (v_load(lane_ok) == one);
      }
      // Invalid lanes sample the safe position (1, 1); their terms are zeroed below.
      const v_float32x4 rxs = v_select(valid, rx, rx_lo), rys = v_select(valid, ry, ry_lo);
      const v_int32x4 x0 = v_floor(rxs), y0 = v_floor(rys);
      const v_float32x4 ax = rxs - v_cvt_f32(x0), ay = rys - v_cvt_f32(y0);
      v_store_aligned(idx, y0 * v_setall_s32(sR) + (x0 << 2));
      // Corners (I, gx, gy, 0) of the 4 lanes, transposed to planes.
      v_float32x4 c[4][4];  // [corner][plane]
      const int corner_off[4] = {0, 4, sR, sR + 4};
      for (int q = 0; q < 4; ++q) {
        v_float32x4 p0 = v_load(R + idx[0] + corner_off[q]), p1 = v_load(R + idx[1] + corner_off[q]);
        v_float32x4 p2 = v_load(R + idx[2] + corner_off[q]), p3 = v_load(R + idx[3] + corner_off[q]);
        v_transpose4x4(p0, p1, p2, p3, c[q][0], c[q][1], c[q][2], c[q][3]);
      }
      const v_float32x4 bx = one - ax, by = one - ay;
      const v_float32x4 w00 = bx * by, w01 = ax * by, w10 = bx * ay, w11 = ax * ay;
      v_float32x4 ref[3];
      for (int pl = 0; pl < 3; ++pl) {
        ref[pl] = v_muladd(w11, c[3][pl], v_muladd(w10, c[2][pl], v_muladd(w01, c[1][pl], w00 * c[0][pl])));
      }
      const v_float32x4 gxc = v_load(Gxc + k), gyc = v_load(Gyc + k);
      const v_float32x4 r = v_select(valid, v_load(Ic + k) - ref[0], zero);
      // Efficient second-order gradient: sum of current and warped reference gradients (1/2 applied later).
      const v_float32x4 gx = gxc + ref[1], gy = gyc + ref[2];
      const v_float32x4 gD0 = gx * fx, gD1 = gy * fy, gD2 = v_muladd(gx, ex, gy * ey);
      const v_float32x4 s_q = v_muladd(v_setall_f32(wp.mu[0]), qx, s_row);
      const v_float32x4 u = v_muladd(gD2, v_setall_f32(wp.th[2]),
                                     v_muladd(gD1, v_setall_f32(wp.th[1]), gD0 * v_setall_f32(wp.th[0])));
      // Weight (0 for invalid pixels); the rows are scaled by sqrt(w).
      v_float32x4 w = v_select(valid, one, zero);
      if constexpr (kGradientWeighting) {
        const v_float32x4 gmag = v_sqrt(v_muladd(gxc, gxc, gyc * gyc));
        gsum = v_muladd(w, gmag, gsum);
        w = w * gmag;
      }
      if constexpr (kHuber) {
        const v_float32x4 ar = v_abs(r);
        w = w * v_select(ar > huber, huber / v_select(ar > huber, ar, one), one);
      }
      const v_float32x4 sw = (kHuber || kGradientWeighting) ? v_sqrt(w) : w;
      const v_float32x4 ssq = sw * s_q, su = sw * u;
      // S = [vartheta (3), mu (2), b_w (3)]; the b_w part is gD [q]x = (gD x q)^T.
      v_store_aligned(buf.T[0] + k, ssq * gD0);
      v_store_aligned(buf.T[1] + k, ssq * gD1);
      v_store_aligned(buf.T[2] + k, ssq * gD2);
      v_store_aligned(buf.T[3] + k, su * v_muladd(v_setall_f32(wp.M[0][0]), qx, qM0));
      v_store_aligned(buf.T[4] + k, su * v_muladd(v_setall_f32(wp.M[0][1]), qx, qM1));
      v_store_aligned(buf.T[5] + k, sw * (gD1 - gD2 * qy));
      v_store_aligned(buf.T[6] + k, sw * (gD2 * qx - gD0));
      v_store_aligned(buf.T[7] + k, sw * (gD0 * qy - gD1 * qx));
      v_store_aligned(buf.T[8] + k, sw * r);
      r2 = v_muladd(r, r, r2);
      vcount += v_select(valid, one, zero);
      if (cfg.stride == 1) {
        // Up to 3 lanes past the last candidate land in the border (or the next row, written later): zeros.
        v_store(res_row + cfg.border + k, r);
      } else {
        alignas(16) float rr[4];
        v_store_aligned(rr, r);
        for (int l = 0; l < 4 && k + l < n; ++l) res_row[cfg.border + (k + l) * cfg.stride] = rr[l];
      }
    }
    accumulateRow(buf.T, n_pad, sums->G);
    sums->candidates += n;
    sums->valid += static_cast<int>(v_reduce_sum(vcount));
    sums->sum_r2 += v_reduce_sum(r2);
    sums->grad_sum += v_reduce_sum(gsum);
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
  using namespace cv;
  packed->create(ref.intensity.size(), CV_32FC4);
  const v_float32x4 z = v_setzero_f32();
  for (int y = 0; y < ref.intensity.rows; ++y) {
    const float* I = ref.intensity.ptr<float>(y);
    const float* gx = ref.grad_x.ptr<float>(y);
    const float* gy = ref.grad_y.ptr<float>(y);
    float* out = packed->ptr<float>(y);
    int x = 0;
    for (; x + 4 <= ref.intensity.cols; x += 4) {
      v_store_interleave(out + 4 * x, v_load(I + x), v_load(gx + x), v_load(gy + x), z);
    }
    for (; x < ref.intensity.cols; ++x) {
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
  prepareBuffers(cur.intensity.size());
  return accumulate(cur, K, gyro_mean_C, dt_s, x, A, b, candidates, nullptr);
}

void PhotometricUpdate::prepareBuffers(const cv::Size& size) {
  if (residual_.size() != size || residual_.type() != CV_32FC1) {
    residual_.create(size, CV_32FC1);
    residual_.setTo(0.0f);  // pixels the sweeps never visit (border, pixel_stride gaps) stay 0
  }
  const int n_pad = (size.width + 3) & ~3;
  if (scratch_.rows != 12 || scratch_.cols < n_pad) scratch_.create(12, n_pad, CV_32FC1);
}

int PhotometricUpdate::accumulate(const PreprocessedFrame& cur, const PinholeK& K, const Vec3& gyro_mean_C,
                                  double dt_s, const State& x, ObservedInfo* A, ObservedVec* b,
                                  int* candidates, double* sum_r2) {
  const SweepConfig cfg = makeConfig(params_, preprocess_, dt_s);
  const PixelWarp wp(x, K, gyro_mean_C);
  SweepSums sums;
  RowBuffers buf;
  for (int i = 0; i < 9; ++i) buf.T[i] = scratch_.ptr<float>(i);
  for (int i = 0; i < 3; ++i) buf.cur[i] = scratch_.ptr<float>(9 + i);
  const bool huber = cfg.huber_abs > 0.0f;
  if (huber && cfg.gradient_weighting) {
    sweep<true, true>(ref_packed_, cur, wp, cfg, buf, &sums, &residual_);
  } else if (huber) {
    sweep<true, false>(ref_packed_, cur, wp, cfg, buf, &sums, &residual_);
  } else if (cfg.gradient_weighting) {
    sweep<false, true>(ref_packed_, cur, wp, cfg, buf, &sums, &residual_);
  } else {
    sweep<false, false>(ref_packed_, cur, wp, cfg, buf, &sums, &residual_);
  }

  // Scale: the sweep's rows are 2/dt times the true S (gradient sum instead of mean, Jacobian without dt);
  // weights 1/sigma^2, times the gradient normalisation (weights |grad I_c| / mean |grad I_c| over the valid
  // pixels) when enabled.
  double scale = 1.0 / (params_.intensity_noise_sigma * params_.intensity_noise_sigma);
  if (cfg.gradient_weighting) scale *= sums.grad_sum > 0.0 ? sums.valid / sums.grad_sum : 0.0;
  const double half_dt = 0.5 * dt_s;
  const double sA = scale * half_dt * half_dt;
  const double sb = scale * half_dt;
  for (int i = 0; i < 8; ++i) {
    for (int j = i; j < 8; ++j) (*A)(i, j) = (*A)(j, i) = sA * sums.G[i][j];
    (*b)(i) = sb * sums.G[i][8];
  }
  if (candidates != nullptr) *candidates = sums.candidates;
  if (sum_r2 != nullptr) *sum_r2 = sums.sum_r2;
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
  prepareBuffers(cur.intensity.size());  // no-op after the first call at this size
  packReference(ref, &ref_packed_);      // once per update, shared by every pass

  // Every pass writes the residual image; the RMS and the valid ratio are those of the last linearisation.
  auto linearize_at = [&](const State& x_j, internal::ObsMat* A, internal::ObsVec* b) {
    int candidates = 0;
    double sum_r2 = 0.0;
    const int valid = accumulate(cur, K, gyro_mean_C, dt_s, x_j, A, b, &candidates, &sum_r2);
    stats.valid_ratio = candidates > 0 ? static_cast<double>(valid) / candidates : 0.0;
    stats.rms_residual = valid > 0 ? std::sqrt(sum_r2 / valid) : 0.0;
    return valid > 0 && stats.valid_ratio >= params_.min_valid_ratio;
  };
  const internal::IterationResult it = internal::iterateInformationForm(
      params_.max_passes, params_.stop_threshold, linearize_at, x, P);
  stats.applied = it.ok;
  stats.passes = it.passes;
  stats.last_step_norm = it.last_step_norm;
  return stats;
}

}  // namespace diekf
