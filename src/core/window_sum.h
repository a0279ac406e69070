// Sliding-window sums along a row: the outlier weights' neighbourhoods (docs/noise_model.md section 10).
#pragma once

#include <algorithm>

namespace diekf {
namespace internal {

/// out[i] = the sum of in[k] over k in [i - half, i + half], truncated at 0 and n - 1, for i in [0, n). A running
/// sum: for each i the value i + half enters, then i - half - 1 leaves (the same additions, in the same order, as
/// a loop testing both at every i); split at the edges so that no loop has a branch. half >= 0.
/// Generic over the value: `in(k)` gives sample k, `out(i, sum)` takes the result, `zero` starts the sum (a float,
/// or a SIMD vector holding independent rows as lanes: the same additions per lane).
template <class V, class In, class Out>
inline void windowSum(int n, int half, In in, Out out, const V& zero) {
  V sum = zero;
  for (int i = 0; i < std::min(half, n); ++i) sum += in(i);
  const int enter_end = std::max(0, n - half);     // i whose window still gains i + half
  const int leave_begin = std::min(n, half + 1);   // i whose window loses i - half - 1
  int i = 0;
  for (; i < std::min(enter_end, leave_begin); ++i) {
    sum += in(i + half);
    out(i, sum);
  }
  for (; i < enter_end; ++i) {
    sum += in(i + half);
    sum -= in(i - half - 1);
    out(i, sum);
  }
  for (; i < leave_begin; ++i) out(i, sum);  // a window wider than the row: nothing enters or leaves
  for (; i < n; ++i) {
    sum -= in(i - half - 1);
    out(i, sum);
  }
}

inline void windowSumRow(const float* in, int n, int half, float* out) {
  windowSum(
      n, half, [in](int k) { return in[k]; }, [out](int i, float v) { out[i] = v; }, 0.0f);
}

}  // namespace internal
}  // namespace diekf
