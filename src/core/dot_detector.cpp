#include "dot_detector.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "morphology.h"

#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace internal {

namespace {
void ensureBytes(cv::Mat& m, int rows, int cols) {
  if (m.rows != rows || m.cols != cols || m.type() != CV_8UC1 || !m.isContinuous()) m.create(rows, cols, CV_8UC1);
}
}  // namespace

void speckLevels(const uint8_t* src, const uint8_t* opened, size_t n, const int* contrast_q8, int levels,
                 uint8_t* out) {
  // A speck where I - O > contrast O + floor, or where I is saturated and I - O > floor; the levels passed
  // counted. Exact integer arithmetic (the same on every platform): with the contrast in 1/256,
  // c = 256 c_hi + c_lo, 256 (I - O) > c O + 256 floor holds exactly when I - O > c_hi O + ((c_lo O) >> 8) + floor
  // (I - O is an integer; O <= I for an opening).
  size_t i = 0;
  {
    using namespace cv;
    const v_uint16x8 vfloor = v_setall_u16(static_cast<uint16_t>(DotDetector::kNoiseFloorGrey));
    const v_uint8x16 v255 = v_setall_u8(255), vlevels = v_setall_u8(static_cast<uint8_t>(levels));
    const v_uint8x16 one = v_setall_u8(1);
    for (; i + 16 <= n; i += 16) {
      const v_uint8x16 vi = v_load(src + i), vo = v_load(opened + i);
      v_uint16x8 i0, i1, o0, o1;
      v_expand(vi, i0, i1);
      v_expand(vo, o0, o1);
      const v_uint16x8 t0 = i0 - o0, t1 = i1 - o1;
      v_uint8x16 count = v_setzero_u8();
      for (int l = 0; l < levels; ++l) {
        const v_uint16x8 vhi = v_setall_u16(static_cast<uint16_t>(contrast_q8[l] >> 8));
        const v_uint16x8 vlo = v_setall_u16(static_cast<uint16_t>(contrast_q8[l] & 255));
        const v_uint16x8 thr0 = v_mul_wrap(o0, vhi) + v_shr<8>(v_mul_wrap(o0, vlo)) + vfloor;
        const v_uint16x8 thr1 = v_mul_wrap(o1, vhi) + v_shr<8>(v_mul_wrap(o1, vlo)) + vfloor;
        count = count + (v_pack(v_reinterpret_as_u16(t0 > thr0), v_reinterpret_as_u16(t1 > thr1)) & one);
      }
      const v_uint8x16 above = v_pack(v_reinterpret_as_u16(t0 > vfloor), v_reinterpret_as_u16(t1 > vfloor));
      v_store(out + i, v_max(count, (vi == v255) & above & vlevels));
    }
  }
  for (; i < n; ++i) {
    const int top = static_cast<int>(src[i]) - static_cast<int>(opened[i]);
    int count = 0;
    for (int l = 0; l < levels; ++l) {
      const int c_hi = contrast_q8[l] >> 8, c_lo = contrast_q8[l] & 255;
      count += top > c_hi * opened[i] + ((c_lo * opened[i]) >> 8) + DotDetector::kNoiseFloorGrey;
    }
    out[i] = static_cast<uint8_t>(src[i] == 255 && top > DotDetector::kNoiseFloorGrey ? levels : count);
  }
}

void speckMask(const uint8_t* src, const uint8_t* opened, size_t n, int contrast_q8, uint8_t* out) {
  speckLevels(src, opened, n, &contrast_q8, 1, out);
  for (size_t i = 0; i < n; ++i) out[i] = static_cast<uint8_t>(-static_cast<int>(out[i]));  // 1 -> 255
}

