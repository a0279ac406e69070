#include "dot_gain.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "morphology.h"

#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace internal {

void divideByGain(const uint8_t* src, const uint16_t* inv_q12, size_t n, uint8_t* out) {
  // round(x inv / 4096) = floor(q + 1/2) with q = x inv / 4096 equals (floor(2 q) + 1) >> 1, and floor(2 q) is the high
  // half of (32 x) inv: one 16-bit multiply-high per pixel (32 x <= 8160; floor(2 q) <= 4080, no overflow).
  size_t i = 0;
  {
    using namespace cv;
    const v_uint16x8 one = v_setall_u16(1);
    for (; i + 16 <= n; i += 16) {
      v_uint16x8 a0, a1;
      v_expand(v_load(src + i), a0, a1);
      const v_uint16x8 t0 = v_mul_hi(v_shl<5>(a0), v_load(inv_q12 + i));
      const v_uint16x8 t1 = v_mul_hi(v_shl<5>(a1), v_load(inv_q12 + i + 8));
      v_store(out + i, v_pack(v_shr<1>(t0 + one), v_shr<1>(t1 + one)));  // (saturating: at most 255)
    }
  }
  for (; i < n; ++i) {
    const uint32_t twice = (static_cast<uint32_t>(src[i]) * 32u * inv_q12[i]) >> 16;
    out[i] = static_cast<uint8_t>(std::min<uint32_t>((twice + 1u) >> 1, 255u));
  }
}

void DotGainLearner::start(const cv::Mat& fill_mask) {
  if (fill_mask.empty() || fill_mask.type() != CV_8UC1 || fill_mask.dims != 2) {
    throw std::invalid_argument("DotGainLearner::start: expected a CV_8UC1 mask");
  }
  width_ = fill_mask.cols;
  height_ = fill_mask.rows;
  grid_cols_ = (width_ - 1) / kGridPx + 2;
  grid_rows_ = (height_ - 1) / kGridPx + 2;
  cv::Mat mask01(height_, width_, CV_8UC1), scratch(height_, width_, CV_8UC1);
  for (int y = 0; y < height_; ++y) {
    const uint8_t* m = fill_mask.ptr<uint8_t>(y);
    uint8_t* o = mask01.ptr<uint8_t>(y);
    for (int x = 0; x < width_; ++x) o[x] = m[x] != 0 ? 1 : 0;
  }
  region_.create(height_, width_, CV_8UC1);
  dilateSquare(mask01.data, region_.data, scratch.data, width_, height_, kRegionRingsPx);
  inv_gain_.create(height_, width_, CV_32FC1);
  inv_gain_.setTo(1.0f);
  known_.create(height_, width_, CV_8UC1);
  for (int i = 0; i < width_ * height_; ++i) known_.data[i] = region_.data[i] != 0 ? 0 : 1;
  at_.clear();
  row_start_.assign(static_cast<size_t>(height_) + 1, 0);
  for (int y = 0; y < height_; ++y) {
    row_start_[static_cast<size_t>(y)] = static_cast<int32_t>(at_.size());
    for (int x = 0; x < width_; ++x)
      if (region_.at<uint8_t>(y, x) != 0) at_.push_back(y * width_ + x);
  }
  row_start_[static_cast<size_t>(height_)] = static_cast<int32_t>(at_.size());
  sum_cur_.assign(at_.size(), 0.f);
  sum_ref_.assign(at_.size(), 0.f);
  samples_.assign(at_.size(), 0);
  clipped_.assign(at_.size(), 0);
  grid_.assign(static_cast<size_t>(grid_cols_) * static_cast<size_t>(grid_rows_), Vec2::Zero());
  row_map_.assign(2 * static_cast<size_t>(grid_cols_), 0.f);
  pairs_ = 0;
  learned_ = 0;
  learning_ = true;
}

