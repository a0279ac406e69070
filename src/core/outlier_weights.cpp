// The photometric update's per-pixel outlier weights and the relief's variance (docs/noise_model.md sections 10
// and 13): PhotometricUpdate::updateWeightMap and PhotometricUpdate::reliefVariance, from the residuals, gradients
// and inverse-depth derivatives the last linearisation left (photometric_update.cpp).
#include "diekf/photometric_update.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/core/hal/intrin.hpp>

#include "lanes.h"
#include "select.h"
#include "window_sum.h"

namespace diekf {

using internal::loadPairs;

namespace {
/// The normal's tilt uncertainty (variance var_mu per tangent axis) as a relative inverse-depth variance along the
/// ray q: var_mu (|q|^2 - (mu . q)^2) / (mu . q)^2, with mq = mu . q and q2 = |q|^2; `grazing` where mu . q is at
/// most 1e-3 (the ray nearly parallel to the plane). The scalar form of the vector code in updateWeightMap and
/// reliefVariance.
template <class T>
T tiltVarianceAlongRay(T mq, T q2, T var_mu, T grazing) {
  return mq > T(1e-3) ? var_mu * std::max(T(0), q2 - mq * mq) / (mq * mq) : grazing;
}

}  // namespace

void PhotometricUpdate::updateWeightMap(const PreprocessedFrame& ref, const PreprocessedFrame& cur,
                                        const PinholeK& K, const State& state, double var_mu,
                                        double dt_s, double variance) {
  const double k = params_.outlier_threshold_sigma;
  weight_map_has_outliers_ = false;
  relief_var_ = 0.0;
  // The previous call's parallax sums carry over when this pair's reference is the image they belong to (an
  // early return or a reset releases the map, and with it the sums' validity).
  const bool previous_sums = weightsBelongTo(ref);
  weight_map_t_s_ = cur.t_s;
  const int W = residual_.cols, H = residual_.rows;
  // The statistics are computed on cells of 2 x 2 pixels (a quarter of the work; the windows are 4 % of the
  // width, so the weights change little within a cell).
  const int Wc = W / 2, Hc = H / 2;
  if (!(k > 0.0) || !(variance > 0.0) || !std::isfinite(variance) || residual_.empty() || Wc < 2 || Hc < 2 ||
      cur.grad_x.size() != residual_.size() || cur.grad_y.size() != residual_.size()) {
    weight_map_.release();
    return;
  }
  const int half = std::max(1, static_cast<int>(std::lround(0.5 * params_.outlier_window_fraction * W)));
  const int hc = std::max(1, static_cast<int>(std::lround(0.5 * half)));  // window half-side in cells
  constexpr int kCh = kWindowChannels;  // r^2, gx^2, gx gy, gy^2, gx r, gy r, a^2, a r (a = dr / d rho)
  const int Wp = (Wc + 3) & ~3;         // cells per plane row, padded to 4 lanes
  // Planes of cells: channel c, cell row j is row c Hc + j.
  weight_cells_.create(kCh * Hc, Wp, CV_32FC1);
  weight_window_.create(kCh * Hc, Wp, CV_32FC1);
  weight_cell_w_.create(Hc, Wc, CV_32FC1);
  weight_map_.create(H, W, CV_32FC1);
  auto cells = [&](int c, int j) { return weight_cells_.ptr<float>(c * Hc + j); };
  auto window = [&](int c, int j) { return weight_window_.ptr<float>(c * Hc + j); };
  // Per cell, the sums of the products over its 4 pixels (4 cells = 8 pixels of a row at a time). The gradient
  // only counts where there is a residual (a valid pixel of the last sweep).
  {
    using namespace cv;
    const v_float32x4 zero = v_setzero_f32();
    const int Wv = Wc & ~3;  // cells done 4 at a time
    for (int j = 0; j < Hc; ++j) {
      float* out[kCh];
      for (int c = 0; c < kCh; ++c) {
        out[c] = cells(c, j);
        std::fill(out[c] + Wv, out[c] + Wp, 0.0f);  // the blocks of 4 cells store their sums whole
      }
      const float* r[2] = {residual_.ptr<float>(2 * j), residual_.ptr<float>(2 * j + 1)};
      const float* a[2] = {depth_jac_.ptr<float>(2 * j), depth_jac_.ptr<float>(2 * j + 1)};
      const float* gx[2] = {cur.grad_x.ptr<float>(2 * j), cur.grad_x.ptr<float>(2 * j + 1)};
      const float* gy[2] = {cur.grad_y.ptr<float>(2 * j), cur.grad_y.ptr<float>(2 * j + 1)};
      for (int i = 0; i < Wv; i += 4) {
        // The sums of both pixel rows in registers, in the order of a sum over rows from zero.
        v_float32x4 acc[kCh];
        for (int c = 0; c < kCh; ++c) acc[c] = zero;
        for (int row = 0; row < 2; ++row) {
          v_float32x4 r0, r1, a0, a1, x0, x1, y0, y1;
          v_load_deinterleave(r[row] + 2 * i, r0, r1);
          v_load_deinterleave(a[row] + 2 * i, a0, a1);
          v_load_deinterleave(gx[row] + 2 * i, x0, x1);
          v_load_deinterleave(gy[row] + 2 * i, y0, y1);
          const v_float32x4 m0 = r0 != zero, m1 = r1 != zero;  // (a mask and x = x where set, +0 elsewhere)
          x0 = m0 & x0;
          y0 = m0 & y0;
          x1 = m1 & x1;
          y1 = m1 & y1;
          acc[0] = acc[0] + v_muladd(r0, r0, r1 * r1);
          acc[1] = acc[1] + v_muladd(x0, x0, x1 * x1);
          acc[2] = acc[2] + v_muladd(x0, y0, x1 * y1);
          acc[3] = acc[3] + v_muladd(y0, y0, y1 * y1);
          acc[4] = acc[4] + v_muladd(x0, r0, x1 * r1);
          acc[5] = acc[5] + v_muladd(y0, r0, y1 * r1);
          acc[6] = acc[6] + v_muladd(a0, a0, a1 * a1);
          acc[7] = acc[7] + v_muladd(a0, r0, a1 * r1);
        }
        for (int c = 0; c < kCh; ++c) v_store(out[c] + i, acc[c]);
      }
      for (int row = 0; row < 2; ++row) {
        for (int x = 2 * Wv; x < 2 * Wc; ++x) {
          const int i = x >> 1;
          const float rv = r[row][x], av = a[row][x];
          const float m = rv != 0.0f ? 1.0f : 0.0f;
          const float gxv = m * gx[row][x], gyv = m * gy[row][x];
          out[0][i] += rv * rv;
          out[1][i] += gxv * gxv;
          out[2][i] += gxv * gyv;
          out[3][i] += gyv * gyv;
          out[4][i] += gxv * rv;
          out[5][i] += gyv * rv;
          out[6][i] += av * av;
          out[7][i] += av * rv;
        }
      }
    }
  }
  // Window sums over (2 hc + 1)^2 cells, truncated at the edges: vertical running sums, then horizontal.
  weight_colsum_.resize(static_cast<size_t>(kCh) * Wp);  // allocates once per image width
  std::fill(weight_colsum_.begin(), weight_colsum_.end(), 0.0f);
  for (int c = 0; c < kCh; ++c) {
    float* colsum = weight_colsum_.data() + c * Wp;
    int lo = 0, hi = 0;  // cell rows [lo, hi) in the column sums
    for (int j = 0; j < Hc; ++j) {
      const int want_hi = std::min(Hc, j + hc + 1), want_lo = std::max(0, j - hc);
      for (; hi < want_hi; ++hi) {
        const float* row = cells(c, hi);
        for (int i = 0; i < Wp; i += 4) cv::v_store(colsum + i, cv::v_load(colsum + i) + cv::v_load(row + i));
      }
      for (; lo < want_lo; ++lo) {
        const float* row = cells(c, lo);
        for (int i = 0; i < Wp; i += 4) cv::v_store(colsum + i, cv::v_load(colsum + i) - cv::v_load(row + i));
      }
      std::copy(colsum, colsum + Wp, window(c, j));  // the vertical sums; the horizontal ones below
    }
    // Horizontal running sums of the vertical sums, the window [i - hc, i + hc] truncated at the edges: four
    // rows at a time with the rows as the lanes (transposed into the lane buffer and back), the rows left over
    // one by one; the same additions per row either way.
    using cv::v_float32x4;
    weight_lanes_.resize(static_cast<size_t>(8) * Wp);  // allocates once per image width
    float* lanes_in = weight_lanes_.data();  // column i of the 4 rows at 4 i
    float* lanes_out = lanes_in + 4 * Wp;
    int j = 0;
    for (; j + 4 <= Hc; j += 4) {
      float* r[4] = {window(c, j), window(c, j + 1), window(c, j + 2), window(c, j + 3)};
      internal::rowsToLanes(r, Wp, lanes_in);
      internal::windowSum(
          Wc, hc, [lanes_in](int k) { return cv::v_load(lanes_in + 4 * k); },
          [lanes_out](int i, const v_float32x4& v) { cv::v_store(lanes_out + 4 * i, v); }, cv::v_setzero_f32());
      std::fill(lanes_out + 4 * Wc, lanes_out + 4 * Wp, 0.0f);
      internal::lanesToRows(lanes_out, Wp, r);
    }
    for (; j < Hc; ++j) {
      std::copy(window(c, j), window(c, j) + Wp, colsum);  // (the column sums are not needed any more)
      internal::windowSumRow(colsum, Wc, hc, window(c, j));
    }
  }
  // 1 / pixels in the window of cell (i, j): a table, remade only when the sizes change.
  if (weight_inv_pixels_.rows != Hc || weight_inv_pixels_.cols != Wc || weight_inv_pixels_hc_ != hc) {
    weight_inv_pixels_.create(Hc, Wc, CV_32FC1);
    weight_inv_pixels_hc_ = hc;
    for (int j = 0; j < Hc; ++j)
      for (int i = 0; i < Wc; ++i)
        weight_inv_pixels_.ptr<float>(j)[i] =
            0.25f / static_cast<float>((std::min(Hc, j + hc + 1) - std::max(0, j - hc)) *
                                       (std::min(Wc, i + hc + 1) - std::max(0, i - hc)));
  }
  auto inv_pixels = [&](int j, int i) { return weight_inv_pixels_.ptr<float>(j)[i]; };
  // Medians over every other cell in both directions.
  auto median_of = [&](auto value) {
    weight_median_buf_.clear();
    for (int j = 0; j < Hc; j += 2)
      for (int i = 0; i < Wc; i += 2) {
        const float v = value(j, i);
        if (std::isfinite(v)) weight_median_buf_.push_back(v);  // capacity kept between images
      }
    if (weight_median_buf_.empty()) return 0.0;
    return static_cast<double>(internal::kthSmallest(weight_median_buf_.data(), weight_median_buf_.size(),
                                                     weight_median_buf_.size() / 2, &weight_median_counts_));
  };

  // (1) Energy: m = mean r^2 of the window, against the larger of the noise and the median over the image.
  // Outliers are what stands out of the bulk of the image; a state error that raises the residual everywhere
  // raises the median with it and does not switch the well-textured half of the image off.
  const double m_ref = std::max(variance, median_of([&](int j, int i) { return window(0, j)[i] * inv_pixels(j, i); }));
  // (2) Shift: q = (mean g r)^T (mean g g^T)^-1 (mean g r), the part of m a local shift of the image explains.
  // Under noise alone q ~ chi-square(2) (scaled: mean = median / ln 2); an object of the ground's texture
  // moving on its own is explained by a shift. Kept in weight_cell_w_ for now.
  for (int j = 0; j < Hc; ++j) {
    const float *gxx = window(1, j), *gxy = window(2, j), *gyy = window(3, j), *gxr = window(4, j), *gyr = window(5, j);
    float* q = weight_cell_w_.ptr<float>(j);
    int i = 0;
#if CV_SIMD128_64F
    // Two cells per double vector, the same operations in the same order as the scalar loop below.
    {
      using namespace cv;
      const v_float64x2 c12 = v_setall_f64(1e-12), c6 = v_setall_f64(1e-6), two = v_setall_f64(2.0);
      const v_float64x2 zero_d = v_setzero_f64();
      const float* ip = weight_inv_pixels_.ptr<float>(j);
      auto shift2 = [&](const v_float64x2& xx, const v_float64x2& xy, const v_float64x2& yy, const v_float64x2& u,
                        const v_float64x2& v) {
        const v_float64x2 ridge = c12 + c6 * (xx + yy);
        const v_float64x2 a = xx + ridge, c = yy + ridge;
        const v_float64x2 det = a * c - xy * xy;
        const v_float64x2 qs = v_select(det > zero_d, ((c * u) * u - ((two * xy) * u) * v + (a * v) * v) / det, zero_d);
        return v_select(qs > zero_d, qs, zero_d);
      };
      for (; i + 4 <= Wc; i += 4) {
        const v_float32x4 xx = v_load(gxx + i), xy = v_load(gxy + i), yy = v_load(gyy + i);
        const v_float32x4 u = v_load(gxr + i), v = v_load(gyr + i);
        const v_float64x2 lo = shift2(v_cvt_f64(xx), v_cvt_f64(xy), v_cvt_f64(yy), v_cvt_f64(u), v_cvt_f64(v));
        const v_float64x2 hi = shift2(v_cvt_f64_high(xx), v_cvt_f64_high(xy), v_cvt_f64_high(yy),
                                      v_cvt_f64_high(u), v_cvt_f64_high(v));
        v_store(q + i, v_cvt_f32(lo, hi) * v_load(ip + i));
      }
    }
#endif
    for (; i < Wc; ++i) {
      const double ridge = 1e-12 + 1e-6 * (double(gxx[i]) + gyy[i]);
      const double a = gxx[i] + ridge, b = gxy[i], c = gyy[i] + ridge, u = gxr[i], v = gyr[i];
      const double det = a * c - b * b;
      const double qs = det > 0.0 ? (c * u * u - 2.0 * b * u * v + a * v * v) / det : 0.0;
      q[i] = static_cast<float>(std::max(0.0, qs)) * inv_pixels(j, i);
    }
  }
  const double n_window = 4.0 * (2 * hc + 1) * (2 * hc + 1);
  const double q_noise = 2.0 * variance * noise_correlation_floor_ / n_window;  // chi-square(2) mean
  const double q_ref = std::max(q_noise, median_of([&](int j, int i) { return weight_cell_w_.ptr<float>(j)[i]; }) /
                                             std::log(2.0));

  // (3) Parallax: the window's relative inverse-depth change e = sum a r / sum a^2 against the plane's, with the
  // sums carried over the recent images along the warp (decay exp(-dt / tau)): a box standing on the ground is
  // seen nearer than the plane in every image, by too little for one image's residual to show.
  const bool parallax = params_.parallax_tolerance > 0.0 && params_.parallax_time_constant_s >= 0.0;
  double e_ref = 0.0, e_spread2 = 0.0;
  if (parallax) {
    std::swap(parallax_sums_, parallax_sums_prev_);
    parallax_sums_.create(Hc, Wc, CV_32FC2);
    const double decay =
        params_.parallax_time_constant_s > 0.0 ? std::exp(-dt_s / params_.parallax_time_constant_s) : 0.0;
    const bool carry = decay > 0.0 && previous_sums && parallax_sums_prev_.rows == Hc &&
                       parallax_sums_prev_.cols == Wc && parallax_sums_prev_.type() == CV_32FC2;
    const float fdecay = static_cast<float>(decay);
    for (int j = 0; j < Hc; ++j) {
      const float* win_aa = window(6, j);
      const float* win_ar = window(7, j);
      // Where the warp took the cell's centre pixel in the reference, i.e. in the previous image's cells.
      const float* rx = ref_x_.ptr<float>(2 * j + 1);
      const float* ry = ref_y_.ptr<float>(2 * j + 1);
      float* sj = parallax_sums_.ptr<float>(j);
      int i = 0;
      {
        // Four cells at a time: the centre pixels' reference positions are the odd lanes of 8 pixels; the
        // previous sums (S, J) of the four cells they land in are gathered as pairs; cells that land nowhere
        // keep their own window sums (as below).
        using namespace cv;
        const v_float32x4 zero = v_setzero_f32(), half_px = v_setall_f32(0.5f), vdecay = v_setall_f32(fdecay);
        const v_int32x4 last_i = v_setall_s32(Wc - 1), last_j = v_setall_s32(Hc - 1), zero_i = v_setzero_s32();
        const float* prev0 = carry ? parallax_sums_prev_.ptr<float>(0) : nullptr;
        const int prev_step = carry ? static_cast<int>(parallax_sums_prev_.step1()) : 0;
        alignas(16) int32_t pi[4], pj[4];
        for (; i + 4 <= Wc; i += 4) {
          v_float32x4 S = v_load(win_ar + i), J = v_load(win_aa + i);
          if (carry) {
            v_float32x4 x_even, x, y_even, y;
            v_load_deinterleave(rx + 2 * i, x_even, x);
            v_load_deinterleave(ry + 2 * i, y_even, y);
            const v_float32x4 lands = (x >= zero) & (y >= zero);
            const v_int32x4 ok = v_reinterpret_as_s32(lands);
            v_store_aligned(pi, v_select(ok, v_min(last_i, v_trunc(half_px * x)), zero_i));
            v_store_aligned(pj, v_select(ok, v_min(last_j, v_trunc(half_px * y)), zero_i));
            const float* q0 = prev0 + pj[0] * prev_step + 2 * pi[0];
            const float* q1 = prev0 + pj[1] * prev_step + 2 * pi[1];
            const float* q2 = prev0 + pj[2] * prev_step + 2 * pi[2];
            const float* q3 = prev0 + pj[3] * prev_step + 2 * pi[3];
            v_float32x4 Sp, Jp;
            loadPairs(q0, q1, q2, q3, &Sp, &Jp);
            S = v_select(lands, S + vdecay * Sp, S);
            J = v_select(lands, J + vdecay * Jp, J);
          }
          v_store_interleave(sj + 2 * i, S, J);
        }
      }
      for (; i < Wc; ++i) {
        float S = win_ar[i], J = win_aa[i];
        if (carry) {
          const float x = rx[2 * i + 1], y = ry[2 * i + 1];
          if (x >= 0.0f && y >= 0.0f) {
            const int pi = std::min(Wc - 1, static_cast<int>(0.5f * x)), pj = std::min(Hc - 1, static_cast<int>(0.5f * y));
            const float* prev = parallax_sums_prev_.ptr<float>(pj) + 2 * pi;
            S += fdecay * prev[0];
            J += fdecay * prev[1];
          }
        }
        sj[2 * i] = S;
        sj[2 * i + 1] = J;
      }
    }
    auto e_at = [&](int j, int i) {
      const float* sj = parallax_sums_.ptr<float>(j) + 2 * i;
      return sj[1] > 0.0f ? sj[0] / sj[1] : std::numeric_limits<float>::quiet_NaN();
    };
    e_ref = median_of(e_at);
    // The image's own spread of e (1.4826 x the median absolute deviation): while the state is still wrong, e
    // varies over the whole image, and nothing stands out of it.
    const double mad = median_of([&](int j, int i) { return static_cast<float>(std::abs(e_at(j, i) - e_ref)); });
    e_spread2 = std::pow(1.4826 * mad, 2);
  }
  // Precision of e: the noise is correlated over the blur's area within a window (the measured correlation of
  // section 3 reaches over tiles larger than the window, and reflects the state error while converging).
  const double var_corr = variance * noise_correlation_floor_;
  const double tol2 = params_.parallax_tolerance * params_.parallax_tolerance;
  const double k2 = k * k;
  const Vec3 mu = state.mu.vector();

  // w = 1 / ((1 + z_m^2) (1 + z_q^4) (1 + z_e^2)) with z_m = m / (k^2 m_ref), z_q = q / (k^2 q_ref) and
  // z_e = (e - e_ref)^2 / max(tol^2 + k^2 (var_e + var_tilt), k^2 spread^2): each term is about 1 within the bulk
  // of the image, 1/2 where the window stands out by k "sigmas" (by the tolerance, for e), falling fast beyond.
  const double inv_m = 1.0 / (k2 * m_ref), inv_q = 1.0 / (k2 * q_ref);
  // The cells' ray x-coordinates (the same for every row).
  weight_qx_.resize(static_cast<size_t>(Wc));  // allocates once per image width
  for (int i = 0; i < Wc; ++i) weight_qx_[i] = (2 * i + 0.5 - K.cx) / K.fx;
  for (int j = 0; j < Hc; ++j) {
    const float* win = window(0, j);
    const float* sj = parallax ? parallax_sums_.ptr<float>(j) : nullptr;
    float* w = weight_cell_w_.ptr<float>(j);
    const double qy = (2 * j + 0.5 - K.cy) / K.fy;
    const double mu_qy = mu(1) * qy, qy2 = qy * qy;
    int i = 0;
#if CV_SIMD128_64F
    // Two cells per double vector, the same operations in the same order as the scalar loop below (a cell
    // without parallax sums, J = 0, computes ze too and selects 0).
    {
      using namespace cv;
      const float* ip = weight_inv_pixels_.ptr<float>(j);
      const v_float64x2 zero_d = v_setzero_f64(), one_d = v_setall_f64(1.0);
      const v_float64x2 v_inv_m = v_setall_f64(inv_m), v_inv_q = v_setall_f64(inv_q);
      const v_float64x2 v_mu0 = v_setall_f64(mu(0)), v_mu_qy = v_setall_f64(mu_qy), v_mu2 = v_setall_f64(mu(2));
      const v_float64x2 v_qy2 = v_setall_f64(qy2), v_var_mu = v_setall_f64(var_mu), v_e_ref = v_setall_f64(e_ref);
      const v_float64x2 v_min_mq = v_setall_f64(1e-3), v_flat = v_setall_f64(1e6);
      const v_float64x2 v_tol2 = v_setall_f64(tol2), v_k2 = v_setall_f64(k2), v_var_corr = v_setall_f64(var_corr);
      const v_float64x2 v_spread = v_setall_f64(k2 * e_spread2);
      const v_float64x2 m_lim = v_setall_f64(0.1), q_lim = v_setall_f64(0.3);
      v_float64x2 flagged = zero_d;
      auto ze2 = [&](const v_float64x2& S, const v_float64x2& J, const v_float64x2& qx) {
        const v_float64x2 mq = (v_mu0 * qx + v_mu_qy) + v_mu2;
        const v_float64x2 q2 = (qx * qx + v_qy2) + one_d;
        const v_float64x2 mq2 = mq * mq, spread = q2 - mq2;
        const v_float64x2 var_tilt =
            v_select(mq > v_min_mq, (v_var_mu * v_select(spread > zero_d, spread, zero_d)) / mq2, v_flat);
        const v_float64x2 de = S / J - v_e_ref;
        const v_float64x2 A = v_tol2 + v_k2 * (v_var_corr / J + var_tilt);
        return v_select(J > zero_d, (de * de) / v_select(A < v_spread, v_spread, A), zero_d);
      };
      auto weight2 = [&](const v_float64x2& zm, const v_float64x2& zq, const v_float64x2& ze) {
        const v_float64x2 zq2 = zq * zq;
        flagged = flagged | (zm > m_lim) | (zq > q_lim) | (ze > q_lim);
        return one_d / (((one_d + zm * zm) * (one_d + zq2 * zq2)) * (one_d + ze * ze));
      };
      for (; i + 4 <= Wc; i += 4) {
        const v_float32x4 m = v_load(win + i) * v_load(ip + i), qf = v_load(w + i);
        const v_float64x2 zm_lo = v_cvt_f64(m) * v_inv_m, zm_hi = v_cvt_f64_high(m) * v_inv_m;
        const v_float64x2 zq_lo = v_cvt_f64(qf) * v_inv_q, zq_hi = v_cvt_f64_high(qf) * v_inv_q;
        v_float64x2 ze_lo = zero_d, ze_hi = zero_d;
        if (parallax) {
          v_float32x4 S, J;
          v_load_deinterleave(sj + 2 * i, S, J);
          ze_lo = ze2(v_cvt_f64(S), v_cvt_f64(J), v_load(weight_qx_.data() + i));
          ze_hi = ze2(v_cvt_f64_high(S), v_cvt_f64_high(J), v_load(weight_qx_.data() + i + 2));
        }
        v_store(w + i, v_cvt_f32(weight2(zm_lo, zq_lo, ze_lo), weight2(zm_hi, zq_hi, ze_hi)));
      }
      if (v_check_any(flagged)) weight_map_has_outliers_ = true;
    }
#endif
    for (; i < Wc; ++i) {
      const double zm = win[i] * inv_pixels(j, i) * inv_m, zq = w[i] * inv_q;
      double ze = 0.0;
      if (parallax && sj[2 * i + 1] > 0.0f) {
        // The plane's own tilt uncertainty changes the inverse depth along the ray q by (dmu . q) / (mu . q).
        const double J = sj[2 * i + 1];
        const double qx = weight_qx_[i];
        const double mq = mu(0) * qx + mu_qy + mu(2);
        const double q2 = qx * qx + qy2 + 1.0;
        const double var_tilt = tiltVarianceAlongRay(mq, q2, var_mu, 1e6);
        const double de = sj[2 * i] / J - e_ref;
        ze = de * de / std::max(tol2 + k2 * (var_corr / J + var_tilt), k2 * e_spread2);
      }
      const double zq2 = zq * zq;
      w[i] = static_cast<float>(1.0 / ((1.0 + zm * zm) * (1.0 + zq2 * zq2) * (1.0 + ze * ze)));
      if (zm > 0.1 || zq > 0.3 || ze > 0.3) weight_map_has_outliers_ = true;
    }
  }
  // A pixel is as suspect as the most suspect window that contains it: each cell takes the minimum of its own
  // weight and of the clearly low weights over the (2 hc + 1)^2 cells around (separable: rows into the free plane
  // 0 of weight_window_, then columns). Without it an object's border, where the windows lie only partly on it,
  // keeps about half its weight; the mild reductions of the bulk are not spread. What a cell of weight w spreads
  // rises continuously from w (below kLow) to 1 (from kHigh): a threshold would make the weights, and the
  // estimate, jump when rounding moves a weight across it (different CPUs, compilers).
  {
    constexpr float kLow = 0.4f, kHigh = 0.6f;
    const auto spread = [](float w) {
      return w <= kLow ? w : (w >= kHigh ? 1.0f : w + (1.0f - w) * (w - kLow) / (kHigh - kLow));
    };
    // Rows with a clearly low weight (most have none: they are skipped).
    weight_median_buf_.assign(static_cast<size_t>(Hc), 0.0f);  // capacity kept between images
    float* row_has = weight_median_buf_.data();
    for (int j = 0; j < Hc; ++j) {
      const float* w = weight_cell_w_.ptr<float>(j);
      float* rowmin = window(0, j);
      bool low = false;
      for (int i = 0; i < Wc; ++i) low |= w[i] < kHigh;  // (no short cut: vectorised)
      row_has[j] = low ? 1.0f : 0.0f;
      if (!low) continue;
      // What each cell spreads (1 from kHigh up), then the minimum over the window (4 cells at a time inside
      // the row, truncated at its ends). Plane 1 of weight_window_ is free by now.
      float* sp = window(1, j);
      for (int i = 0; i < Wc; ++i) sp[i] = spread(w[i]);
      auto min_at = [&](int i) {
        float m = 1.0f;
        for (int d = std::max(0, i - hc); d <= std::min(Wc - 1, i + hc); ++d) m = std::min(m, sp[d]);
        return m;
      };
      int i = 0;
      for (; i < std::min(hc, Wc); ++i) rowmin[i] = min_at(i);
      for (; i + 4 + hc <= Wc; i += 4) {
        cv::v_float32x4 m = cv::v_setall_f32(1.0f);
        for (int d = -hc; d <= hc; ++d) m = cv::v_min(m, cv::v_load(sp + i + d));
        cv::v_store(rowmin + i, m);
      }
      for (; i < Wc; ++i) rowmin[i] = min_at(i);
    }
    for (int j = 0; j < Hc; ++j) {
      float* w = weight_cell_w_.ptr<float>(j);
      for (int d = std::max(0, j - hc); d <= std::min(Hc - 1, j + hc); ++d) {
        if (row_has[d] == 0.0f) continue;
        const float* rowmin = window(0, d);
        for (int i = 0; i < Wc; ++i) w[i] = std::min(w[i], rowmin[i]);
      }
    }
  }
  if (parallax) relief_var_ = reliefVariance(K, mu, var_mu, var_corr);
  // The cells' weights to the pixels (the odd last row and column take their neighbours').
  for (int y = 0; y < H; ++y) {
    float* w = weight_map_.ptr<float>(y);
    if ((y & 1) == 1 && (y >> 1) < Hc) {
      const float* above = weight_map_.ptr<float>(y - 1);  // the same cells
      std::copy(above, above + W, w);
      continue;
    }
    const float* wc = weight_cell_w_.ptr<float>(std::min(Hc - 1, y >> 1));
    for (int i = 0; i < Wc; ++i) w[2 * i] = w[2 * i + 1] = wc[i];
    for (int x = 2 * Wc; x < W; ++x) w[x] = wc[Wc - 1];
  }
}

double PhotometricUpdate::reliefVariance(const PinholeK& K, const Vec3& mu, double var_mu, double var_corr) const {
  // Over the cells with parallax sums, weighted by the weight each keeps times its information J about e (what
  // the update's estimate of the plane leans on): the spread of e = S / J about its weighted mean, less what the
  // noise of e (var_corr / J) and the normal's tilt uncertainty along the ray (var_tilt) explain
  // (docs/noise_model.md section 13). Sums: u = w J, u e = w S, u e^2 = w S^2 / J.
  // Four cells at a time in float (each row's sums, then into double), the rest one at a time.
  const int Hc = weight_cell_w_.rows, Wc = weight_cell_w_.cols;
  const float mu0 = static_cast<float>(mu(0)), vmu = static_cast<float>(var_mu);
  const double* qxs = weight_qx_.data();  // the cells' ray x-coordinates (updateWeightMap)
  double su = 0.0, sue = 0.0, sue2 = 0.0, sw = 0.0, sut = 0.0;
  for (int j = 0; j < Hc; ++j) {
    const float* sj = parallax_sums_.ptr<float>(j);
    const float* w = weight_cell_w_.ptr<float>(j);
    const float qy = static_cast<float>((2 * j + 0.5 - K.cy) / K.fy);
    const float mu_qy = static_cast<float>(mu(1)) * qy + static_cast<float>(mu(2)), qy2 = qy * qy + 1.0f;
    // The normal's tilt uncertainty along the ray q = (qx, qy, 1).
    const auto tilt = [&](float qx) { return tiltVarianceAlongRay(mu0 * qx + mu_qy, qx * qx + qy2, vmu, 0.0f); };
    int i = 0;
    {
      using namespace cv;
      const v_float32x4 zero = v_setzero_f32(), one = v_setall_f32(1.0f), v_min_mq = v_setall_f32(1e-3f);
      const v_float32x4 v_mu0 = v_setall_f32(mu0), v_mu_qy = v_setall_f32(mu_qy), v_qy2 = v_setall_f32(qy2);
      const v_float32x4 v_vmu = v_setall_f32(vmu);
      v_float32x4 a_u = zero, a_ue = zero, a_ue2 = zero, a_w = zero, a_ut = zero;
      for (; i + 4 <= Wc; i += 4) {
#if CV_SIMD128_64F
        const v_float32x4 qx = v_cvt_f32(v_load(qxs + i), v_load(qxs + i + 2));
#else  // (32-bit ARM's NEON has no double lanes: the same roundings one by one)
        const v_float32x4 qx(static_cast<float>(qxs[i]), static_cast<float>(qxs[i + 1]), static_cast<float>(qxs[i + 2]),
                             static_cast<float>(qxs[i + 3]));
#endif
        v_float32x4 S, J;
        v_load_deinterleave(sj + 2 * i, S, J);
        const v_float32x4 valid = J > zero;
        const v_float32x4 wv = v_select(valid, v_load(w + i), zero), Js = v_select(valid, J, one);
        const v_float32x4 u = wv * J, mq = v_mu0 * qx + v_mu_qy, mq2 = mq * mq;
        const v_float32x4 spread = qx * qx + v_qy2 - mq2;
        const v_float32x4 var_t =
            v_select(mq > v_min_mq, v_vmu * v_select(spread > zero, spread, zero) / v_select(mq > v_min_mq, mq2, one),
                     zero);
        a_u += u;
        a_ue += wv * S;
        a_ue2 += wv * S * S / Js;
        a_w += wv;
        a_ut += u * var_t;
      }
      su += v_reduce_sum(a_u);
      sue += v_reduce_sum(a_ue);
      sue2 += v_reduce_sum(a_ue2);
      sw += v_reduce_sum(a_w);
      sut += v_reduce_sum(a_ut);
    }
    for (; i < Wc; ++i) {
      const float J = sj[2 * i + 1];
      if (!(J > 0.0f)) continue;
      const float S = sj[2 * i], wi = w[i];
      su += wi * J;
      sue += wi * S;
      sue2 += wi * S * S / J;
      sw += wi;
      sut += wi * J * tilt(static_cast<float>(qxs[i]));
    }
  }
  if (!(su > 0.0)) return 0.0;
  const double mean = sue / su;
  const double excess = sue2 / su - mean * mean - (var_corr * sw + sut) / su;
  return std::isfinite(excess) ? std::max(0.0, excess) : 0.0;
}

}  // namespace diekf
