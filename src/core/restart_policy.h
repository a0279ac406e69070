// Internal part of the estimator (docs/algorithm.md section 9): what a run of the filter starts from. The cold
// prior of the parameters (init.*), or after an automatic restart the warm prior of a recently healthy state;
// counts the restarts and keeps the reason of the last one.
#pragma once

#include <array>
#include <string>

#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {
namespace internal {

class RestartPolicy {
 public:
  /// `params` must outlive the policy (the estimator's own copy).
  explicit RestartPolicy(const EstimatorParams& params) : params_(params) {}

  /// The initial state and covariance of a run (init.*). The time offset and readout are properties of the
  /// sensors, not of the flight: when the previous run had `converged`, their estimates in `x` are kept (with
  /// the initial 1-sigma around them), otherwise they start at the calibration's (offset 0 on top of it, readout
  /// `configured_readout_s`). Clears the warm-start flag.
  void coldStart(bool converged, double configured_readout_s, State* x, ErrorCov* P);
  /// After an automatic restart at t_now_s (init.warm_restart): the distance, normal, gravity and biases of the
  /// newest remembered healthy state taken at least kWarmRestartLagS before t_now_s and at most
  /// init.warm_restart_max_age_s old, alpha's 1-sigma relative (init.warm_restart_sigma_alpha_relative). The
  /// velocity keeps the prior (the fault made it unknown). No-op without such a state.
  void applyWarmPrior(double t_now_s, State* x, ErrorCov* P);
  /// The initial uncertainty of alpha and vartheta (init.sigma_alpha0_inv_m, init.sigma_vartheta0_inv_s),
  /// uncorrelated: their rows and columns of P replaced. Part of coldStart; also what the opening's switch for
  /// projector dots gives them back (docs/noise_model.md section 11).
  void setInitialScaleCovariance(ErrorCov* P) const;
  /// Whether the current run started from a remembered state (for the status text).
  bool warmStarted() const { return warm_started_; }
  void setWarmStarted(bool warm) { warm_started_ = warm; }

  /// Remembers a healthy tracking state (one every kSnapshotSpacingS, the last ~3 s).
  void rememberGood(double t_s, const State& x);
  /// Forgets the remembered states (they are from other data, e.g. after a time jump).
  void forgetHistory();

  /// Counts a restart and keeps its reason.
  void noteRestart(const std::string& reason) {
    ++count_;
    last_reason_ = reason;
  }
  int count() const { return count_; }
  const std::string& lastReason() const { return last_reason_; }

  static constexpr double kWarmRestartLagS = 1.0;    // warm restarts use a state at least this old, s
  static constexpr double kSnapshotSpacingS = 0.25;  // spacing of the kept snapshots, s

 private:
  struct GoodSnapshot {
    bool valid = false;
    double t_s = 0.0;  // IMU clock, s
    State x;
  };
  const EstimatorParams& params_;
  std::array<GoodSnapshot, 12> good_history_;  // healthy tracking states, about the last 3 s
  bool warm_started_ = false;                  // the current run started from a remembered state
  int count_ = 0;                              // restarts since construction
  std::string last_reason_;                    // reason of the last restart
};

}  // namespace internal
}  // namespace diekf
