// The one rule for a stamp compared with the previous one of the same stream (IMU samples or images), for the
// core (Estimator::addImu / addImage) and the ROS layer's callbacks alike (docs/robustness.md).
#pragma once

namespace diekf {

enum class StampStep {
  kForward,     ///< later than the previous stamp: accepted
  kDuplicate,   ///< the same stamp: rejected
  kOutOfOrder,  ///< earlier by at most time_jump_reset_s: rejected
  kJumpBack,    ///< earlier by more than time_jump_reset_s (a looping bag, a restarted driver): restart
};

/// How t_s follows previous_s (input/time_jump_reset_s: time_jump_reset_s).
inline StampStep classifyStampStep(double previous_s, double t_s, double time_jump_reset_s) {
  const double dt = t_s - previous_s;
  if (dt < -time_jump_reset_s) return StampStep::kJumpBack;
  if (dt == 0.0) return StampStep::kDuplicate;
  if (dt < 0.0) return StampStep::kOutOfOrder;
  return StampStep::kForward;
}

}  // namespace diekf
