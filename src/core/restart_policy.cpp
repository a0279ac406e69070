#include "restart_policy.h"

#include <cmath>

namespace diekf {
namespace internal {

void RestartPolicy::coldStart(bool converged, double configured_readout_s, State* x_io, ErrorCov* P_out) {
  const InitParams& in = params_.init;
  State& x = *x_io;
  ErrorCov& P = *P_out;
  const bool keep_t_d = converged && std::isfinite(x.t_d_s);
  const double t_d_s = keep_t_d ? x.t_d_s : 0.0;
  const bool keep_readout = converged && params_.estimate_readout && std::isfinite(x.readout_s);
  const double readout_s = keep_readout ? x.readout_s : configured_readout_s;
  const bool keep_focal = converged && params_.estimate_focal_scale && std::isfinite(x.focal_scale);
  const double focal_scale = keep_focal ? x.focal_scale : 0.0;
  x = State();
  x.t_d_s = t_d_s;
  x.readout_s = readout_s;
  x.focal_scale = focal_scale;
  x.alpha = in.alpha0_inv_m;
  x.vartheta = in.vartheta0_inv_s;
  x.mu = UnitVector(in.mu0);
  x.g = UnitVector(in.g0);
  P.setZero();
  setInitialScaleCovariance(&P);
  P.block<2, 2>(ErrIdx::kMu, ErrIdx::kMu) = Mat2::Identity() * in.sigma_mu0_rad * in.sigma_mu0_rad;
  P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = Mat2::Identity() * in.sigma_g0_rad * in.sigma_g0_rad;
  P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa) = Mat3::Identity() * in.sigma_ba0_mps2 * in.sigma_ba0_mps2;
  P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw) = Mat3::Identity() * in.sigma_bw0_radps * in.sigma_bw0_radps;
  P(ErrIdx::kTd, ErrIdx::kTd) = in.sigma_time_offset_s * in.sigma_time_offset_s;
  P(ErrIdx::kRo, ErrIdx::kRo) = in.sigma_readout_s * in.sigma_readout_s;
  P(ErrIdx::kFs, ErrIdx::kFs) = in.sigma_focal_scale * in.sigma_focal_scale;
  warm_started_ = false;
}

void RestartPolicy::setInitialScaleCovariance(ErrorCov* P_io) const {
  const InitParams& in = params_.init;
  ErrorCov& P = *P_io;
  for (int i = ErrIdx::kAlpha; i < ErrIdx::kVartheta + 3; ++i) {
    P.row(i).setZero();
    P.col(i).setZero();
  }
  P(ErrIdx::kAlpha, ErrIdx::kAlpha) = in.sigma_alpha0_inv_m * in.sigma_alpha0_inv_m;
  P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) =
      Mat3::Identity() * in.sigma_vartheta0_inv_s * in.sigma_vartheta0_inv_s;
}

// A fault is usually detected within a second of its start: the snapshot used is at least kWarmRestartLagS old,
// so that the estimate it had already corrupted is not reused.
void RestartPolicy::applyWarmPrior(double t_now_s, State* x, ErrorCov* P) {
  if (!params_.init.warm_restart) return;
  const GoodSnapshot* best = nullptr;
  for (const GoodSnapshot& g : good_history_) {
    const double age_s = t_now_s - g.t_s;
    if (g.valid && age_s >= kWarmRestartLagS && age_s <= params_.init.warm_restart_max_age_s &&
        (best == nullptr || g.t_s > best->t_s)) {
      best = &g;
    }
  }
  if (best == nullptr) return;
  x->alpha = best->x.alpha;
  // The remembered distance is at most warm_restart_max_age_s old: a relative 1-sigma, not the wide start-up
  // one. With the wide one, the first updates at speed explain the unknown velocity by a wrong distance.
  const double sigma_alpha = params_.init.warm_restart_sigma_alpha_relative * x->alpha;
  (*P)(ErrIdx::kAlpha, ErrIdx::kAlpha) = sigma_alpha * sigma_alpha;
  x->mu = best->x.mu;
  x->g = best->x.g;
  x->b_a = best->x.b_a;
  x->b_w = best->x.b_w;
  warm_started_ = true;
}

void RestartPolicy::rememberGood(double t_s, const State& x) {
  GoodSnapshot* newest = nullptr;
  GoodSnapshot* oldest = &good_history_[0];
  for (GoodSnapshot& g : good_history_) {
    if (g.valid && (newest == nullptr || g.t_s > newest->t_s)) newest = &g;
    if (!g.valid || (oldest->valid && g.t_s < oldest->t_s)) oldest = &g;
  }
  if (newest != nullptr && t_s - newest->t_s < kSnapshotSpacingS && t_s >= newest->t_s) return;
  oldest->valid = true;
  oldest->t_s = t_s;
  oldest->x = x;
}

void RestartPolicy::forgetHistory() {
  for (GoodSnapshot& g : good_history_) g.valid = false;
}

}  // namespace internal
}  // namespace diekf
