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

/// Rank of the 2 r + 1 vectors of 16 bytes at p, p + step, ..., p + 2 r step; R > 0: r = R known at compile time
/// (the loop unrolled), else r at run time.
template <bool kMax, int R>
cv::v_uint8x16 rankVectors(const uint8_t* p, size_t step, int r) {
  cv::v_uint8x16 v = cv::v_load(p);
  if constexpr (R > 0) {
    for (int j = 1; j <= 2 * R; ++j) v = rank<kMax>(v, cv::v_load(p + j * step));
  } else {
    for (int j = 1; j <= 2 * r; ++j) v = rank<kMax>(v, cv::v_load(p + j * step));
  }
  return v;
}

/// Running minimum (kMax false) or maximum (kMax true) over [i - r, i + r] of a row of n bytes, the window clipped
/// at the ends (what lies outside does not count, as in OpenCV's morphology). src and dst must not overlap.
/// R: r at compile time (0: at run time).
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
  for (; x <= last; x += 16) cv::v_store(dst + x, rankVectors<kMax, R>(src + x - r, 1, r));
  if (x > r && x < n - r && last >= r) {
    // The rest of the interior as one more window ending at the last interior output (overlapping the previous).
    cv::v_store(dst + last, rankVectors<kMax, R>(src + last - r, 1, r));
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
        cv::v_store(out + x, rankVectors<kMax, R>(first + x, step, r));
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

/// The rows' then the columns' rank of a w x h image into dst (a: scratch), with r at compile time where it is small.
template <bool kMax>
void rankSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r) {
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
    case 4: run(std::integral_constant<int, 4>()); break;
    default: run(std::integral_constant<int, 0>()); break;
  }
}

}  // namespace

void openSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r) {
  rankSquare<false>(src, b, a, w, h, r);  // erosion into b
  rankSquare<true>(b, dst, a, w, h, r);   // then dilation into dst
}

void dilateSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r) {
  rankSquare<true>(src, dst, a, w, h, r);
}

}  // namespace internal
}  // namespace diekf
