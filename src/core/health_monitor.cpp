#include "health_monitor.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "gauss_newton.h"

namespace diekf {
namespace internal {

void HealthMonitor::startRun(int bad_frames) {
  bad_frames_ = bad_frames;
  updates_since_reset_ = 0;
  converged_ = false;
  converged_since_s_ = HUGE_VAL;
  nis_smoothed_ = 0.0;
  degraded_at_s_ = -HUGE_VAL;
  degraded_reason_[0] = '\0';
  stall_ref_t_s_ = HUGE_VAL;
  stalled_ = false;
}

void HealthMonitor::trackStall(double t_s, double relative_sigma_d, double accel_mps2) {
  if (!(stall_ref_t_s_ <= t_s)) {
    stalled_ = false;
  } else if (t_s - stall_ref_t_s_ < kStallWindowS) {
    stall_max_accel_mps2_ = std::max(stall_max_accel_mps2_, accel_mps2);
    return;
  } else {
    stalled_ = relative_sigma_d > (1.0 - kStallMinFall) * stall_ref_relative_sigma_d_ &&
               std::max(stall_max_accel_mps2_, accel_mps2) < kStallMaxAccelMps2;
  }
  stall_ref_t_s_ = t_s;
  stall_ref_relative_sigma_d_ = relative_sigma_d;
  stall_max_accel_mps2_ = accel_mps2;
}

void HealthMonitor::noteDegraded(double t_s, const char* why) {
  degraded_at_s_ = t_s;
  std::snprintf(degraded_reason_, sizeof(degraded_reason_), "%s", why);
}

void HealthMonitor::noteInnovation(double t_s, double dt_s, double nis) {
  const double a = 1.0 - std::exp(-dt_s / 1.0);
  nis_smoothed_ = nis_smoothed_ > 0.0 ? nis_smoothed_ + a * (nis - nis_smoothed_) : nis;
  if (nis_smoothed_ > params_.divergence.max_nis_ratio * kObsDim) {
    char why[kMessageCapacity];
    std::snprintf(why, sizeof(why), "innovations too large: smoothed NIS %.3g (expected %d)", nis_smoothed_, kObsDim);
    noteDegraded(t_s, why);
  }
}

void HealthMonitor::checkDivergence(const State& x, const ErrorCov& P, bool applied, bool image_usable,
                                    const std::string& skip_reason, std::string* reason) {
  const DivergenceParams& dv = params_.divergence;
  scale_lost_ = false;
  if (!x.allFinite() || !P.allFinite()) {
    *reason = "non-finite state or covariance";
    return;
  }
  if (P.diagonal().minCoeff() < -1e-9) {
    *reason = "covariance lost positive semi-definiteness (negative variance)";
    return;
  }
  const double d = x.distance_m();
  if (!(d > dv.min_distance_m && d < dv.max_distance_m)) {
    std::ostringstream os;
    os << "distance " << d << " m outside [" << dv.min_distance_m << ", " << dv.max_distance_m << "] m";
    *reason = os.str();
    return;
  }
  const double sigma_d = sigmaDistance_m(x, P);
  if (!(sigma_d <= dv.max_sigma_distance_m)) {
    std::ostringstream os;
    os << "distance 1-sigma " << sigma_d << " m above " << dv.max_sigma_distance_m << " m";
    // Before the first convergence this is the usual way a still or hovering camera ends a run: nothing tells
    // the distance until the camera accelerates (docs/results.md, "Start-up").
    if (!converged_) os << " before convergence (no scale until the camera accelerates)";
    scale_lost_ = !converged_;
    *reason = os.str();
    return;
  }
  const double speed = x.velocity_mps().norm();
  if (!(speed <= dv.max_speed_mps)) {
    std::ostringstream os;
    os << "speed " << speed << " m/s above " << dv.max_speed_mps << " m/s";
    *reason = os.str();
    return;
  }
  const double sigma_v = sigmaVelocity_mps(x, P).maxCoeff();
  if (!(sigma_v <= dv.max_sigma_velocity_mps)) {
    std::ostringstream os;
    os << "velocity 1-sigma " << sigma_v << " m/s above " << dv.max_sigma_velocity_mps << " m/s";
    *reason = os.str();
    return;
  }
  // Unusable images (black, saturated, uniform) are not counted here: a blackout is handled by
  // input.max_image_gap_s. Nor is the prior itself reset again when no update has been applied since.
  if (!image_usable) return;
  // A bad photometric residual has already turned into a rejected (not applied) update.
  bad_frames_ = applied ? 0 : bad_frames_ + 1;
  if (bad_frames_ >= dv.bad_frames_before_reset && updates_since_reset_ > 0) {
    std::ostringstream os;
    os << bad_frames_ << " consecutive frames with a bad or skipped update (last: " << skip_reason << ")";
    *reason = os.str();
  }
}

void HealthMonitor::appendDegradedReason(double t_s, char* msg, size_t msg_size) const {
  // The failed check may be an earlier frame's (the status holds for degraded_hold_s): its age then, so that the
  // reason is not read as this frame's (a rejected update's RMS next to an applied one's). The checks are noted
  // at the image's time: 0 for this frame's own.
  const size_t used = std::strlen(msg);
  const double age_s = t_s - degraded_at_s_;
  if (age_s > 0.0) {
    std::snprintf(msg + used, msg_size - used, "%s (%.1f s ago)", degraded_reason_, age_s);
  } else {
    std::snprintf(msg + used, msg_size - used, "%s", degraded_reason_);
  }
}

FilterStatus HealthMonitor::frameStatus(const FrameFacts& f, const State& x, const ErrorCov& P, char* msg,
                                        size_t msg_size) {
  FilterStatus s;
  if (f.reset_here != nullptr && !f.reset_here->empty()) {
    s = FilterStatus::kReset;
    std::snprintf(msg, msg_size, "%s", f.reset_here->c_str());
  } else if (!pending_reset_reason_.empty()) {
    // The first frame after a restart triggered by the input (time jump, IMU gap, internal error).
    s = FilterStatus::kReset;
    std::snprintf(msg, msg_size, "%s", pending_reset_reason_.c_str());
  } else if (!converged_) {
    const double relative_sigma_d = relativeSigmaDistance(x, P);
    converged_ = updates_since_reset_ > 0 && relative_sigma_d < params_.init.tracking_max_relative_sigma_d;
    if (converged_) converged_since_s_ = f.t_s;
    s = converged_ ? FilterStatus::kTracking : FilterStatus::kInitializing;
    if (!f.usable) {
      std::snprintf(msg, msg_size, "%s", f.usable_why->c_str());
    } else if (!f.had_reference) {
      std::snprintf(msg, msg_size, "first image: reference set");
    } else if (updates_since_reset_ == 0) {
      std::snprintf(msg, msg_size, "%s",
                    f.skip_reason->empty() ? "waiting for a valid image update" : f.skip_reason->c_str());
    } else if (!converged_) {
      trackStall(f.t_s, relative_sigma_d, f.accel_mps2);
      const int used = std::snprintf(msg, msg_size, "converging: sigma_d/d = %g (tracking below %g)",
                                     relative_sigma_d, params_.init.tracking_max_relative_sigma_d);
      if (stalled_ && used > 0 && static_cast<size_t>(used) < msg_size) {
        std::snprintf(msg + used, msg_size - used,
                      "; no acceleration to scale the images (sigma_d/d down < %.0f %% in %.0f s)",
                      100.0 * kStallMinFall, kStallWindowS);
      }
    }
    if (!converged_ && degradedHeld(f.t_s)) {
      // A note of the hold (a pattern found, projector dots, large innovations): said while converging too.
      const size_t used = std::strlen(msg);
      if (used > 0) std::snprintf(msg + used, msg_size - used, "; ");
      appendDegradedReason(f.t_s, msg, msg_size);
    }
    if (!converged_ && !f.last_reset_reason->empty()) {
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, msg_size - used, " (last reset: %s%s", f.last_reset_reason->c_str(),
                    f.warm_started ? "; restarted from the last good distance)" : ")");
    }
  } else if (degradedHeld(f.t_s)) {
    s = FilterStatus::kDegraded;
    msg[0] = '\0';
    appendDegradedReason(f.t_s, msg, msg_size);
  } else {
    s = FilterStatus::kTracking;
    std::snprintf(msg, msg_size, "%s", f.skip_reason->c_str());
  }
  if (f.outlier_fraction >= kReportOutlierFraction && s != FilterStatus::kReset) {
    // Objects or clutter not moving with the plane (docs/noise_model.md section 10): say how much is ignored.
    const size_t used = std::strlen(msg);
    std::snprintf(msg + used, msg_size - used, "%soutliers: %.0f %% of the image down-weighted",
                  used > 0 ? "; " : "", 100.0 * f.outlier_fraction);
  }
  pending_reset_reason_.clear();
  status_ = s;
  return s;
}

}  // namespace internal
}  // namespace diekf
