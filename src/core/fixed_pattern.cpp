// Camera-fixed photometric structure: see include/diekf/fixed_pattern.h and docs/noise_model.md section 11.
#include "diekf/fixed_pattern.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <opencv2/core/hal/intrin.hpp>

#include "diekf/image_preprocessor.h"

namespace diekf {

double imageMotionPx(const Vec3& vartheta_inv_s, const Vec3& rate_radps, const PinholeK& K, double dt_s) {
  if (!(dt_s > 0.0) || !vartheta_inv_s.allFinite() || !rate_radps.allFinite()) return 0.0;
  const double f = 0.5 * (K.fx + K.fy);
  const double r = 0.5 * std::hypot(static_cast<double>(K.width), static_cast<double>(K.height));
  const double centre = f * (vartheta_inv_s.head<2>().norm() + rate_radps.head<2>().norm());
  const double rim = r * (std::abs(vartheta_inv_s.z()) + std::abs(rate_radps.z()));
  return dt_s * (centre + rim);
}

Vec2 groundShiftPx(const Vec3& vartheta_inv_s, const Vec3& rate_radps, const PinholeK& K, double dt_s) {
  if (!(dt_s > 0.0) || !vartheta_inv_s.allFinite() || !rate_radps.allFinite()) return Vec2::Zero();
  return dt_s * Vec2(-K.fx * (vartheta_inv_s.x() + rate_radps.y()), K.fy * (rate_radps.x() - vartheta_inv_s.y()));
}

Vec3 lowerBoundVartheta(const Vec3& vartheta_inv_s, const Mat3& cov) {
  const double norm = vartheta_inv_s.norm(), trace = cov.trace();
  if (!(norm > 0.0) || !std::isfinite(norm) || !(trace >= 0.0) || !std::isfinite(trace)) return Vec3::Zero();
  return std::max(0.0, 1.0 - 2.0 * std::sqrt(trace) / norm) * vartheta_inv_s;
}

namespace {

float medianOf(std::vector<float>* v) {
  if (v->empty()) return 0.f;
  auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

/// Shrinkage of a deviation d with standard error se: d (1 - (k se / d)^4), 0 below k se (a deviation at 1.5 k se
/// keeps 80 %, at 2 k se 94 %).
float shrink(float d, float se, float k) {
  const float z2 = d * d;
  const float t2 = k * k * se * se;
  if (!(z2 > t2)) return 0.f;
  const float q = t2 / z2;
  return d * (1.f - q * q);
}

/// Mean over the (2 half + 1)^2 window (truncated at the edges) of src into dst, by running sums; tmp: W x H,
/// colsum: W doubles. No allocation.
void boxMean(const float* src, float* dst, float* tmp, double* colsum, int W, int H, int half) {
  for (int y = 0; y < H; ++y) {
    const float* r = src + y * W;
    float* o = tmp + y * W;
    double sum = 0.0;
    int lo = 0, hi = 0;
    for (int x = 0; x < W; ++x) {
      const int want_hi = std::min(W, x + half + 1), want_lo = std::max(0, x - half);
      for (; hi < want_hi; ++hi) sum += r[hi];
      for (; lo < want_lo; ++lo) sum -= r[lo];
      o[x] = static_cast<float>(sum / (hi - lo));
    }
  }
  std::fill(colsum, colsum + W, 0.0);
  int lo = 0, hi = 0;
  for (int y = 0; y < H; ++y) {
    const int want_hi = std::min(H, y + half + 1), want_lo = std::max(0, y - half);
    for (; hi < want_hi; ++hi)
      for (int x = 0; x < W; ++x) colsum[x] += tmp[hi * W + x];
    for (; lo < want_lo; ++lo)
      for (int x = 0; x < W; ++x) colsum[x] -= tmp[lo * W + x];
    const double inv = 1.0 / (hi - lo);
    for (int x = 0; x < W; ++x) dst[y * W + x] = static_cast<float>(colsum[x] * inv);
  }
}

}  // namespace

FixedPattern::FixedPattern(const FixedPatternParams& params, int width, int height, const cv::Mat& flat_field,
                           const Vec2& optical_centre_px)
    : params_(params), width_(width), height_(height) {
  if (width <= 0 || height <= 0) throw std::invalid_argument("FixedPattern: empty working image");
  if (!flat_field.empty()) {
    if (flat_field.type() != CV_32FC1 || flat_field.cols != width || flat_field.rows != height)
      throw std::invalid_argument("FixedPattern: the flat field must be CV_32FC1 of the working size");
    flat_inv_.create(height, width, CV_32FC1);
    for (int i = 0; i < width * height; ++i) {
      const float g = flat_field.ptr<float>()[i];
      flat_inv_.ptr<float>()[i] = g > 1e-3f ? 1.f / g : 1.f;
    }
  }
  last_u_.create(height, width, CV_32FC1);
  m1_.create(height, width, CV_32FC1);
  m2_.create(height, width, CV_32FC1);
  gain_.create(height, width, CV_32FC1);
  inv_gain_.create(height, width, CV_32FC1);
  offset_.create(height, width, CV_32FC1);
  confidence_.create(height, width, CV_32FC1);
  vig_.create(height, width, CV_32FC1);
  inv_vig_.create(height, width, CV_32FC1);
  // The optical centre: the radial vignetting's (its radius, VignettingLearner::radius2, is 1 at the farthest
  // corner) and the centre of the ground's turn and change of scale (learn()).
  const double cx = optical_centre_px.x() >= 0.0 ? optical_centre_px.x() : 0.5 * (width - 1);
  const double cy = optical_centre_px.y() >= 0.0 ? optical_centre_px.y() : 0.5 * (height - 1);
  vig_learner_.configure(width, height, cx, cy);
  radius_px_.create(height, width, CV_32FC1);
  pixel_samples_.create(height, width, CV_32FC1);  // (zeroed by reset())
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x)
      radius_px_.at<float>(y, x) = static_cast<float>(std::sqrt((x - cx) * (x - cx) + (y - cy) * (y - cy)));
  median_buf_.reserve(static_cast<size_t>(((width + 1) / 2) * ((height + 1) / 2)));
  smooth_.create(height, width, CV_32FC1);
  scratch_.create(height, width, CV_32FC1);
  const size_t cells = static_cast<size_t>(kGroundSide) * kGroundSide;
  ground_.cell.assign(cells, 0.0);
  coarse_.cell.assign(cells, 0.0);
  coarse_shifted_.cell.assign(cells, 0.0);
  for (Snapshot& s : snapshots_) {
    s.detail.create(height, width, CV_32FC1);
    s.ground.cell.assign(cells, 0.0);
  }
  colsum_.assign(static_cast<size_t>(width), 0.0);
  reset();
}

void FixedPattern::reset() {
  m1_.setTo(0.f);
  m2_.setTo(0.f);
  pixel_samples_.setTo(0.f);
  gain_.setTo(1.f);
  inv_gain_.setTo(1.f);
  offset_.setTo(0.f);
  confidence_.setTo(1.f);
  clearVignetting();
  samples_ = 0.0;
  var_factor_ = 0.0;
  detail_noise_per_sample_ = 0.0;
  for (Snapshot& s : snapshots_) s.valid = false;
  newest_ = 0;
  position_ = Vec2::Zero();
  turn_scale_ = Vec2::Zero();
  std::fill(ground_.cell.begin(), ground_.cell.end(), 0.0);
  ground_.scale = 1.0;
  for (GroundWeights* g : {&coarse_, &coarse_shifted_}) {
    std::fill(g->cell.begin(), g->cell.end(), 0.0);
    g->scale = 1.0;
  }
  coarse_var_factor_ = 0.0;
  coarse_shifted_var_factor_ = 0.0;
  frames_since_refresh_ = 0;
  last_valid_ = false;
  last_kept_ = false;
  active_ = false;
  vignetting_only_ = false;
  has_low_confidence_ = false;
  strong_fraction_ = 0.0;
  contrast_share_ = 0.0;
}

namespace {

/// Sum, and with `squares` the sum of squares, of n floats in double, two double lanes per SIMD vector where
/// there are (the rounding of the double sums differs from a sequential loop only in the last bits).
double sumOf(const float* v, int n, double* squares) {
  double s = 0.0, sq = 0.0;
  int i = 0;
#if CV_SIMD128_64F
  {
    using namespace cv;
    v_float64x2 s0 = v_setzero_f64(), s1 = v_setzero_f64(), q0 = v_setzero_f64(), q1 = v_setzero_f64();
    for (; i + 4 <= n; i += 4) {
      const v_float32x4 x = v_load(v + i);
      const v_float64x2 lo = v_cvt_f64(x), hi = v_cvt_f64_high(x);
      s0 += lo;
      s1 += hi;
      if (squares != nullptr) {
        q0 = v_muladd(lo, lo, q0);
        q1 = v_muladd(hi, hi, q1);
      }
    }
    s = v_reduce_sum(s0 + s1);
    sq = v_reduce_sum(q0 + q1);
  }
#endif
  for (; i < n; ++i) {
    s += v[i];
    sq += static_cast<double>(v[i]) * v[i];
  }
  if (squares != nullptr) *squares = sq;
  return s;
}

}  // namespace

void FixedPattern::apply(float* I, double* sum, double* sum_sq) {
  const int n = width_ * height_;
  if (!flat_inv_.empty()) {
    const float* fi = flat_inv_.ptr<float>();
    for (int i = 0; i < n; ++i) I[i] *= fi[i];
  }
  double sq = 0.0;
  double s = sumOf(I, n, &sq);
  const double mean = s / n;
  last_valid_ = params_.enabled && mean > 1e-3;
  last_kept_ = last_valid_;
  last_mean_ = mean;
  if (last_valid_) {
    const float inv_mean = static_cast<float>(1.0 / mean);
    float* u = last_u_.ptr<float>();
    for (int i = 0; i < n; ++i) u[i] = I[i] * inv_mean;
  }
  if (corrects() && last_valid_) {
    // I' = mean (u - a) / g = (I - mean a) / g
    const float* a = offset_.ptr<float>();
    const float* ig = inv_gain_.ptr<float>();
    const float fm = static_cast<float>(mean);
    for (int i = 0; i < n; ++i) I[i] = (I[i] - fm * a[i]) * ig[i];
    s = sumOf(I, n, &sq);
  }
  *sum = s;
  *sum_sq = sq;
}

bool FixedPattern::reapply(float* I, double* sum, double* sum_sq) const {
  if (!last_kept_ || !corrects()) return false;
  const int n = width_ * height_;
  const float* u = last_u_.ptr<float>();
  const float* a = offset_.ptr<float>();
  const float* ig = inv_gain_.ptr<float>();
  const float fm = static_cast<float>(last_mean_);
  for (int i = 0; i < n; ++i) I[i] = fm * (u[i] - a[i]) * ig[i];
  *sum = sumOf(I, n, sum_sq);
  return true;
}

bool FixedPattern::learn(double motion_px, const Vec2& ground_shift_px, const Vec2& ground_turn_scale) {
  if (!last_valid_ || !params_.enabled) return false;
  if (ground_shift_px.allFinite()) position_ += ground_shift_px;
  if (ground_turn_scale.allFinite()) {
    turn_scale_ += ground_turn_scale;
    turn_scale_.x() = std::remainder(turn_scale_.x(), 2.0 * M_PI);
  }
  last_valid_ = false;  // each image is learned from once
  const double w = std::min(1.0, motion_px / params_.decorrelation_px);
  if (!(w > 0.0) || !std::isfinite(w)) return false;
  samples_ = std::min(samples_ + w, params_.memory_samples);
  const float lambda = static_cast<float>(w / std::max(samples_, w));  // (the ground cells' weights below)
  const float keep = 1.f - lambda;
  const int n = width_ * height_;
  const float* u = last_u_.ptr<float>();
  float* m1 = m1_.ptr<float>();
  float* m2 = m2_.ptr<float>();
  // Exponentially weighted mean and variance per pixel (m2 holds the variance): v <- (1 - l) (v + l d^2),
  // d = u - mean, l = w_p / n_p. Each pixel counts its own ground's motion w_p: a turn or a change of scale moves
  // the ground at radius r by r times as much, and not at all at the centre (a climb over one spot: the centre
  // sees the same ground throughout, which its mean cannot tell from a pattern). The shift plus r (|turn| + |log
  // scale|), an upper estimate as imageMotionPx's, at most motion_px; the caller's w where it gives neither.
  const double shift = ground_shift_px.allFinite() ? ground_shift_px.norm() : 0.0;
  const double turn_scale = ground_turn_scale.allFinite() ? ground_turn_scale.cwiseAbs().sum() : 0.0;
  const bool per_pixel = shift > 0.0 || turn_scale > 0.0;
  const float w_max = static_cast<float>(w), memory = static_cast<float>(params_.memory_samples);
  const float w_shift = static_cast<float>(shift / params_.decorrelation_px);
  const float w_per_radius = static_cast<float>(turn_scale / params_.decorrelation_px);
  const float* radius = radius_px_.ptr<float>();
  float* np = pixel_samples_.ptr<float>();
  // (Branch-free, so that it vectorises: a pixel whose ground did not move has w_p = 0, hence l = 0.)
  const auto update = [&](int i, float wp) {
    np[i] = std::min(np[i] + wp, memory);
    const float l = wp / std::max(np[i], 1e-12f);
    const float d = u[i] - m1[i];
    m1[i] += l * d;
    m2[i] = (1.f - l) * (m2[i] + l * d * d);
  };
  if (per_pixel) {
    for (int i = 0; i < n; ++i) update(i, std::min(w_max, w_shift + w_per_radius * radius[i]));
  } else {
    for (int i = 0; i < n; ++i) update(i, w_max);
  }
  // The mean's variance and its covariances with the snapshots' means, in units of one sample's variance: the
  // ground is counted per cell of its track through the image (docs/noise_model.md section 11), so that samples
  // of ground seen before (hovering, flying back) add to that ground's weight, not to the number of samples. The
  // mean's weights decay by keep and the current cell gains lambda.
  {
    const double l = lambda, kp = keep;
    const double cell_px = kGroundCellSamples * (params_.decorrelation_px > 0.0 ? params_.decorrelation_px : 1.0);
    const int c = groundCell(position_, turn_scale_, cell_px);
    for (Snapshot& s : snapshots_)
      s.cov_factor = kp * s.cov_factor + (s.valid ? l * s.ground.at(c) : 0.0);
    addWeight(&ground_, &var_factor_, c, l, kp);
    addWeight(&coarse_, &coarse_var_factor_, groundCell(position_, turn_scale_, coarseCellPx()), l, kp);
    addWeight(&coarse_shifted_, &coarse_shifted_var_factor_, groundCell(position_, turn_scale_, coarseCellPx(), 0.5),
              l, kp);
  }
  ++frames_since_refresh_;
  if (!snapshots_[newest_].valid && samples_ >= 0.5 * params_.startup_samples) {
    // The first snapshot of the detail, half-way through the start-up (refresh() takes the later ones).
    computeDetail(scratch_.ptr<float>(), smooth_.ptr<float>(), gain_.ptr<float>());
    takeSnapshot();
    if (vignetting_only_)  // (gain_ was used as scratch)
      vig_.copyTo(gain_);
    else
      gain_.setTo(1.f);
  }
  // Before the start-up is done: the lens's vignetting alone. Its learner fits pair ratios, in which the ground's
  // texture cancels, so it needs neither the start-up's samples nor different patches of ground; on low-contrast
  // ground the uncorrected vignetting is what the pair's images share most, and it holds the flow toward "no
  // motion" (docs/noise_model.md section 11, "The vignetting before the start-up").
  bool changed = false;
  if (!active_ && params_.radial_vignetting && frames_since_refresh_ >= params_.refresh_frames) {
    frames_since_refresh_ = 0;
    changed = applyVignettingOnly();
  }
  if (samples_ >= params_.startup_samples && (frames_since_refresh_ >= params_.refresh_frames || !active_)) {
    // Only from enough different ground: the mean of one patch of ground seen again and again (hovering, holding
    // a position) is fixed in the image like a pattern, and its structure stands out of its own spread. Counted
    // over cells of the local mean's window, the coarser scale tested (docs/noise_model.md section 11).
    // The estimator waives it while the images deny the motion the IMU measures (waivePatchCondition).
    if (!patches_waived_ && independentPatches() < params_.min_ground_patches) return changed;
    refresh();
    frames_since_refresh_ = 0;
    active_ = true;
    vignetting_only_ = false;
    return true;
  }
  return changed;
}

bool FixedPattern::applyVignettingOnly() {
  const bool was_on = vignetting_only_;
  fitVignetting();  // (V = 1 unless its corner stands out of its standard error)
  vignetting_only_ = vig_corner_ != 1.0;
  if (!vignetting_only_ && !was_on) return false;
  vig_.copyTo(gain_);
  inv_vig_.copyTo(inv_gain_);
  return true;  // (offset_ stays 0 and confidence_ 1 until the start-up is done)
}

template <class Value>
float FixedPattern::sampleMedian(Value value) {
  median_buf_.clear();
  for (int y = 0; y < height_; y += 2)
    for (int x = 0; x < width_; x += 2) median_buf_.push_back(value(y * width_ + x));
  return medianOf(&median_buf_);
}

void FixedPattern::computeDetail(float* dt, float* sm, float* tmp, float level) {
  const int n = width_ * height_;
  const float* m1 = m1_.ptr<float>();
  const float* iv = inv_vig_.ptr<float>();
  if (!(level > 0.f)) level = std::max(sampleMedian([&](int i) { return m1[i] * iv[i]; }), 1e-6f);
  const float inv_level = 1.f / level;
  for (int i = 0; i < n; ++i) dt[i] = m1[i] * iv[i] * inv_level;
  boxMean(dt, sm, tmp, colsum_.data(), width_, height_, localMeanHalfPx());
  for (int i = 0; i < n; ++i) dt[i] = dt[i] / std::max(sm[i], 1e-6f) - 1.f;
}

void FixedPattern::addWeight(GroundWeights* g, double* var_factor, int c, double l, double kp) {
  // All weights decay by kp (through the common scale) and cell c gains l: the variance factor sum w^2 follows.
  const double w_c = kp * g->at(c);  // the cell's weight after the decay
  *var_factor = kp * kp * *var_factor + 2.0 * l * w_c + l * l;
  if (kp * g->scale < 1e-200) {  // the first sample (keep 0), or the scale about to underflow
    for (double& v : g->cell) v *= g->scale * kp;
    g->scale = 1.0;
  } else {
    g->scale *= kp;
  }
  g->cell[static_cast<size_t>(c)] += l / g->scale;
}

int FixedPattern::groundCell(const Vec2& position_px, const Vec2& turn_scale, double cell_px, double shift) const {
  // A turn or a change of scale moves the pixels at the image's RMS radius sqrt((W^2 + H^2) / 12) by one cell
  // per step.
  const double rms_radius_px =
      std::sqrt((static_cast<double>(width_) * width_ + static_cast<double>(height_) * height_) / 12.0);
  Vec2 step = (turn_scale * (rms_radius_px / cell_px)).array() + shift;
  step = step.array().floor();
  if (!step.allFinite()) step.setZero();
  const double kx = 97.0 * step.x() + 29.0 * step.y(), ky = 61.0 * step.x() + 113.0 * step.y();
  auto wrap = [shift](double v) {
    const double k = std::floor(v + shift);
    if (!std::isfinite(k)) return 0;
    const long long i = static_cast<long long>(std::fmod(k, static_cast<double>(kGroundSide)));
    return static_cast<int>(i < 0 ? i + kGroundSide : i);
  };
  return wrap(position_px.y() / cell_px + ky) * kGroundSide + wrap(position_px.x() / cell_px + kx);
}

void FixedPattern::takeSnapshot() {
  if (snapshots_[newest_].valid) newest_ = 1 - newest_;  // the older slot
  Snapshot& s = snapshots_[newest_];
  scratch_.copyTo(s.detail);
  s.var_factor = var_factor_;
  s.cov_factor = var_factor_;
  std::copy(ground_.cell.begin(), ground_.cell.end(), s.ground.cell.begin());
  s.ground.scale = ground_.scale;
  s.valid = true;
}

void FixedPattern::clearVignetting() {
  // (std::fill, not cv::Mat::setTo: that allocates a buffer for its scalar on every call.)
  const size_t n = static_cast<size_t>(width_) * static_cast<size_t>(height_);
  std::fill(vig_.ptr<float>(), vig_.ptr<float>() + n, 1.f);
  std::fill(inv_vig_.ptr<float>(), inv_vig_.ptr<float>() + n, 1.f);
  vig_corner_ = 1.0;
}

void FixedPattern::fitVignetting() {
  if (!params_.radial_vignetting) return;  // (vig_ stays all 1 from reset())
  clearVignetting();
  // ln V = a1 s + a2 s^2 from the ground's motion (VignettingLearner): the temporal mean m holds the ground's
  // large-scale structure too. The corner's ln V tested as a whole against its standard error and shrunk like a
  // pixel's, so the field stays smooth.
  double a1 = 0.0, a2 = 0.0, sigma = 0.0;
  if (!vig_learner_.estimate(&a1, &a2, &sigma)) return;
  const double dev = a1 + a2;
  // A lens darkens its periphery (the cos^4 law, the barrel's mechanical shading): a brighter corner is the estimate's
  // error (the first few dozen pairs of a slow flight over sharp edges read up to 3.8 at the corner, 1-sigma 0.08 in
  // ln), not a field to apply.
  if (dev > 0.0) return;
  const double kept = shrink(static_cast<float>(dev), static_cast<float>(sigma),
                             static_cast<float>(params_.significance_sigma));
  if (kept == 0.0 || !std::isfinite(kept) || !(std::abs(dev) > 0.0)) return;
  const double f = kept / dev;
  float* vg = vig_.ptr<float>();
  float* iv = inv_vig_.ptr<float>();
  for (int y = 0, i = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x, ++i) {
      // The learner's own radius, 1 at the farthest corner (in float, as the field has always been evaluated).
      const double s = static_cast<float>(vig_learner_.radius2(x, y));
      vg[i] = static_cast<float>(std::clamp(std::exp(f * (a1 * s + a2 * s * s)), 0.05, 2.0));
      iv[i] = 1.f / vg[i];
    }
  vig_corner_ = std::clamp(std::exp(f * dev), 0.05, 2.0);
}

void FixedPattern::refresh() {
  const int n = width_ * height_;
  const float* m1 = m1_.ptr<float>();
  const float* m2 = m2_.ptr<float>();
  float* g = gain_.ptr<float>();
  float* a = offset_.ptr<float>();
  float* ig = inv_gain_.ptr<float>();
  float* conf = confidence_.ptr<float>();
  // The radial vignetting first (one smooth field); the per-pixel model below sees the mean and the spread
  // divided by it.
  fitVignetting();
  // Spread per pixel (into a for now); medians of the spread (S) and of the mean (the ground's level) over every
  // 2nd pixel in x and y.
  const float* vg = vig_.ptr<float>();
  const float* iv = inv_vig_.ptr<float>();
  for (int i = 0; i < n; ++i) a[i] = std::sqrt(std::max(0.f, m2[i])) * iv[i];
  const float S = sampleMedian([&](int i) { return a[i]; });
  const float level = sampleMedian([&](int i) { return m1[i] * iv[i]; });
  if (!(S > 1e-6f) || !(level > 1e-6f)) {  // no texture seen: no model
    clearVignetting();
    gain_.setTo(1.f);
    inv_gain_.setTo(1.f);
    offset_.setTo(0.f);
    confidence_.setTo(1.f);
    has_low_confidence_ = false;
    strong_fraction_ = 0.0;
    return;
  }
  const float inv_S = 1.f / S, inv_level = 1.f / level;
  // The ground is not white noise: its structure larger than the path flown so far has not averaged out and
  // leaves deviations all over the image. A camera-fixed pattern is what stands out of that bulk: the standard
  // error is at least the robust spread (1.4826 x median absolute deviation) of the ratios over the image.
  // Two scales: the mean ratio g_m = m / level as its local mean over a window of 10 % of the width (vignetting,
  // a shadow, the ground's large patches) times the detail g_m / local mean (projector dots, specks of dirt). Each
  // is tested against its own bulk: the ground's large patches do not hide the dots.
  float* sm = smooth_.ptr<float>();
  float* dt = scratch_.ptr<float>();
  computeDetail(dt, sm, g, level);  // g as scratch (rewritten below)
  const float bulk_sm = 1.4826f * sampleMedian([&](int i) { return std::abs(sm[i] - 1.f); });
  float bulk_dt = 1.4826f * sampleMedian([&](int i) { return std::abs(dt[i]); });
  // The spatial spread of the detail is an upper bound of its noise: a pattern dense at the working resolution
  // (an IR projector's dots, one every few pixels) is part of it. Its noise alone is what differs between the
  // detail now and the snapshot's, taken when the mean was mostly of other samples: the fixed pattern cancels.
  // With the mean's variance v and the snapshot's v_s (per unit sample variance) and their covariance c:
  // Var(detail - snapshot) = s^2 (v + v_s - 2 c), so the detail's own noise is s sqrt(v). Only where the two
  // means are of different ground (their correlation counted over the ground cells); the newest such snapshot.
  const auto correlation = [&](const Snapshot& s) {
    return s.valid && var_factor_ > 0.0 && s.var_factor > 0.0 ? s.cov_factor / std::sqrt(var_factor_ * s.var_factor)
                                                              : 1.0;
  };
  for (int j = 0; j < 2; ++j) {
    const Snapshot& s = snapshots_[j == 0 ? newest_ : 1 - newest_];
    const double vd = var_factor_ + s.var_factor - 2.0 * s.cov_factor;
    if (!s.valid || !(vd > 0.0) || correlation(s) >= kMaxSnapshotCorrelation) continue;
    const float* snap = s.detail.ptr<float>();
    const float med = sampleMedian([&](int i) { return dt[i] - snap[i]; });
    const float spread = 1.4826f * sampleMedian([&](int i) { return std::abs(dt[i] - snap[i] - med); });
    detail_noise_per_sample_ = spread / std::sqrt(vd);
    break;
  }
  // Between two such measurements (a new snapshot not yet far enough from the mean, or flying back over the same
  // ground), the last measured noise of one sample, scaled to the mean's variance now: the ground's detail is
  // still as noisy per sample, and the spatial spread would count the dots as noise again.
  if (detail_noise_per_sample_ > 0.0)
    bulk_dt = std::min(bulk_dt, static_cast<float>(detail_noise_per_sample_ * std::sqrt(var_factor_)));
  if (correlation(snapshots_[newest_]) < kSnapshotRenewCorrelation) takeSnapshot();
  const float bulk_s = 1.4826f * sampleMedian([&](int i) { return std::abs(a[i] * inv_S - 1.f); });
  const float k = static_cast<float>(params_.significance_sigma);
  const float* pixel_samples = pixel_samples_.ptr<float>();
  const float g_floor = static_cast<float>(std::max(1e-3, 0.5 * params_.min_gain));
  const float inv_min_gain = params_.min_gain > 0.0 ? static_cast<float>(1.0 / params_.min_gain) : 0.f;
  has_low_confidence_ = false;
  int strong = 0;
  for (int i = 0; i < n; ++i) {
    // Mean ratio g_m = g + a / c and spread ratio g_s = g (c: the ground's mean level, u = g R + a). A gain
    // (shadow, vignetting, dirt) moves both alike; added light (glare, saturating dots) only the mean. A
    // pattern edge moving a little (the shadow as the drone tilts) raises the spread there, so the mean ratio
    // is the gain unless the spread says that light was added (g_s below g_m).
    // Standard errors from the pixel's own samples (its ground's motion, learn()).
    const float n_p = std::max(1.f, pixel_samples[i]);
    const float se_rel_m = 1.f / std::sqrt(n_p), se_rel_s = 1.f / std::sqrt(2.f * n_p);
    const float se_m = a[i] * inv_level * se_rel_m;  // standard error of g_m from the pixel's own statistics
    const float se_sm = std::max(se_m, bulk_sm), se_dt = std::max(se_m, bulk_dt);
    const float d_sm = shrink(sm[i] - 1.f, se_sm, k), d_dt = shrink(dt[i], se_dt, k);
    const float gm_s = (1.f + d_sm) * (1.f + d_dt);
    // What the shrinkage left uncorrected, in k standard errors: a deviation near the threshold is neither
    // trusted nor removed, so its pixel loses weight, 1 / (1 + z^4) (1/2 at the threshold).
    float c_unexplained = 1.f;
    if (k > 0.f) {  // (k = 0: every deviation is removed, nothing is left over)
      const float z_sm = (sm[i] - 1.f - d_sm) / (k * se_sm), z_dt = (dt[i] - d_dt) / (k * se_dt);
      const float z2 = z_sm * z_sm + z_dt * z_dt;
      c_unexplained = std::isfinite(z2) ? 1.f / (1.f + z2 * z2) : 0.f;
    }
    const float gs = a[i] * inv_S;
    const float se_s = std::max(std::max(gs, 1e-3f) * se_rel_s, bulk_s);
    const bool added = gm_s - gs > k * se_s;  // the spread is significantly below the mean ratio: added light
    const float gain = added ? std::clamp(gs, 0.f, gm_s) : gm_s;
    const float add = added ? (gm_s - gain) * level : 0.f;
    // Confidence: the gain's noise amplification below min_gain, and the part of the pixel's spread the model
    // does not explain: a spread significantly above the gain's (a pattern edge that moves, a dot modulating
    // the ground below a working pixel) leaves the corrected pixel with (g_s / g)^2 times the ground's variance,
    // the excess unrelated to the motion; weight g^2 / g_s^2.
    const float gs_s = 1.f + shrink(gs - gain, se_s, k) / std::max(gain, 1e-3f);
    const float total = vg[i] * gain;  // with the vignetting
    float c = inv_min_gain > 0.f ? std::min(1.f, (total * inv_min_gain) * (total * inv_min_gain)) : 1.f;
    if (gs_s > 1.f) c /= gs_s * gs_s;
    c *= c_unexplained;
    conf[i] = c;
    if (c < 1.f) has_low_confidence_ = true;
    g[i] = std::max(total, g_floor);
    ig[i] = 1.f / g[i];
    a[i] = add * vg[i];
    // (the vignetting, smooth and expected of every lens, is not reported as a strong pattern)
    if (std::abs(gain - 1.f) > 0.3f || add > 0.5f * S || c < 0.5f) ++strong;
  }
  strong_fraction_ = static_cast<double>(strong) / n;
  // The pattern's share of the image's contrast: the update weighs a pixel by its gradient, so what the pattern
  // adds to the image, (g - 1) level + a, votes for "no motion" in proportion to its gradient energy against the
  // image's (the last image learned from, uncorrected; forward differences).
  const float* u = last_u_.ptr<float>();
  float* p = sm;  // the local mean is not needed any more: the pattern's part of the image, once per pixel
  for (int i = 0; i < n; ++i) p[i] = (g[i] - 1.f) * level + a[i];
  double e_pat = 0.0, e_img = 0.0;
  for (int y = 0; y + 1 < height_; ++y) {
    for (int x = 0; x + 1 < width_; ++x) {
      const int i = y * width_ + x;
      const float px = p[i + 1] - p[i], py = p[i + width_] - p[i];
      const float ux = u[i + 1] - u[i], uy = u[i + width_] - u[i];
      e_pat += static_cast<double>(px) * px + static_cast<double>(py) * py;
      e_img += static_cast<double>(ux) * ux + static_cast<double>(uy) * uy;
    }
  }
  contrast_share_ = e_img > 0.0 ? std::min(1.0, e_pat / e_img) : 0.0;
}

cv::Mat loadFlatField(const std::string& path, const CameraModel& camera, const PreprocessParams& preprocess) {
  cv::FileStorage fs;
  try {
    fs.open(path, cv::FileStorage::READ);
  } catch (const cv::Exception& e) {
    throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': " + e.what());
  }
  if (!fs.isOpened()) throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': cannot open");
  cv::Mat gain;
  fs["gain"] >> gain;
  if (gain.empty()) throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': no matrix 'gain'");
  if (gain.cols != camera.K.width || gain.rows != camera.K.height || gain.channels() != 1) {
    throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': 'gain' is " +
                                std::to_string(gain.cols) + "x" + std::to_string(gain.rows) + ", the camera " +
                                std::to_string(camera.K.width) + "x" + std::to_string(camera.K.height));
  }
  cv::Mat g64;
  gain.convertTo(g64, CV_64F);
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(g64, &lo, &hi);
  if (!(hi > 0.0) || !std::isfinite(hi) || !std::isfinite(lo) || lo < 0.0)
    throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': 'gain' must be >= 0 and not all 0");
  // Through the same resampling (and blur) as the images: 8 bits with the maximum at 250.
  cv::Mat g8;
  g64.convertTo(g8, CV_8U, 250.0 / hi);
  PreprocessParams pp = preprocess;
  pp.normalize_brightness = false;
  ImagePreprocessor pre(camera, pp);
  PreprocessedFrame f;
  pre.process(g8, 0.0, &f);
  cv::Mat out = f.intensity.clone();
  std::vector<float> v(out.begin<float>(), out.end<float>());
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  if (!(*mid > 0.f)) throw std::invalid_argument("fixed_pattern/vignetting_file '" + path + "': median gain 0");
  out *= 1.0 / *mid;
  return out;
}

}  // namespace diekf