void DotDetector::configure(int width, int height, int element_px, double contrast, double min_share, int levels) {
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
  if (levels < 1 || levels > kMaxLevels) throw std::invalid_argument("DotDetector: levels not in [1, 3]");
  width_ = width;
  height_ = height;
  radius_ = element_px / 2;
  min_share_ = min_share;
  motion_px_ = kMotionElements * element_px;
  step_px_ = element_px + 2.0;
  ensureBytes(opened_, height, width);
  ensureBytes(scratch_a_, height, width);
  ensureBytes(scratch_b_, height, width);
  ensureBytes(last_, height, width);
  ensureBytes(larger_, height, width);
  ensureBytes(blob_lowest_, height, width);
  blob_lowest_.setTo(255);
  blob_share_.fill(0.0);
  // Tiles, and blocks made of whole tiles.
  tiles_x_ = (width + kTilePx - 1) / kTilePx;
  tiles_y_ = (height + kTilePx - 1) / kTilePx;
  const size_t tiles = static_cast<size_t>(tiles_x_) * static_cast<size_t>(tiles_y_);
  n_levels_ = levels;
  level_ = 0;
  for (int l = 0; l < levels; ++l) {
    Level& L = levels_[static_cast<size_t>(l)];
    contrast_q8_[static_cast<size_t>(l)] = std::max(1, static_cast<int>(std::lround(std::ldexp(contrast, -l) * 256.0)));
    L.tile_chance.assign(tiles, 1.0);
    L.tile_q.assign(tiles, 1.0);
    L.tile_fixed.assign(tiles, 0);
  }
  for (cv::Mat& m : lowest_) {
    ensureBytes(m, height, width);
    m.setTo(255);  // (no sample yet: above every level)
  }
  tile_block_.assign(tiles, 0);
  tile_area_.assign(tiles, 0);
  for (int ty = 0; ty < tiles_y_; ++ty)
    for (int tx = 0; tx < tiles_x_; ++tx)
      tile_area_[static_cast<size_t>(ty * tiles_x_ + tx)] =
          std::min(kTilePx, width - tx * kTilePx) * std::min(kTilePx, height - ty * kTilePx);
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
  // (One sample at a time: images queued for the IMU would all look independent of the positions not yet noted.)
  if (!armed_ || samples_ >= kMaxSamples || pending_position_) return false;
  for (const Block& b : blocks_)
    if (independent(b)) return true;
  return false;
}

double DotDetector::fixedShare(const Level& L, const std::array<bool, kBlocks>& use) const {
  size_t count = 0, area = 0;
  for (size_t t = 0; t < tile_area_.size(); ++t) {
    if (!use[static_cast<size_t>(tile_block_[t])]) continue;
    count += static_cast<size_t>(L.tile_fixed[t]);
    area += static_cast<size_t>(tile_area_[t]);
  }
  return area > 0 ? static_cast<double>(count) / static_cast<double>(area) : 0.0;
}

