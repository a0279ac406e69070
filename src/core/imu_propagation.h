// Internal: how the estimator walks its buffer of filtered IMU samples between two times (one definition for
// the estimator and the tests).
#pragma once

#include <algorithm>

#include "diekf/prediction.h"

namespace diekf {
namespace internal {

/// Splits (t_from_s, t_to_s] at the stamps of the filtered samples in `buf` (ordered by stamp, indexable,
/// size()) and calls fn(t0_s, t1_s, input) for each piece, `input` the mean IMU input over it: the linear
/// interpolation between the two samples around the piece (meanImuOver) when they are at most
/// `max_interp_span_s` apart, otherwise (the first sample of the buffer, or across a bridged gap) the sample
/// at the piece's end held over it. Pieces after the last sample are not visited. Returns the time reached.
template <class Buffer, class Fn>
double forEachImuPiece(const Buffer& buf, double t_from_s, double t_to_s, double max_interp_span_s, Fn&& fn) {
  size_t i = 0;
  while (i < buf.size() && t_from_s >= buf[i].t_s) ++i;
  double t = t_from_s;
  while (t < t_to_s && i < buf.size()) {
    const ImuSample& s = buf[i];
    const double t_end = std::min(s.t_s, t_to_s);
    if (t_end > t) {
      const bool interpolate = i > 0 && s.t_s - buf[i - 1].t_s <= max_interp_span_s;
      fn(t, t_end, interpolate ? meanImuOver(buf[i - 1], s, t, t_end) : s);
      t = t_end;
    }
    if (s.t_s <= t_to_s) ++i;
  }
  return t;
}

}  // namespace internal
}  // namespace diekf
