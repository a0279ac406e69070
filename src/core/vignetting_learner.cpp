// The lens's radial vignetting learned from the ground's motion: see vignetting_learner.h.
#include "diekf/vignetting_learner.h"

#include "select.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/LU>

namespace diekf {

void VignettingLearner::configure(int width, int height, double cx_px, double cy_px) {
  width_ = std::max(0, width);
  height_ = std::max(0, height);
  cx_ = cx_px;
  cy_ = cy_px;
  const double dx = std::max(cx_, width_ - 1 - cx_), dy = std::max(cy_, height_ - 1 - cy_);
  inv_r2max_ = 1.0 / std::max(1.0, dx * dx + dy * dy);
  grid_cols_ = (width_ - 1) / kGridPx + 2;  // one beyond the last column: every pixel has four grid points
  grid_rows_ = (height_ - 1) / kGridPx + 2;
  grid_.assign(static_cast<size_t>(grid_cols_) * static_cast<size_t>(grid_rows_),
               Vec2::Constant(std::numeric_limits<double>::quiet_NaN()));
  const size_t samples = static_cast<size_t>((width_ / kStridePx + 1) * (height_ / kStridePx + 1));
  for (std::vector<float>* v : {&d_, &z1_, &z2_, &w_}) v->assign(samples, 0.f);
  scratch_.reserve(samples);
  median_.reserve(samples);
  reset();
}

void VignettingLearner::reset() {
  N_.setZero();
  b_.setZero();
  G_.setZero();
  pairs_ = 0;
  calls_ = 0;
  settled_ = false;
}

bool VignettingLearner::due() {
  ++calls_;
  return !settled_ || calls_ % kSettledEvery == 0;
}

bool VignettingLearner::observe(const float* cur, const float* ref) {
  if (width_ < 8 || height_ < 8 || cur == nullptr || ref == nullptr) return false;
  const int W = width_, H = height_;
  constexpr float kMinValue = 0.02f;  // of the image's mean: darker samples are noise
  const float xmax = static_cast<float>(W) - 2.f, ymax = static_cast<float>(H) - 2.f;
  const float inv_grid = 1.f / kGridPx, cx = static_cast<float>(cx_), cy = static_cast<float>(cy_);
  const float inv_r2max = static_cast<float>(inv_r2max_);
  const float noise_var = static_cast<float>(kNoiseVar), warp_var = static_cast<float>(kWarpVarPx2);
  size_t n = 0;
  for (int y = 2; y < H - 2; y += kStridePx) {
    const int gj = y / kGridPx;
    const float fy = static_cast<float>(y - gj * kGridPx) * inv_grid;
    const float dyc = static_cast<float>(y) - cy;
    for (int x = 2; x < W - 2; x += kStridePx) {
      const int gi = x / kGridPx;
      const float fx = static_cast<float>(x - gi * kGridPx) * inv_grid;
      const Vec2* g0 = grid_.data() + static_cast<size_t>(gj * grid_cols_ + gi);
      const Vec2* g1 = g0 + grid_cols_;
      const float w00 = (1.f - fx) * (1.f - fy), w01 = fx * (1.f - fy), w10 = (1.f - fx) * fy, w11 = fx * fy;
      const float px = static_cast<float>(w00 * g0[0].x() + w01 * g0[1].x() + w10 * g1[0].x() + w11 * g1[1].x());
      const float py = static_cast<float>(w00 * g0[0].y() + w01 * g0[1].y() + w10 * g1[0].y() + w11 * g1[1].y());
      if (!(px >= 1.f && px < xmax && py >= 1.f && py < ymax)) continue;  // (NaN: not seen)
      const int x0 = static_cast<int>(px), y0 = static_cast<int>(py);
      const float ax = px - static_cast<float>(x0), ay = py - static_cast<float>(y0);
      const float* r0 = ref + y0 * W + x0;
      const float top = r0[0] + ax * (r0[1] - r0[0]), bottom = r0[W] + ax * (r0[W + 1] - r0[W]);
      const float ur = top + ay * (bottom - top);
      const float uc = cur[y * W + x];
      if (!(ur > kMinValue) || !(uc > kMinValue)) continue;
      const float inv_ur = 1.f / ur;
      const float gx = ((r0[1] - r0[0]) + ay * ((r0[W + 1] - r0[W]) - (r0[1] - r0[0]))) * inv_ur;
      const float gy = (bottom - top) * inv_ur;
      const float dx = static_cast<float>(x) - cx, dxr = px - cx, dyr = py - cy;
      const float s = (dx * dx + dyc * dyc) * inv_r2max, sr = (dxr * dxr + dyr * dyr) * inv_r2max;
      d_[n] = std::log(uc * inv_ur);
      z1_[n] = s - sr;
      z2_[n] = (s - sr) * (s + sr);
      w_[n] = 1.f / (noise_var + (gx * gx + gy * gy) * warp_var);
      ++n;
    }
  }
  if (n < 64) return false;

  // Residuals at the estimate so far (0 before one), their intercept (the exposure ratio) and robust scale in
  // units of each sample's own sigma; Huber weights from them.
  Vec2 a_prev = Vec2::Zero();
  double sigma_unused = 0.0;
  if (!estimate(&a_prev.x(), &a_prev.y(), &sigma_unused)) a_prev.setZero();
  double sw = 0.0, swe = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const double e = d_[i] - a_prev.x() * z1_[i] - a_prev.y() * z2_[i];
    sw += w_[i];
    swe += w_[i] * e;
  }
  const double c = swe / sw;
  // |normalised residual| per sample, and a copy for its median.
  std::vector<float>& t = scratch_;
  t.resize(n);  // (reserved by configure: no allocation)
  for (size_t i = 0; i < n; ++i)
    t[i] = std::abs(static_cast<float>(d_[i] - a_prev.x() * z1_[i] - a_prev.y() * z2_[i] - c)) * std::sqrt(w_[i]);
  median_.assign(t.begin(), t.end());
  const double scale = 1.4826 * internal::kthSmallest(median_.data(), n, n / 2, &select_counts_);
  const double limit = kHuberSigma * scale;