void DotDetector::addImage(const cv::Mat& grey) {
  if (!armed_ || samples_ >= kMaxSamples) return;
  if (grey.type() != CV_8UC1 || grey.cols != width_ || grey.rows != height_) {
    throw std::invalid_argument("DotDetector::addImage: expected an 8-bit grey image of the configured size");
  }
  grey.copyTo(last_);  // kept for removalElement; contiguous rows for the opening whatever the input's stride
  const uint8_t* src = last_.data;
  const size_t n = static_cast<size_t>(width_) * static_cast<size_t>(height_);
  // Blobs: the specks above both the square's and the diamond's opening (in larger_), dilated, their lowest passes
  // over the samples, and per level the share of the pixels that were blobs in every sample.
  openSquare(src, opened_.data, scratch_a_.data, scratch_b_.data, width_, height_, radius_);
  openDiamond(src, larger_.data, scratch_a_.data, scratch_b_.data, width_, height_, radius_);
  uint8_t* both = larger_.data;
  uint8_t* blobs = scratch_a_.data;
  uint8_t* blob_lowest = blob_lowest_.data;
  {
    using namespace cv;
    size_t i = 0;
    for (; i + 16 <= n; i += 16) v_store(both + i, v_max(v_load(both + i), v_load(opened_.data + i)));
    for (; i < n; ++i) both[i] = std::max(both[i], opened_.data[i]);
    speckLevels(src, both, n, contrast_q8_.data(), n_levels_, blobs);
    dilateSquare(blobs, blobs, scratch_b_.data, width_, height_, 1);
    for (i = 0; i + 16 <= n; i += 16) v_store(blob_lowest + i, v_min(v_load(blob_lowest + i), v_load(blobs + i)));
    for (; i < n; ++i) blob_lowest[i] = std::min(blob_lowest[i], blobs[i]);
  }
  // Pixels per lowest level passed (0 .. levels after a sample), then per level those at or above it.
  std::array<size_t, kMaxLevels + 1> at_level{};
  for (size_t i = 0; i < n; ++i) ++at_level[std::min<size_t>(blob_lowest[i], kMaxLevels)];
  for (int l = 0; l < n_levels_; ++l) {
    size_t count = 0;
    for (int v = n_levels_ - l; v <= kMaxLevels; ++v) count += at_level[static_cast<size_t>(v)];
    blob_share_[static_cast<size_t>(l)] = static_cast<double>(count) / static_cast<double>(n);
  }
  // The passes of every level in one mask (a pixel passing level l passes every fainter one too), dilated: a pixel
  // is a (dilated) speck at level l when it holds at least levels - l.
  uint8_t* passes = scratch_a_.data;
  speckLevels(src, opened_.data, n, contrast_q8_.data(), n_levels_, passes);
  dilateSquare(passes, passes, scratch_b_.data, width_, height_, 1);
  // The three lowest passes over the samples, in order: M of level l is lowest >= levels - l, the pixels that
  // missed at most one or two samples the second and third lowest.
  uint8_t* m1 = lowest_[0].data;
  uint8_t* m2 = lowest_[1].data;
  uint8_t* m3 = lowest_[2].data;
  {
    size_t i = 0;
    using namespace cv;
    for (; i + 16 <= n; i += 16) {
      const v_uint8x16 v = v_load(passes + i), a = v_load(m1 + i), b = v_load(m2 + i), c = v_load(m3 + i);
      v_store(m3 + i, v_max(b, v_min(c, v)));
      v_store(m2 + i, v_max(a, v_min(b, v)));
      v_store(m1 + i, v_min(a, v));
    }
    for (; i < n; ++i) {
      const uint8_t v = passes[i], a = m1[i], b = m2[i], c = m3[i];
      m3[i] = std::max(b, std::min(c, v));
      m2[i] = std::max(a, std::min(b, v));
      m1[i] = std::min(a, v);
    }
  }
  // Per level and tile, the specks of this sample and the pixels in M. (Levels that said no dots are done with.)
  for (int l = level_; l < n_levels_; ++l) {
    Level& L = levels_[static_cast<size_t>(l)];
    std::fill(L.tile_q.begin(), L.tile_q.end(), 0.0);
    std::fill(L.tile_fixed.begin(), L.tile_fixed.end(), 0);
  }
  for (int y = 0; y < height_; ++y) {
    const size_t row = static_cast<size_t>(y) * static_cast<size_t>(width_);
    const size_t t0 = static_cast<size_t>((y / kTilePx) * tiles_x_);
    for (int tx = 0; tx < tiles_x_; ++tx) {
      const int x0 = tx * kTilePx, x1 = std::min(width_, x0 + kTilePx);
      for (int l = level_; l < n_levels_; ++l) {
        const uint8_t need = static_cast<uint8_t>(n_levels_ - l);
        unsigned specks = 0, fixed = 0;
        int x = x0;
        if (x1 - x0 == 16) {
          using namespace cv;
          const v_uint8x16 vneed = v_setall_u8(need), one = v_setall_u8(1);
          const v_uint8x16 sp = v_load(passes + row + x0) >= vneed, m = v_load(m1 + row + x0) >= vneed;
          v_uint16x8 a0, a1, b0, b1;
          v_expand(sp & one, a0, a1);
          v_expand(m & one, b0, b1);
          specks = v_reduce_sum(a0 + a1);
          fixed = v_reduce_sum(b0 + b1);
          x = x1;
        }
        for (; x < x1; ++x) {
          specks += passes[row + x] >= need;
          fixed += m1[row + x] >= need;
        }
        Level& L = levels_[static_cast<size_t>(l)];
        L.tile_q[t0 + tx] += specks;
        L.tile_fixed[t0 + tx] += static_cast<int>(fixed);
      }
    }
  }
  std::array<bool, kBlocks> all;
  all.fill(true);
  for (int l = level_; l < n_levels_; ++l) {
    Level& L = levels_[static_cast<size_t>(l)];
    for (size_t t = 0; t < L.tile_q.size(); ++t) L.tile_q[t] /= static_cast<double>(tile_area_[t]);
    L.share_history[static_cast<size_t>(samples_)] = fixedShare(L, all);
  }
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
  for (int l = level_; l < n_levels_; ++l) {
    Level& L = levels_[static_cast<size_t>(l)];
    for (size_t t = 0; t < L.tile_chance.size(); ++t)
      if (counted[static_cast<size_t>(tile_block_[t])]) L.tile_chance[t] *= L.tile_q[t];
  }
}

void DotDetector::restartMotion() {
  for (Block& b : blocks_) {
    b.position.setZero();
    b.uncertainty.setZero();
    b.count = 0;
  }
  for (Level& L : levels_) std::fill(L.tile_chance.begin(), L.tile_chance.end(), 1.0);
  pending_position_ = false;
}

DotDetector::Verdict DotDetector::decide() {
  if (!armed_ || samples_ <= kStableSamples) return Verdict::kUndecided;
  // A level's verdict of no dots hands over to the next, fainter one (which has seen every sample too).
  Verdict v = decideLevel();
  while (v == Verdict::kNoDots && level_ + 1 < n_levels_) {
    ++level_;
    armed_ = true;
    v = decideLevel();
  }
  return v;
}

