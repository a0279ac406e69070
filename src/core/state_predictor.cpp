#include "diekf/state_predictor.h"

#include <algorithm>
#include <cmath>

#include "diekf/prediction.h"
#include "imu_propagation.h"

namespace diekf {

StatePredictor::StatePredictor(const CameraModel& camera, const EstimatorParams& params)
    : params_(params),
      pre_(camera.T_cam_imu, params.imu),
      nominal_dt_s_(std::max(1, params.imu.decimation_factor) / std::max(1e-9, params.imu.input_rate_hz)) {
  // The newest filtered sample lags the newest raw one by the low-pass delay, and by up to one output period.
  max_hold_s = pre_.delay_s() + 1.5 * nominal_dt_s_ + 0.01;
}

bool StatePredictor::addImu(const ImuSample& raw_imu) {
  ImuSample filtered;
  if (!pre_.push(raw_imu, &filtered)) return false;
  if (!filtered_.empty() && filtered.t_s <= filtered_.back().t_s) return false;
  filtered_.push_back(filtered);
  // Keep what a prediction from the posterior needs (the sample at or before it interpolates the first piece).
  const double keep_from = has_posterior_ ? std::min(t_post_, t_) - 2.0 * nominal_dt_s_ : filtered.t_s - 1.0;
  while (filtered_.size() > 2 && filtered_[1].t_s <= keep_from) filtered_.pop_front();
  while (filtered_.size() > 4000) filtered_.pop_front();  // no posterior for long: bounded memory
  return true;
}

void StatePredictor::setPosterior(double t_s, const State& x, const ErrorCov& P) {
  has_posterior_ = true;
  t_post_ = t_ = t_s;
  x_post_ = x_ = x;
  P_post_ = P_ = P;
}

void StatePredictor::reset(bool clear_imu) {
  has_posterior_ = false;
  if (clear_imu) {
    filtered_.clear();
    pre_.reset();
  }
}

void StatePredictor::propagateOver(double t_to) {
  // The step rule of ImuPropagator::propagateTo (predictImuPiece): each piece between sample stamps fed the mean
  // of the interpolation; across a gap the sample after it held and its unknown motion added as noise.
  internal::forEachImuPiece(filtered_, t_, t_to, 2.0 * nominal_dt_s_,
                            [&](double t0_s, double t1_s, const ImuSample& s) {
    internal::predictImuPiece(s, t1_s - t0_s, nominal_dt_s_, params_, &x_, &P_);
    t_ = t1_s;
  });
}

bool StatePredictor::predict(double t_s, State* x, ErrorCov* P) {
  if (!has_posterior_ || !(t_s >= t_post_) || filtered_.empty()) return false;
  const double newest = filtered_.back().t_s;
  if (t_s > newest + max_hold_s) return false;
  if (t_s < t_) {  // earlier than the last prediction: start again from the posterior
    t_ = t_post_;
    x_ = x_post_;
    P_ = P_post_;
  }
  if (t_ < newest) propagateOver(std::min(t_s, newest));
  *x = x_;
  *P = P_;
  if (t_s > t_) {  // beyond the newest filtered sample: hold it (on copies: the next sample continues from t_)
    const ImuSample& s = filtered_.back();
    diekf::predict(s.accel_mps2, s.gyro_radps, t_s - t_, params_.imu, params_.process, x, P);
  }
  return true;
}

}  // namespace diekf