void DotGainLearner::stop() {
  learning_ = false;
  std::vector<int32_t>().swap(at_);
  std::vector<float>().swap(sum_cur_);
  std::vector<float>().swap(sum_ref_);
  std::vector<uint16_t>().swap(samples_);
  std::vector<uint16_t>().swap(clipped_);
  region_.release();
  inv_gain_.release();
  std::vector<int32_t>().swap(row_start_);
  known_.release();
}

double DotGainLearner::regionShare() const {
  return width_ > 0 ? static_cast<double>(at_.size()) / (static_cast<double>(width_) * height_) : 0.0;
}

bool DotGainLearner::ready() const {
  if (!learning_) return false;
  const double share = readyShare();
  return share >= kReadyShare || (pairs_ >= kMaxPairs && share >= kMinReadyShare);
}

double DotGainLearner::readyShare() const {
  return at_.empty() ? 0.0 : static_cast<double>(learned_) / static_cast<double>(at_.size());
}

void DotGainLearner::observe(const uint8_t* cur, const uint8_t* ref) {
  if (!learning_ || at_.empty()) return;
  const uint8_t* region = region_.data;
  const uint8_t* known = known_.data;
  float* inv_gain = reinterpret_cast<float*>(inv_gain_.data);
  const int w = width_, h = height_;
  // The map at row y, interpolated between grid rows (the grid's points are kGridPx apart; the last row and
  // column lie at or beyond the image's edge).
  auto prepareRow = [&](int y) {
    const int gy = y / kGridPx;
    const float fy = static_cast<float>(y - gy * kGridPx) / kGridPx;
    const Vec2* a = &grid_[static_cast<size_t>(gy) * static_cast<size_t>(grid_cols_)];
    const Vec2* b = a + grid_cols_;
    for (int i = 0; i < grid_cols_; ++i) {
      row_map_[2 * static_cast<size_t>(i)] = static_cast<float>((1.0f - fy) * a[i].x() + fy * b[i].x());
      row_map_[2 * static_cast<size_t>(i) + 1] = static_cast<float>((1.0f - fy) * a[i].y() + fy * b[i].y());
    }
  };
  // The ground's brightness in the reference where pixel x of the prepared row lands: bilinear over four pixels
  // whose gain is known (outside the region, or learned already) and not saturated, each divided by its gain;
  // negative when there is none.
  auto sample = [&](int x) -> float {
    const int gx = x / kGridPx;
    const float fx = static_cast<float>(x - gx * kGridPx) / kGridPx;
    const float* m = &row_map_[2 * static_cast<size_t>(gx)];
    const float u = (1.0f - fx) * m[0] + fx * m[2];
    const float v = (1.0f - fx) * m[1] + fx * m[3];
    if (!(u >= 0.0f && v >= 0.0f && u < static_cast<float>(w - 1) && v < static_cast<float>(h - 1))) return -1.0f;
    const int x0 = static_cast<int>(u), y0 = static_cast<int>(v);
    const int i = y0 * w + x0;
    if ((known[i] & known[i + 1] & known[i + w] & known[i + w + 1]) == 0) return -1.0f;
    const int p00 = ref[i], p01 = ref[i + 1], p10 = ref[i + w], p11 = ref[i + w + 1];
    if (std::max(std::max(p00, p01), std::max(p10, p11)) >= 255) return -1.0f;
    const float ax = u - static_cast<float>(x0), ay = v - static_cast<float>(y0);
    return (1.0f - ay) * ((1.0f - ax) * static_cast<float>(p00) * inv_gain[i] +
                          ax * static_cast<float>(p01) * inv_gain[i + 1]) +
           ay * ((1.0f - ax) * static_cast<float>(p10) * inv_gain[i + w] +
                 ax * static_cast<float>(p11) * inv_gain[i + w + 1]);
  };
  // The pair's brightness ratio away from the dots (every fourth pixel of every fourth row outside the region).
  double sum_c = 0.0, sum_r = 0.0;
  int n = 0;
  for (int y = 0; y < h; y += 4) {
    prepareRow(y);
    for (int x = 0; x < w; x += 4) {
      const int i = y * w + x;
      if (region[i] != 0 || cur[i] >= 255 || cur[i] < kMinGrey) continue;
      const float r = sample(x);  // (mostly away from the region too)
      if (r < kMinGrey) continue;
      sum_c += cur[i];
      sum_r += r;
      ++n;
    }
  }
  if (n < 100 || !(sum_r > 0.0)) return;  // the pair sees too little of the ground away from the dots
  const float ratio = static_cast<float>(sum_c / sum_r);
  for (int y = 0; y < h; ++y) {
    const size_t k0 = static_cast<size_t>(row_start_[static_cast<size_t>(y)]);
    const size_t k1 = static_cast<size_t>(row_start_[static_cast<size_t>(y) + 1]);
    if (k0 == k1) continue;
    prepareRow(y);
    for (size_t k = k0; k < k1; ++k) {
      if (samples_[k] >= kMinSamples) continue;  // learned (its gain serves its neighbours from now on)
      const int i = at_[k];
      const int c = cur[i];
      if (c < kMinGrey) continue;
      const float r = sample(i - y * w);
      if (r < kMinGrey) continue;
      if (c >= 255) {
        if (clipped_[k] < UINT16_MAX) ++clipped_[k];
        continue;
      }
      sum_cur_[k] += static_cast<float>(c);
      sum_ref_[k] += ratio * r;
      if (++samples_[k] == kMinSamples) {
        // Learned: the pixels whose reference samples land here use it from now on.
        inv_gain[i] = std::clamp(sum_ref_[k] / sum_cur_[k], static_cast<float>(1.0 / kMaxGain),
                                 static_cast<float>(kMaxGain));
        known_.data[i] = 1;
        ++learned_;
      }
    }
  }
  ++pairs_;
}

