#include "dot_detector.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "morphology.h"

namespace diekf {
namespace internal {

namespace {
void ensureBytes(cv::Mat& m, int rows, int cols) {
  if (m.rows != rows || m.cols != cols || m.type() != CV_8UC1 || !m.isContinuous()) m.create(rows, cols, CV_8UC1);
}
}  // namespace

void DotDetector::configure(int width, int height, int element_px, double contrast, double min_share) {
  if (!fits(width, height)) {
    throw std::invalid_argument("DotDetector: image of " + std::to_string(width) + "x" + std::to_string(height) +
                                " px too small");
  }
  if (element_px < 3 || element_px % 2 == 0 || element_px > 31) {
    throw std::invalid_argument("DotDetector: element side " + std::to_string(element_px) +
                                " px is not odd in [3, 31]");
  }
  if (!(contrast > 0.0 && contrast <= 10.0)) throw std::invalid_argument("DotDetector: contrast not in (0, 10]");
  if (!(min_share > 0.0 && min_share < 1.0)) throw std::invalid_argument("DotDetector: share not in (0, 1)");
  width_ = width;
  height_ = height;
  radius_ = element_px / 2;
  border_ = radius_ + 1;
  contrast_q8_ = static_cast<int>(std::lround(contrast * 256.0));
  min_share_ = min_share;
  motion_px_ = kMotionElements * element_px;
  step_px_ = element_px + 2.0;
  ensureBytes(opened_, height, width);
  ensureBytes(scratch_a_, height, width);
  ensureBytes(scratch_b_, height, width);
  ensureBytes(copy_, height, width);
  ensureBytes(fixed_, height, width);
  // Tiles, and blocks made of whole tiles.
  tiles_x_ = (width + kTilePx - 1) / kTilePx;
  tiles_y_ = (height + kTilePx - 1) / kTilePx;
  const size_t tiles = static_cast<size_t>(tiles_x_) * static_cast<size_t>(tiles_y_);
  tile_chance_.assign(tiles, 1.0);
  tile_q_.assign(tiles, 1.0);
  tile_block_.assign(tiles, 0);
  for (int by = 0; by < kBlocksY; ++by) {
    for (int bx = 0; bx < kBlocksX; ++bx) {
      Block& b = blocks_[static_cast<size_t>(by * kBlocksX + bx)];
      const int tx0 = tiles_x_ * bx / kBlocksX, tx1 = tiles_x_ * (bx + 1) / kBlocksX;
      const int ty0 = tiles_y_ * by / kBlocksY, ty1 = tiles_y_ * (by + 1) / kBlocksY;
      b.x0 = tx0 * kTilePx;
      b.x1 = std::min(width, tx1 * kTilePx);
      b.y0 = ty0 * kTilePx;
      b.y1 = std::min(height, ty1 * kTilePx);
      for (int ty = ty0; ty < ty1; ++ty)
        for (int tx = tx0; tx < tx1; ++tx) tile_block_[static_cast<size_t>(ty * tiles_x_ + tx)] = by * kBlocksX + bx;
    }
  }
  armed_ = true;
  samples_ = 0;
  share_ = 0.0;
  restartMotion();
}

Vec2 DotDetector::blockCentre(int b) const {
  const Block& k = blocks_[static_cast<size_t>(b)];
  return Vec2(0.5 * (k.x0 + k.x1 - 1), 0.5 * (k.y0 + k.y1 - 1));
}

bool DotDetector::independent(const Block& b) const {
  for (int i = 0; i < b.count; ++i) {
    if ((b.position - b.samples[static_cast<size_t>(i)]).cwiseAbs().maxCoeff() < step_px_) return false;
  }
  return b.count < kMaxSamples;
}

bool DotDetector::resolved(const Block& b) const {
  if (b.count <= kStableSamples) return false;
  Vec2 lo = b.samples[0], hi = b.samples[0];
  for (int i = 1; i < b.count; ++i) {
    lo = lo.cwiseMin(b.samples[static_cast<size_t>(i)]);
    hi = hi.cwiseMax(b.samples[static_cast<size_t>(i)]);
  }
  const Eigen::Array2d span = (hi - lo).array() - 2.0 * b.uncertainty.array();
  return (span >= motion_px_).all() || span.maxCoeff() >= kStraightFactor * motion_px_;
}

bool DotDetector::wantsImage() const {
  if (!armed_ || samples_ >= kMaxSamples) return false;
  for (const Block& b : blocks_)
    if (independent(b)) return true;
  return false;
}

double DotDetector::fixedShare(const std::array<bool, kBlocks>& use) const {
  size_t count = 0, area = 0;
  for (int i = 0; i < kBlocks; ++i) {
    if (!use[static_cast<size_t>(i)]) continue;
    const Block& b = blocks_[static_cast<size_t>(i)];
    const int x0 = std::max(b.x0, border_), x1 = std::min(b.x1, width_ - border_);
    const int y0 = std::max(b.y0, border_), y1 = std::min(b.y1, height_ - border_);
    if (x1 <= x0 || y1 <= y0) continue;
    for (int y = y0; y < y1; ++y) {
      const uint8_t* row = fixed_.ptr<uint8_t>(y);
      for (int x = x0; x < x1; ++x) count += row[x] != 0;
    }
    area += static_cast<size_t>(x1 - x0) * static_cast<size_t>(y1 - y0);
  }
  return area > 0 ? static_cast<double>(count) / static_cast<double>(area) : 0.0;
}

void DotDetector::addImage(const cv::Mat& grey) {
  if (!armed_ || samples_ >= kMaxSamples) return;
  if (grey.type() != CV_8UC1 || grey.cols != width_ || grey.rows != height_) {
    throw std::invalid_argument("DotDetector::addImage: expected an 8-bit grey image of the configured size");
  }
  const uint8_t* src = grey.data;
  if (!grey.isContinuous()) {  // (the opening reads rows contiguously)
    grey.copyTo(copy_);
    src = copy_.data;
  }
  openSquare(src, opened_.data, scratch_a_.data, scratch_b_.data, width_, height_, radius_);
  // Speck where I - O > contrast O + floor, in 1/256 grey levels (integers: the same on every platform), or where
  // the pixel is saturated above its surroundings (a dot on bright ground is clipped below that contrast).
  uint8_t* speck = scratch_a_.data;
  const uint8_t* o = opened_.data;
  const int floor_q8 = kNoiseFloorGrey * 256;
  const size_t n = static_cast<size_t>(width_) * static_cast<size_t>(height_);
  for (size_t i = 0; i < n; ++i) {
    const int top = (static_cast<int>(src[i]) - static_cast<int>(o[i])) * 256;
    speck[i] = top > contrast_q8_ * static_cast<int>(o[i]) + floor_q8 || (src[i] == 255 && top > floor_q8) ? 255 : 0;
  }
  dilateSquare(speck, speck, scratch_b_.data, width_, height_, 1);
  // The sample's speck share per tile (counted into tile_chance_ by notePosition where it is independent).
  std::fill(tile_q_.begin(), tile_q_.end(), 0.0);
  for (int y = 0; y < height_; ++y) {
    const uint8_t* row = speck + static_cast<size_t>(y) * static_cast<size_t>(width_);
    double* q = tile_q_.data() + static_cast<size_t>((y / kTilePx) * tiles_x_);
    for (int x = 0; x < width_; ++x) q[x / kTilePx] += row[x] != 0 ? 1.0 : 0.0;
  }
  for (int ty = 0; ty < tiles_y_; ++ty) {
    const int th = std::min(kTilePx, height_ - ty * kTilePx);
    for (int tx = 0; tx < tiles_x_; ++tx) {
      const int tw = std::min(kTilePx, width_ - tx * kTilePx);
      tile_q_[static_cast<size_t>(ty * tiles_x_ + tx)] /= static_cast<double>(tw * th);
    }
  }
  if (samples_ == 0) {
    std::copy(speck, speck + n, fixed_.data);
  } else {
    uint8_t* f = fixed_.data;
    for (size_t i = 0; i < n; ++i) f[i] = std::min(f[i], speck[i]);
  }
  std::array<bool, kBlocks> all;
  all.fill(true);
  share_history_[static_cast<size_t>(samples_)] = fixedShare(all);
  ++samples_;
  pending_position_ = true;
}

void DotDetector::addMotion(const std::array<Vec2, kBlocks>& shift_px, const std::array<Vec2, kBlocks>& sigma_px) {
  if (!armed_) return;
  double worst = 0.0;
  for (int i = 0; i < kBlocks; ++i) {
    const Vec2& s = shift_px[static_cast<size_t>(i)];
    const Vec2& e = sigma_px[static_cast<size_t>(i)];
    if (!s.allFinite() || !e.allFinite()) {
      restartMotion();
      return;
    }
    Block& b = blocks_[static_cast<size_t>(i)];
    b.position += s;
    b.uncertainty = (b.uncertainty.cwiseProduct(b.uncertainty) + e.cwiseProduct(e)).cwiseSqrt();
    worst = std::max(worst, b.uncertainty.maxCoeff());
  }
  // The positions' span must exceed the motion by twice the accumulated 1-sigma: once that alone takes half the
  // motion, the positions start again (the filter is not converged yet; M keeps what it has).
  if (worst > 0.25 * motion_px_) restartMotion();
}

void DotDetector::notePosition(bool known) {
  if (!armed_ || !pending_position_) return;
  pending_position_ = false;
  if (!known) return;
  std::array<bool, kBlocks> counted;
  for (int i = 0; i < kBlocks; ++i) {
    Block& b = blocks_[static_cast<size_t>(i)];
    counted[static_cast<size_t>(i)] = independent(b);
    if (counted[static_cast<size_t>(i)]) b.samples[static_cast<size_t>(b.count++)] = b.position;
  }
  for (size_t t = 0; t < tile_chance_.size(); ++t)
    if (counted[static_cast<size_t>(tile_block_[t])]) tile_chance_[t] *= tile_q_[t];
}

void DotDetector::restartMotion() {
  for (Block& b : blocks_) {
    b.position.setZero();
    b.uncertainty.setZero();
    b.count = 0;
  }
  std::fill(tile_chance_.begin(), tile_chance_.end(), 1.0);
  pending_position_ = false;
}

DotDetector::Verdict DotDetector::decide() {
  if (!armed_ || samples_ <= kStableSamples) return Verdict::kUndecided;
  // Every dot is in every sample: fewer fixed specks than the share are no dots (M only ever shrinks).
  const double whole = share_history_[static_cast<size_t>(samples_ - 1)];
  if (whole < min_share_ || (samples_ >= kMaxSamples && !pending_position_)) {
    share_ = whole;
    armed_ = false;
    return Verdict::kNoDots;
  }
  std::array<bool, kBlocks> use;
  size_t resolved_area = 0;
  for (int i = 0; i < kBlocks; ++i) {
    const Block& b = blocks_[static_cast<size_t>(i)];
    use[static_cast<size_t>(i)] = resolved(b);
    if (use[static_cast<size_t>(i)]) resolved_area += static_cast<size_t>(b.x1 - b.x0) * static_cast<size_t>(b.y1 - b.y0);
  }
  if (2 * resolved_area < static_cast<size_t>(width_) * static_cast<size_t>(height_)) {
    share_ = whole;
    return Verdict::kUndecided;
  }
  double chance = 0.0;
  for (int ty = 0; ty < tiles_y_; ++ty) {
    const int th = std::min(kTilePx, height_ - ty * kTilePx);
    for (int tx = 0; tx < tiles_x_; ++tx) {
      const size_t t = static_cast<size_t>(ty * tiles_x_ + tx);
      if (!use[static_cast<size_t>(tile_block_[t])]) continue;
      chance += tile_chance_[t] * std::min(kTilePx, width_ - tx * kTilePx) * th;
    }
  }
  chance /= static_cast<double>(resolved_area);
  share_ = fixedShare(use);
  if (chance > 0.1 * min_share_ || share_ < min_share_) return Verdict::kUndecided;
  const double earlier = share_history_[static_cast<size_t>(samples_ - 1 - kStableSamples)];
  if (whole < kStableFraction * earlier) return Verdict::kUndecided;  // still falling: chance agreements
  armed_ = false;
  return Verdict::kDots;
}

}  // namespace internal
}  // namespace diekf
