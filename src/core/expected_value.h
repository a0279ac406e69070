// Internal: the expected value of a quantity from a noisy reading of it (regression calibration), shared by the
// rolling-shutter rows and the time offset (stateRateMap, interval_warp.cpp) and the prediction's distance column
// (imu_propagator.cpp).
#pragma once

#include "diekf/types.h"

namespace diekf {
namespace internal {

/// The expected value of a reading r with the noise variance v (per component): r max(0, 1 - v / r^2), the
/// reading shrunk by the share of its square that the noise explains (zero where the noise explains all of it).
inline Vec3 expectedGivenReading(const Vec3& r, const Vec3& v) {
  Vec3 out;
  for (int i = 0; i < 3; ++i) {
    const double r2 = r(i) * r(i);
    out(i) = r2 > v(i) ? r(i) * (1.0 - v(i) / r2) : 0.0;
  }
  return out;
}

}  // namespace internal
}  // namespace diekf