double DotGainLearner::gainAt(int x, int y) const {
  if (x < 0 || y < 0 || x >= width_ || y >= height_ || region_.empty()) return 1.0;
  const int i = y * width_ + x;
  if (region_.data[i] == 0) return 1.0;
  const size_t k = static_cast<size_t>(std::lower_bound(at_.begin(), at_.end(), i) - at_.begin());
  return samples_[k] > 0 && sum_ref_[k] > 0.f ? static_cast<double>(sum_cur_[k] / sum_ref_[k]) : 0.0;
}

double DotGainLearner::result(cv::Mat* inv_gain_q12, cv::Mat* core) const {
  if (inv_gain_q12 == nullptr || core == nullptr) throw std::invalid_argument("DotGainLearner::result: null output");
  inv_gain_q12->create(height_, width_, CV_16UC1);
  inv_gain_q12->setTo(4096);
  core->create(height_, width_, CV_8UC1);
  core->setTo(0);
  if (width_ == 0) return 0.0;
  size_t filled = 0;
  for (size_t k = 0; k < at_.size(); ++k) {
    const int i = at_[k];
    const double g = sum_ref_[k] > 0.f ? static_cast<double>(sum_cur_[k] / sum_ref_[k]) : 0.0;
    const bool enough = samples_[k] >= kMinSamples;
    const bool clips = static_cast<double>(clipped_[k]) > kCoreClipShare * (samples_[k] + clipped_[k]);
    if (!enough || clips || g > kCoreGain || !(g > 0.0)) {
      core->data[i] = 255;
      ++filled;
      continue;
    }
    const double gain = std::clamp(g, 1.0 / kMaxGain, kMaxGain);
    reinterpret_cast<uint16_t*>(inv_gain_q12->data)[i] = static_cast<uint16_t>(std::lround(4096.0 / gain));
  }
  return static_cast<double>(filled) / (static_cast<double>(width_) * height_);
}

}  // namespace internal
}  // namespace diekf
