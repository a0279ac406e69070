#include "morphology.h"

#include <algorithm>
#include <cstddef>

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

/// Running minimum (kMax false) or maximum (kMax true) over [i - r, i + r] of a row of n bytes, the window clipped
/// at the ends (what lies outside does not count, as in OpenCV's morphology). src and dst must not overlap.
template <bool kMax>
void rankRow(const uint8_t* src, uint8_t* dst, int n, int r) {
  auto scalar = [&](int x) {
    uint8_t v = src[x];
    for (int j = std::max(0, x - r); j <= std::min(n - 1, x + r); ++j) v = rank<kMax>(v, src[j]);
    dst[x] = v;
  };
  int x = 0;
  for (; x < std::min(r, n); ++x) scalar(x);
  for (; x + 16 + r <= n; x += 16) {
    cv::v_uint8x16 v = cv::v_load(src + x - r);
    for (int j = 1; j <= 2 * r; ++j) v = rank<kMax>(v, cv::v_load(src + x - r + j));
    cv::v_store(dst + x, v);
  }
  for (; x < n; ++x) scalar(x);
}

/// The same down the columns: row y of dst from the rows y - r .. y + r of src (clipped), w bytes each.
template <bool kMax>
void rankColumns(const uint8_t* src, uint8_t* dst, int w, int h, int r) {
  for (int y = 0; y < h; ++y) {
    const int y0 = std::max(0, y - r), y1 = std::min(h - 1, y + r);
    uint8_t* out = dst + static_cast<size_t>(y) * w;
    const uint8_t* first = src + static_cast<size_t>(y0) * w;
    int x = 0;
    for (; x + 16 <= w; x += 16) {
      cv::v_uint8x16 v = cv::v_load(first + x);
      for (int yy = y0 + 1; yy <= y1; ++yy) v = rank<kMax>(v, cv::v_load(src + static_cast<size_t>(yy) * w + x));
      cv::v_store(out + x, v);
    }
    for (; x < w; ++x) {
      uint8_t v = first[x];
      for (int yy = y0 + 1; yy <= y1; ++yy) v = rank<kMax>(v, src[static_cast<size_t>(yy) * w + x]);
      out[x] = v;
    }
  }
}

}  // namespace

void openSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r) {
  for (int y = 0; y < h; ++y) rankRow<false>(src + static_cast<size_t>(y) * w, a + static_cast<size_t>(y) * w, w, r);
  rankColumns<false>(a, b, w, h, r);
  for (int y = 0; y < h; ++y) rankRow<true>(b + static_cast<size_t>(y) * w, a + static_cast<size_t>(y) * w, w, r);
  rankColumns<true>(a, dst, w, h, r);
}

void dilateSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r) {
  for (int y = 0; y < h; ++y) rankRow<true>(src + static_cast<size_t>(y) * w, a + static_cast<size_t>(y) * w, w, r);
  rankColumns<true>(a, dst, w, h, r);
}

}  // namespace internal
}  // namespace diekf