DotDetector::Verdict DotDetector::decideLevel() {
  const Level& L = levels_[static_cast<size_t>(level_)];
  // Every dot is in every sample: fewer fixed specks than the share are no dots (M only ever shrinks).
  const double whole = wholeShare();
  if (whole < min_share_) {
    share_ = whole;
    armed_ = false;
    return Verdict::kNoDots;
  }
  if (samples_ >= kMaxSamples && !pending_position_) {
    share_ = whole;
    armed_ = false;  // the motion never qualified (or M never settled): no verdict, the learned pattern decides
    return Verdict::kUndecided;
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
  for (size_t t = 0; t < L.tile_chance.size(); ++t)
    if (use[static_cast<size_t>(tile_block_[t])]) chance += L.tile_chance[t] * tile_area_[t];
  chance /= static_cast<double>(resolved_area);
  share_ = fixedShare(L, use);
  if (chance > 0.1 * min_share_ || share_ < min_share_) return Verdict::kUndecided;
  const double earlier = L.share_history[static_cast<size_t>(samples_ - 1 - kStableSamples)];
  if (whole < kStableFraction * earlier) return Verdict::kUndecided;  // still falling: chance agreements
  armed_ = false;
  return Verdict::kDots;
}

int DotDetector::removalElement(int max_px) {
  int side = 2 * radius_ + 1;
  if (samples_ == 0) return side;
  const size_t n = static_cast<size_t>(width_) * static_cast<size_t>(height_);
  const uint8_t* img = last_.data;
  const uint8_t* lowest = lowest_[0].data;
  const uint8_t need = static_cast<uint8_t>(n_levels_ - level_);
  // opened_ holds the last sample's opening by `side` (addImage); the next larger one goes to larger_.
  uint8_t* cur = opened_.data;
  uint8_t* next = larger_.data;
  for (; side + 2 <= max_px; side += 2) {
    openSquare(img, next, scratch_a_.data, scratch_b_.data, width_, height_, (side + 1) / 2);
    uint64_t sum_dots = 0, sum_ground = 0, n_dots = 0;
    for (size_t i = 0; i < n; ++i) {
      const unsigned d = static_cast<unsigned>(cur[i] - next[i]);  // (openings shrink with the element)
      if (lowest[i] >= need) {
        sum_dots += d;
        ++n_dots;
      } else {
        sum_ground += d;
      }
    }
    if (n_dots == 0 || n_dots == n) break;
    const double excess = static_cast<double>(sum_dots) / static_cast<double>(n_dots) -
                          static_cast<double>(sum_ground) / static_cast<double>(n - n_dots);
    if (excess < kRemnantGrey) break;
    std::swap(cur, next);
  }
  return side;
}

double DotDetector::fillMask(cv::Mat* mask, int misses) {
  if (mask == nullptr) throw std::invalid_argument("DotDetector::fillMask: null mask");
  ensureBytes(*mask, height_, width_);
  if (width_ == 0) return 0.0;
  const size_t n = static_cast<size_t>(width_) * static_cast<size_t>(height_);
  uint8_t* m = mask->data;
  if (samples_ == 0) {
    std::fill(m, m + n, uint8_t{0});
    return 0.0;
  }
  // M is the pixels that were specks in every sample (the lowest passes); a dot may miss a sample's speck test
  // (weak, on bright ground), so with `misses` the pixels that missed at most that many are taken too (the second or
  // third lowest; while there are no more samples than misses, one is enough: the highest).
  const int rank = std::clamp(std::min(misses, samples_ - 1), 0, kFillMisses);
  const uint8_t* lowest = lowest_[static_cast<size_t>(rank)].data;
  const uint8_t need = static_cast<uint8_t>(n_levels_ - level_);
  for (size_t i = 0; i < n; ++i) m[i] = lowest[i] >= need ? 255 : 0;
  const uint8_t* img = last_.data;
  uint8_t* grown = larger_.data;
  for (int ring = 0; ring < kMaxFillGrowth; ++ring) {
    dilateSquare(m, grown, scratch_a_.data, width_, height_, 1);
    uint64_t sum_ring = 0, n_ring = 0, sum_out = 0, n_out = 0;
    for (size_t i = 0; i < n; ++i) {
      if (grown[i] == 0) {
        sum_out += img[i];
        ++n_out;
      } else if (m[i] == 0) {
        sum_ring += img[i];
        ++n_ring;
      }
    }
    if (n_ring == 0 || n_out == 0) break;
    const double excess = static_cast<double>(sum_ring) / static_cast<double>(n_ring) -
                          static_cast<double>(sum_out) / static_cast<double>(n_out);
    if (excess < kFillTailFraction * static_cast<double>(sum_out) / static_cast<double>(n_out)) break;
    std::copy(grown, grown + n, m);
  }
  size_t lit = 0;
  for (size_t i = 0; i < n; ++i) lit += m[i] != 0;
  return static_cast<double>(lit) / static_cast<double>(n);
}

}  // namespace internal
}  // namespace diekf
