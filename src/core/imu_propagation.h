// Internal: how the estimator walks its buffer of filtered IMU samples between two times (one definition for
// the estimator and the tests).
#pragma once

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "diekf/params.h"
#include "diekf/prediction.h"

namespace diekf {
namespace internal {

/// Splits (t_from_s, t_to_s] at the stamps of the filtered samples in `buf` (ordered by stamp, indexable,
/// size()) and calls fn(t0_s, t1_s, input) for each piece, `input` the mean IMU input over it: the linear
/// interpolation between the two samples around the piece (meanImuOver) when they are at most
/// `max_interp_span_s` apart, otherwise (the first sample of the buffer, or across a bridged gap) the sample
/// at the piece's end held over it. Pieces after the last sample are not visited. Returns the time reached.
/// A callback taking two more arguments, fn(t0_s, t1_s, input, u, starts), is also given the later sample's
/// weight u in `input` (the interpolation's at the piece's middle; 1 when held) and whether the piece starts at
/// the earlier sample's stamp.
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
      const ImuSample input = interpolate ? meanImuOver(buf[i - 1], s, t, t_end) : s;
      if constexpr (std::is_invocable_v<Fn, double, double, const ImuSample&, double, bool>) {
        // Also: the later sample's weight in `input` (1 when held) and whether the piece starts a sample interval.
        const double u = interpolate ? (0.5 * (t + t_end) - buf[i - 1].t_s) / (s.t_s - buf[i - 1].t_s) : 1.0;
        fn(t, t_end, input, u, i > 0 && t == buf[i - 1].t_s);
      } else {
        fn(t, t_end, input);
      }
      t = t_end;
    }
    if (s.t_s <= t_to_s) ++i;
  }
  return t;
}

/// One piece (t0, t0 + dt] of forEachImuPiece fed `input`: one prediction step (prediction.h), or across a
/// bridged gap (dt longer than two nominal periods) steps of at most one period with the IMU white-noise
/// densities raised to sqrt(density^2 + sigma_gap^2 dt) (input.gap_*: an unknown acceleration and rate change,
/// constant over the gap, add variance (sigma dt)^2). The one step rule of the estimator (ImuPropagator) and of
/// the predictions between images (StatePredictor). `column_accel_C`: predict's (the held acceleration of the
/// distance's column, ImuPropagator::holdColumnAccel), or null.
inline void predictImuPiece(const ImuSample& input, double dt, double nominal_dt_s, const EstimatorParams& params,
                            State* x, ErrorCov* P, const Vec3* column_accel_C = nullptr,
                            ErrorVec* sensitivity = nullptr) {
  const bool gap = dt > 2.0 * nominal_dt_s;
  const int steps = gap ? static_cast<int>(std::ceil(dt / nominal_dt_s)) : 1;
  const double h = dt / steps;
  ImuParams imu = params.imu;
  if (gap) {
    const InputParams& in = params.input;
    imu.accel_noise_density = std::sqrt(imu.accel_noise_density * imu.accel_noise_density +
                                        in.gap_accel_sigma_mps2 * in.gap_accel_sigma_mps2 * dt);
    imu.gyro_noise_density = std::sqrt(imu.gyro_noise_density * imu.gyro_noise_density +
                                       in.gap_gyro_sigma_radps * in.gap_gyro_sigma_radps * dt);
  }
  for (int k = 0; k < steps; ++k)
    predict(input.accel_mps2, input.gyro_radps, h, imu, params.process, x, P, column_accel_C, sensitivity);
}

}  // namespace internal
}  // namespace diekf
