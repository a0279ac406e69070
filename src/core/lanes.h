// Four rows of floats as the lanes of SIMD vectors: a row-wise recursion or running sum then runs on four rows at
// once with the same operations per row (the spline prefilter, bspline.cpp; the outlier weights' window sums,
// outlier_weights.cpp).
#pragma once

#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace internal {

/// Columns [0, n4) of the rows r[0..3] into `lanes`, column x of row l at 4 x + l; n4 a multiple of 4.
inline void rowsToLanes(const float* const r[4], int n4, float* lanes) {
  for (int x = 0; x < n4; x += 4) {
    cv::v_float32x4 t0, t1, t2, t3;
    cv::v_transpose4x4(cv::v_load(r[0] + x), cv::v_load(r[1] + x), cv::v_load(r[2] + x), cv::v_load(r[3] + x), t0, t1,
                       t2, t3);
    cv::v_store(lanes + 4 * x, t0);
    cv::v_store(lanes + 4 * x + 4, t1);
    cv::v_store(lanes + 4 * x + 8, t2);
    cv::v_store(lanes + 4 * x + 12, t3);
  }
}

/// The inverse of rowsToLanes: columns [0, n4) of `lanes` back into the rows r[0..3].
inline void lanesToRows(const float* lanes, int n4, float* const r[4]) {
  for (int x = 0; x < n4; x += 4) {
    cv::v_float32x4 t0, t1, t2, t3;
    cv::v_transpose4x4(cv::v_load(lanes + 4 * x), cv::v_load(lanes + 4 * x + 4), cv::v_load(lanes + 4 * x + 8),
                       cv::v_load(lanes + 4 * x + 12), t0, t1, t2, t3);
    cv::v_store(r[0] + x, t0);
    cv::v_store(r[1] + x, t1);
    cv::v_store(r[2] + x, t2);
    cv::v_store(r[3] + x, t3);
  }
}

/// The pairs (p[0], p[1]) at four addresses as two vectors, (p0[0], p1[0], p2[0], p3[0]) and (p0[1], ... p3[1]):
/// two lanes per 64-bit load, regrouped by two zips (the warped samples' value and weight in the photometric
/// update's sweep and its outlier weights).
inline void loadPairs(const float* p0, const float* p1, const float* p2, const float* p3, cv::v_float32x4* first,
                      cv::v_float32x4* second) {
  cv::v_float32x4 z0, z1;
  cv::v_zip(cv::v_load_halves(p0, p1), cv::v_load_halves(p2, p3), z0, z1);
  cv::v_zip(z0, z1, *first, *second);
}

}  // namespace internal
}  // namespace diekf