  double Sw = 0.0, Sd = 0.0;
  Vec2 Sz = Vec2::Zero(), Szd = Vec2::Zero();
  Mat2 Szz = Mat2::Zero();
  for (size_t i = 0; i < n; ++i) {
    const double h = limit > 0.0 && t[i] > limit ? limit / t[i] : 1.0;
    const double w = w_[i] * h;
    const Vec2 z(z1_[i], z2_[i]);
    Sw += w;
    Sd += w * d_[i];
    Sz += w * z;
    Szd += w * d_[i] * z;
    Szz += w * z * z.transpose();
  }
  if (!(Sw > 0.0)) return false;
  // Centred: the pair's own intercept removed.
  const Mat2 Np = Szz - Sz * Sz.transpose() / Sw;
  const Vec2 bp = Szd - Sz * (Sd / Sw);
  if (!Np.allFinite() || !bp.allFinite()) return false;
  const Vec2 score = bp - Np * a_prev;
  const double keep = 1.0 - 1.0 / kPairMemory;
  N_ = keep * N_ + Np;
  b_ = keep * b_ + bp;
  G_ = keep * keep * G_ + score * score.transpose();
  ++pairs_;
  double a1 = 0.0, a2 = 0.0, sigma = 0.0;
  settled_ = estimate(&a1, &a2, &sigma) && sigma < kSettledSigmaLn;
  return true;
}

bool VignettingLearner::estimate(double* a1, double* a2, double* sigma_corner_ln) const {
  if (pairs_ < kMinPairs) return false;
  // Both coefficients determined: the smaller eigenvalue of the symmetric 2 x 2 N a fair part of the larger, and
  // above an absolute floor (kMinInformation), which the relative test alone misses when N is rounding only.
  const double tr = N_.trace(), det = N_.determinant();
  const double half_gap = std::sqrt(std::max(0.0, 0.25 * tr * tr - det));
  const double lo = 0.5 * tr - half_gap, hi = 0.5 * tr + half_gap;
  if (!(lo > kMinInformation) || !(lo > 1e-9 * hi) || !std::isfinite(hi)) return false;
  const Mat2 N_inv = N_.inverse();
  const Vec2 a = N_inv * b_;
  const Mat2 cov = N_inv * G_ * N_inv;
  const Vec2 one(1.0, 1.0);
  const double var = one.dot(cov * one);
  if (!a.allFinite() || !(var >= 0.0)) return false;
  *a1 = a.x();
  *a2 = a.y();
  *sigma_corner_ln = std::sqrt(var);
  return true;
}

}  // namespace diekf
