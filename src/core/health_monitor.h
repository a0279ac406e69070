// Internal part of the estimator (docs/algorithm.md section 9): the filter's health. Runs the divergence checks
// (which restart the filter), collects the consistency checks of the updates (which degrade the status) and owns
// the status as an explicit state machine.
//
// States (FilterStatus) and transitions, decided once per processed image by frameStatus(), in this order:
//   any          -> reset         the filter restarts at this image (a divergence check failed, no usable image
//                                 for input.max_image_gap_s) or restarted since the last image because of the
//                                 input (time jump, IMU gap beyond input.max_imu_bridge_s, internal error)
//   reset        -> initializing  the next image, until the run has converged
//   initializing -> tracking      an update was applied in this run and sigma_d / d fell below
//                                 init.tracking_max_relative_sigma_d (the run has converged; it stays converged
//                                 until the next restart)
//   tracking     -> degraded      a consistency check failed within the last divergence.degraded_hold_s: an
//                                 update gated (NIS above photometric.gate_nis) or rejected (photometric RMS,
//                                 inverse-distance step), the smoothed NIS too large, an image pair across a
//                                 bridged IMU gap
//   degraded     -> tracking      no failed check for divergence.degraded_hold_s
// A user's reset() starts a new run without a reset frame (initializing).
#pragma once

#include <cmath>
#include <cstddef>
#include <string>

#include "diekf/estimator.h"
#include "diekf/params.h"
#include "diekf/photometric_update.h"
#include "diekf/state.h"

namespace diekf {
namespace internal {

constexpr size_t kMessageCapacity = 160;  // chars reserved per result message (formatted without allocation)
/// While converging, the status says the distance is not being observed when, over the last kStallWindowS,
/// sigma_d / d fell by less than kStallMinFall and the camera's acceleration stayed below kStallMaxAccelMps2: a
/// camera holding still or flying at constant velocity gives the images nothing to scale (docs/noise_model.md
/// section 5). 0.1 m/s^2 changes the velocity by 0.2 m/s over the window; the smoothed level of a resting IMU's
/// noise reaches 0.02-0.03 m/s^2 in 2 s (the simulator's IMU, 500 Hz, 20 Hz low-pass), a noisier one may hide the
/// note but not make it appear.
constexpr double kStallWindowS = 2.0;
constexpr double kStallMinFall = 0.05;
constexpr double kStallMaxAccelMps2 = 0.1;

/// What the status of a frame depends on besides the monitor's own memory.
struct FrameFacts {
  double t_s = 0.0;                          ///< the image's time (IMU clock), s
  const std::string* reset_here = nullptr;   ///< reason of a restart at this image (null or empty: none)
  bool usable = false;                       ///< the image had texture
  const std::string* usable_why = nullptr;   ///< why not
  bool had_reference = false;                ///< a reference image existed before this one
  const std::string* skip_reason = nullptr;  ///< why this image's update was not applied (empty: applied)
  const std::string* last_reset_reason = nullptr;  ///< reason of the last restart (empty: never)
  bool warm_started = false;                 ///< the run started from a remembered state
  double outlier_fraction = 0.0;             ///< share of the pixels' weight down-weighted as outliers
  double accel_mps2 = 0.0;                   ///< magnitude of the camera's acceleration (IMU, smoothed), m/s^2
};

class HealthMonitor {
 public:
  /// `params` must outlive the monitor (the estimator's own copy).
  explicit HealthMonitor(const EstimatorParams& params) : params_(params) {}

  /// A new run of the filter: not converged, no update yet, nothing degraded; `bad_frames` carried over.
  void startRun(int bad_frames = 0);

  // --- Consistency checks: failing one degrades the status for divergence.degraded_hold_s ---
  void noteDegraded(double t_s, const char* why);
  void noteDegraded(double t_s, const std::string& why) { noteDegraded(t_s, why.c_str()); }
  /// NIS of an applied update, smoothed over about a second: persistently above divergence.max_nis_ratio times
  /// its mean (the observation dimension) means the noise model does not fit.
  void noteInnovation(double t_s, double dt_s, double nis);

  // --- Divergence checks: failing one restarts the filter ---
  /// Counts an applied update of this run.
  void countUpdate(bool applied) {
    if (applied) ++updates_since_reset_;
  }
  /// The checks on the posterior of a frame (non-finite, negative variance, distance, speed and their 1-sigma
  /// out of their bounds; divergence.bad_frames_before_reset bad or skipped updates in a row on usable images).
  /// Fills *reason when the filter must restart.
  void checkDivergence(const State& x, const ErrorCov& P, bool applied, bool image_usable,
                       const std::string& skip_reason, std::string* reason);
  /// The last checkDivergence's restart was the distance's 1-sigma running away before convergence (no scale).
  bool scaleLost() const { return scale_lost_; }

  // --- Status ---
  /// The filter restarted because of the input since the last image: the next frame reports reset with `reason`.
  void announceReset(const std::string& reason) { pending_reset_reason_ = reason; }
  /// Restart: status initializing until the next frame.
  void setInitializing() { status_ = FilterStatus::kInitializing; }
  /// The status of this frame (the transitions above) and its message into msg (capacity `msg_size`).
  FilterStatus frameStatus(const FrameFacts& f, const State& x, const ErrorCov& P, char* msg, size_t msg_size);

  FilterStatus status() const { return status_; }
  bool converged() const { return converged_; }
  /// Image time at which the current run converged (HUGE_VAL before), s.
  double convergedSince() const { return converged_since_s_; }
  int updatesSinceReset() const { return updates_since_reset_; }
  /// Consecutive bad or skipped updates on usable images.
  int badFrames() const { return bad_frames_; }

  static constexpr double kReportOutlierFraction = 0.05;  // outlier weight share named in the status message

 private:
  /// Appends the last failed check's reason to msg, with its age when it was an earlier frame's.
  void appendDegradedReason(double t_s, char* msg, size_t msg_size) const;
  /// While converging: renews the stall window (kStallWindowS) with this frame's sigma_d / d and acceleration.
  void trackStall(double t_s, double relative_sigma_d, double accel_mps2);
  /// A check failed within the last divergence.degraded_hold_s before image time t_s.
  bool degradedHeld(double t_s) const { return t_s <= degraded_at_s_ + params_.divergence.degraded_hold_s; }

  const EstimatorParams& params_;
  FilterStatus status_ = FilterStatus::kInitializing;
  int bad_frames_ = 0;
  int updates_since_reset_ = 0;
  bool converged_ = false;                  // sigma_d / d has fallen below the tracking threshold in this run
  double converged_since_s_ = HUGE_VAL;
  double nis_smoothed_ = 0.0;               // NIS smoothed over about 1 s (0: none yet)
  bool scale_lost_ = false;                   // the last divergence check: no scale before convergence
  double degraded_at_s_ = -HUGE_VAL;          // time of the last failed check (IMU clock), s
  char degraded_reason_[kMessageCapacity] = "";  // the last failed consistency check (no allocation per frame)
  std::string pending_reset_reason_;        // the next frame reports status reset with this reason
  double stall_ref_t_s_ = HUGE_VAL;         // start of the current kStallWindowS while converging (HUGE_VAL: none)
  double stall_ref_relative_sigma_d_ = 0.0;  // sigma_d / d at that start
  double stall_max_accel_mps2_ = 0.0;       // largest acceleration seen in the current window, m/s^2
  bool stalled_ = false;                    // over the last window: sigma_d / d fell little, no acceleration
};

}  // namespace internal
}  // namespace diekf
