// The filter's state predicted between images: the last posterior (FrameResult) propagated with the filter's own
// prediction model (prediction.h) and the same filtered IMU samples the estimator uses (ImuPreprocessor), for
// outputs faster than the images (the nodelet's ~odometry_imu_rate). Not a second dead-reckoner: the same state,
// the same inputs, the same step as ImuPropagator::propagateTo, on copies; the estimator itself is not touched.
#pragma once

#include <deque>

#include "diekf/camera_model.h"
#include "diekf/imu_filter.h"
#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {

class StatePredictor {
 public:
  /// `params` as the estimator's (after the IMU preprocessing was designed for the measured rate).
  StatePredictor(const CameraModel& camera, const EstimatorParams& params);

  /// Raw IMU sample, exactly as given to Estimator::addImu. Returns true when a filtered sample came out.
  bool addImu(const ImuSample& raw_imu);
  /// A posterior of the filter (FrameResult::t_s, state, covariance): predictions start from it.
  void setPosterior(double t_s, const State& x, const ErrorCov& P);
  /// Forgets the posterior (after a filter restart) and the filter memory when `clear_imu`.
  void reset(bool clear_imu);

  /// The posterior predicted to t_s, which must not be before it: over the filtered samples as the estimator
  /// steps them (interpolated; a gap longer than two periods held and its noise inflated as in
  /// ImuPropagator::propagateTo), and beyond the newest filtered sample with that sample held, for at most
  /// `max_hold_s` (the low-pass delay and one period). False before a posterior, for an earlier t_s, or beyond the
  /// hold. Incremental: consecutive calls with increasing t_s cost one step per new sample.
  bool predict(double t_s, State* x, ErrorCov* P);

  bool hasPosterior() const { return has_posterior_; }
  /// Stamp of the newest filtered sample (delay-compensated), s; -1 before any.
  double newestFilteredTime() const { return filtered_.empty() ? -1.0 : filtered_.back().t_s; }
  /// Longest time predicted beyond the newest filtered sample, s.
  double max_hold_s = 0.0;

 private:
  /// Propagates (t_, x_, P_) to t_to with the filtered samples (up to the newest one).
  void propagateOver(double t_to);

  EstimatorParams params_;
  ImuPreprocessor pre_;
  std::deque<ImuSample> filtered_;  ///< filtered samples in C, delay-compensated stamps, oldest first
  double nominal_dt_s_;
  bool has_posterior_ = false;
  double t_post_ = 0.0;
  State x_post_;
  ErrorCov P_post_ = ErrorCov::Zero();
  // The prediction so far (advanced incrementally), up to the newest filtered sample at most.
  double t_ = 0.0;
  State x_;
  ErrorCov P_ = ErrorCov::Zero();
};

}  // namespace diekf
