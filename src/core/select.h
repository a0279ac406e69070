// Internal: the k-th smallest of n floats (none NaN), as std::nth_element finds it, in fewer steps: a histogram of
// the values' top 11 bits (an order-preserving integer key: sign, exponent and the mantissa's first 2 bits, i.e.
// quarter octaves) finds the bin that holds rank k, and only that bin's values are then selected among. For the
// image medians of the outlier weights (outlier_weights.cpp): 1300 values at 180 px, where nth_element's
// data-dependent branches made it 3 % of a frame's time.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace diekf {
namespace internal {

/// Order-preserving key of a float that is not NaN: a < b  =>  key(a) < key(b) (-0 before +0).
inline uint32_t floatOrderKey(float v) {
  uint32_t u;
  std::memcpy(&u, &v, sizeof u);
  return (u & 0x80000000u) != 0u ? ~u : (u | 0x80000000u);
}

/// The value of rank k (0-based) among v[0..n), k < n, none NaN. Reorders v; `counts` is scratch (no allocation).
/// The value equals std::nth_element's (up to the sign of a zero when both zeros are present).
inline float kthSmallest(float* v, std::size_t n, std::size_t k, std::array<uint32_t, 2048>* counts) {
  constexpr int kShift = 21;  // 32 - 11 bits
  if (n <= 64) {
    std::nth_element(v, v + k, v + n);
    return v[k];
  }
  counts->fill(0u);
  for (std::size_t i = 0; i < n; ++i) ++(*counts)[floatOrderKey(v[i]) >> kShift];
  std::size_t below = 0;
  uint32_t bin = 0;
  for (;; ++bin) {
    const std::size_t c = (*counts)[bin];
    if (below + c > k) break;
    below += c;
  }
  // The bin's values to the front (their order among themselves does not matter), then the rank within them.
  std::size_t m = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const float x = v[i];
    v[m] = x;
    m += (floatOrderKey(x) >> kShift) == bin ? 1u : 0u;
  }
  std::nth_element(v, v + (k - below), v + m);
  return v[k - below];
}

}  // namespace internal
}  // namespace diekf
