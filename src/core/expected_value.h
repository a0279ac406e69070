// Internal: the expected value of a quantity from a noisy reading of it (regression calibration), shared by the
// rolling-shutter rows and the time offset (stateRateMap, interval_warp.cpp) and the prediction's distance column
// (imu_propagator.cpp).
#pragma once

#include <algorithm>
#include <cmath>

#include "diekf/types.h"

namespace diekf {
namespace internal {

/// The expected value of a reading r with the noise variance v (per component): r max(0, 1 - v / p), the reading
/// shrunk by the share of the power p that the noise explains (zero where the noise explains all of it). p is the
/// readings' mean square over recent frames where given (mean_sq > 0), else the reading's own square r^2. One
/// reading's own square is noise too: in a hover whose true rates are near zero it leaves a third of the noise's
/// variance in the shrunk reading, a regressor of noise that pulls a state fitted against it toward zero
/// (docs/algorithm.md section 3.7, "The rates' expected values").
inline Vec3 expectedGivenReading(const Vec3& r, const Vec3& v, const Vec3& mean_sq = Vec3::Zero()) {
  Vec3 out;
  for (int i = 0; i < 3; ++i) {
    const double p = mean_sq(i) > 0.0 ? mean_sq(i) : r(i) * r(i);
    out(i) = p > v(i) ? r(i) * (1.0 - v(i) / p) : 0.0;
  }
  return out;
}

/// The mean square of a reading per component over the last window_s (exponential weights with that time
/// constant; the first readings weighted equally, so the first mean square is the first reading's square).
class MeanSquareWindow {
 public:
  /// Adds the reading r taken at t_s (later than the last one; an earlier or equal time restarts the window) and
  /// returns the mean square with it.
  const Vec3& add(const Vec3& r, double t_s, double window_s) {
    if (count_ > 0 && !(t_s > last_t_s_)) count_ = 0;
    const double weight =
        count_ == 0 ? 1.0 : std::max(1.0 - std::exp(-(t_s - last_t_s_) / window_s), 1.0 / (count_ + 1.0));
    mean_sq_ = (1.0 - weight) * mean_sq_ + weight * r.cwiseAbs2();
    count_ = std::min(count_ + 1, kMaxCount);
    last_t_s_ = t_s;
    return mean_sq_;
  }
  void reset() { count_ = 0; }

 private:
  static constexpr int kMaxCount = 1 << 20;  // readings counted (the exponential weights take over long before)
  Vec3 mean_sq_ = Vec3::Zero();
  double last_t_s_ = 0.0;
  int count_ = 0;
};

}  // namespace internal
}  // namespace diekf
