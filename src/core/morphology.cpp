#include "morphology.h"

#include <algorithm>
#include <cstddef>
#include <type_traits>

#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace internal {
namespace {

/// The smaller (kMax false) or larger (kMax true) of two bytes, one or sixteen at a time.
template <bool kMax>
uint8_t rank(uint8_t a, uint8_t b) {
  return kMax ? std::max(a, b) : std::min(a, b);
}
template <bool kMax>
cv::v_uint8x16 rank(const cv::v_uint8x16& a, const cv::v_uint8x16& b) {
  return kMax ? cv::v_max(a, b) : cv::v_min(a, b);
}

/// Rank of the 2 R + 1 vectors of 16 bytes at p, p + step, ..., p + 2 R step (R known at compile time: the loop
/// unrolled).
template <bool kMax, int R>
cv::v_uint8x16 rankVectors(const uint8_t* p, size_t step) {
  cv::v_uint8x16 v = cv::v_load(p);
  for (int j = 1; j <= 2 * R; ++j) v = rank<kMax>(v, cv::v_load(p + j * step));
  return v;
}

/// Running minimum (kMax false) or maximum (kMax true) over [i - r, i + r] of a row of n bytes, the window clipped
/// at the ends (what lies outside does not count, as in OpenCV's morphology). src and dst must not overlap.
/// R: r at compile time (1-4).
template <bool kMax, int R>
void rankRow(const uint8_t* src, uint8_t* dst, int n, int r) {
  auto scalar = [&](int x) {
    uint8_t v = src[x];
    for (int j = std::max(0, x - r); j <= std::min(n - 1, x + r); ++j) v = rank<kMax>(v, src[j]);
    dst[x] = v;
  };
  int x = 0;
  for (; x < std::min(r, n); ++x) scalar(x);
  const int last = n - r - 16;  // the last start of a whole window of 16 outputs
  for (; x <= last; x += 16) cv::v_store(dst + x, rankVectors<kMax, R>(src + x - r, 1));
  if (x > r && x < n - r && last >= r) {
    // The rest of the interior as one more window ending at the last interior output (overlapping the previous).
    cv::v_store(dst + last, rankVectors<kMax, R>(src + last - r, 1));
    x = n - r;
  }
  for (; x < n; ++x) scalar(x);
}

/// The same down the columns: row y of dst from the rows y - r .. y + r of src (clipped), w bytes each.
template <bool kMax, int R>
void rankColumns(const uint8_t* src, uint8_t* dst, int w, int h, int r) {
  const size_t step = static_cast<size_t>(w);
  for (int y = 0; y < h; ++y) {
    const int y0 = std::max(0, y - r), y1 = std::min(h - 1, y + r);
    uint8_t* out = dst + static_cast<size_t>(y) * step;
    const uint8_t* first = src + static_cast<size_t>(y0) * step;
    const bool whole = y0 == y - r && y1 == y + r;
    int x = 0;
    for (; x + 16 <= w; x += 16) {
      if (whole) {
        cv::v_store(out + x, rankVectors<kMax, R>(first + x, step));
      } else {
        cv::v_uint8x16 v = cv::v_load(first + x);
        for (int yy = y0 + 1; yy <= y1; ++yy) v = rank<kMax>(v, cv::v_load(src + static_cast<size_t>(yy) * step + x));
        cv::v_store(out + x, v);
      }
    }
    for (; x < w; ++x) {
      uint8_t v = first[x];
      for (int yy = y0 + 1; yy <= y1; ++yy) v = rank<kMax>(v, src[static_cast<size_t>(yy) * step + x]);
      out[x] = v;
    }
  }
}

// Larger windows by doubling: with L_s[i] the rank over [i, i + s - 1] (clipped at the end), L_2s[i] = rank(L_s[i],
// L_s[i + s]); a window of W <= 2 S elements starting at i is rank(L_S[i], L_S[i + W - S]). About log2(W) + 1
// passes instead of W - 1 comparisons per element.

/// The doubling's last level S for a window of `width` elements: the least power of two with 2 S >= width.
int doublingSpan(int width) {
  int span = 1;
  while (2 * span < width) span *= 2;
  return span;
}

/// In place: v[i] becomes the rank of v[i .. i + span - 1] (clipped at n), through the levels 2, 4, .., span.
/// Each level reads ahead of what it writes, so increasing i sees the previous level's values.
template <bool kMax>
void doubleInPlace(uint8_t* v, int n, int span, int first_level = 1) {
  for (int s = first_level; s < span; s *= 2) {
    int i = 0;
    for (; i + s + 16 <= n; i += 16) cv::v_store(v + i, rank<kMax>(cv::v_load(v + i), cv::v_load(v + i + s)));
    for (; i + s < n; ++i) v[i] = rank<kMax>(v[i], v[i + s]);
  }
}

/// rankRow for r > 4 by doubling in dst (src and dst must not overlap).
template <bool kMax>
void rankRowDoubling(const uint8_t* src, uint8_t* dst, int n, int r) {
  auto clipped = [&](int x) {
    uint8_t v = src[x];
    for (int j = std::max(0, x - r); j <= std::min(n - 1, x + r); ++j) v = rank<kMax>(v, src[j]);
    dst[x] = v;
  };
  if (n <= 2 * r) {  // every window clipped
    for (int x = 0; x < n; ++x) clipped(x);
    return;
  }
  // The first level straight from the source (span >= 8 here), the others in place.
  const int span = doublingSpan(2 * r + 1);
  int i = 0;
  for (; i + 17 <= n; i += 16) cv::v_store(dst + i, rank<kMax>(cv::v_load(src + i), cv::v_load(src + i + 1)));
  for (; i + 1 < n; ++i) dst[i] = rank<kMax>(src[i], src[i + 1]);
  dst[n - 1] = src[n - 1];
  doubleInPlace<kMax>(dst, n, span, 2);
  // The whole windows, downwards: x reads L[x - r] and L[x - r + off] (off = 2 r + 1 - span <= r), both at or
  // below x, where nothing has been written yet.
  const int off = 2 * r + 1 - span;
  int x = n - 1 - r;
  for (; x - 15 >= r; x -= 16) {
    const int b = x - 15;
    cv::v_store(dst + b, rank<kMax>(cv::v_load(dst + b - r), cv::v_load(dst + b - r + off)));
  }
  for (; x >= r; --x) dst[x] = rank<kMax>(dst[x - r], dst[x - r + off]);
  // The clipped windows from the source, as running ranks: [0, x + r] growing, [x - r, n - 1] growing downwards.
  uint8_t v = src[0];
  for (x = 1; x < r; ++x) v = rank<kMax>(v, src[x]);
  for (x = 0; x < r; ++x) dst[x] = v = rank<kMax>(v, src[x + r]);
  v = src[n - 1];
  for (x = n - r; x < n - 1; ++x) v = rank<kMax>(v, src[x]);
  for (x = n - 1; x >= n - r; --x) dst[x] = v = rank<kMax>(v, src[x - r]);
}

/// rankColumns for r > 4 by doubling: the clipped rows of dst first, then the levels in place in src (which is
/// scratch), then the whole windows.
template <bool kMax>
void rankColumnsDoubling(uint8_t* src, uint8_t* dst, int w, int h, int r) {
  const size_t step = static_cast<size_t>(w);
  auto rank_rows = [&](const uint8_t* p, const uint8_t* q, uint8_t* out) {
    int x = 0;
    for (; x + 16 <= w; x += 16) cv::v_store(out + x, rank<kMax>(cv::v_load(p + x), cv::v_load(q + x)));
    for (; x < w; ++x) out[x] = rank<kMax>(p[x], q[x]);
  };
  auto clipped_row = [&](int y) {
    const int y0 = std::max(0, y - r), y1 = std::min(h - 1, y + r);
    uint8_t* out = dst + static_cast<size_t>(y) * step;
    std::copy(src + static_cast<size_t>(y0) * step, src + static_cast<size_t>(y0 + 1) * step, out);
    for (int yy = y0 + 1; yy <= y1; ++yy) rank_rows(out, src + static_cast<size_t>(yy) * step, out);
  };
  if (h <= 2 * r) {
    for (int y = 0; y < h; ++y) clipped_row(y);
    return;
  }
  for (int y = 0; y < r; ++y) clipped_row(y);
  for (int y = h - r; y < h; ++y) clipped_row(y);
  const int span = doublingSpan(2 * r + 1);
  for (int s = 1; s < span; s *= 2) {
    for (int y = 0; y + s < h; ++y) {
      uint8_t* row = src + static_cast<size_t>(y) * step;
      rank_rows(row, row + static_cast<size_t>(s) * step, row);
    }
  }
  const int off = 2 * r + 1 - span;
  for (int y = r; y < h - r; ++y) {
    const uint8_t* first = src + static_cast<size_t>(y - r) * step;
    rank_rows(first, first + static_cast<size_t>(off) * step, dst + static_cast<size_t>(y) * step);
  }
}

/// The rows' then the columns' rank of a w x h image into dst (a: scratch): r 1-4 with r at compile time, larger
/// by doubling; r <= 0 is the image itself.
template <bool kMax>
void rankSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r) {
  if (r <= 0) {
    if (dst != src) std::copy(src, src + static_cast<size_t>(w) * static_cast<size_t>(h), dst);
    return;
  }
  if (r > 4) {
    for (int y = 0; y < h; ++y)
      rankRowDoubling<kMax>(src + static_cast<size_t>(y) * w, a + static_cast<size_t>(y) * w, w, r);
    rankColumnsDoubling<kMax>(a, dst, w, h, r);
    return;
  }
  auto run = [&](auto radius) {
    constexpr int R = decltype(radius)::value;
    for (int y = 0; y < h; ++y)
      rankRow<kMax, R>(src + static_cast<size_t>(y) * w, a + static_cast<size_t>(y) * w, w, r);
    rankColumns<kMax, R>(a, dst, w, h, r);
  };
  switch (r) {
    case 1: run(std::integral_constant<int, 1>()); break;
    case 2: run(std::integral_constant<int, 2>()); break;
    case 3: run(std::integral_constant<int, 3>()); break;
    default: run(std::integral_constant<int, 4>()); break;
  }
}

}  // namespace

void openSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r) {
  rankSquare<false>(src, b, a, w, h, r);  // erosion into b
  rankSquare<true>(b, dst, a, w, h, r);   // then dilation into dst
}

namespace {

/// One erosion (kMax false) or dilation (true) of a w x h image by the 3 x 3 cross into dst (src != dst); what
/// lies outside the image does not count. 16 pixels at a time inside each row.
template <bool kMax>
void crossStep(const uint8_t* src, uint8_t* dst, int w, int h) {
  using namespace cv;
  const auto pick = [](uint8_t x, uint8_t y) -> uint8_t { return kMax ? std::max(x, y) : std::min(x, y); };
  const auto pick16 = [](const v_uint8x16& x, const v_uint8x16& y) { return kMax ? v_max(x, y) : v_min(x, y); };
  for (int y = 0; y < h; ++y) {
    const uint8_t* row = src + static_cast<size_t>(y) * static_cast<size_t>(w);
    const uint8_t* up = y > 0 ? row - w : row;
    const uint8_t* down = y + 1 < h ? row + w : row;
    uint8_t* out = dst + static_cast<size_t>(y) * static_cast<size_t>(w);
    const auto one = [&](int x) {
      const uint8_t left = row[x > 0 ? x - 1 : x], right = row[x + 1 < w ? x + 1 : x];
      out[x] = pick(pick(pick(row[x], up[x]), pick(down[x], left)), right);
    };
    int x = 0;
    if (w > 0) one(x++);
    for (; x + 17 <= w; x += 16) {  // (reads row[x - 1] .. row[x + 16])
      const v_uint8x16 c = v_load(row + x), l = v_load(row + x - 1), r = v_load(row + x + 1);
      v_store(out + x, pick16(pick16(pick16(c, l), pick16(r, v_load(up + x))), v_load(down + x)));
    }
    for (; x < w; ++x) one(x);
  }
}

}  // namespace

void openDiamond(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r) {
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  if (r <= 0) {
    std::copy(src, src + n, dst);
    return;
  }
  // Erosions src -> a -> b -> a ..., dilations on, the last one into dst.
  const uint8_t* cur = src;
  uint8_t* bufs[2] = {a, b};
  int next = 0;
  for (int i = 0; i < r; ++i, next ^= 1) {
    crossStep<false>(cur, bufs[next], w, h);
    cur = bufs[next];
  }
  for (int i = 0; i < r; ++i, next ^= 1) {
    uint8_t* out = i + 1 == r ? dst : bufs[next];
    crossStep<true>(cur, out, w, h);
    cur = out;
  }
}

void dilateSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r) {
  rankSquare<true>(src, dst, a, w, h, r);
}

}  // namespace internal
}  // namespace diekf
