#include "diekf/eval/metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace diekf {
namespace eval {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

}  // namespace

bool EstimateRow::allFinite() const {
  return std::isfinite(t_s) && std::isfinite(d_m) && std::isfinite(h_m) && v_mps.allFinite() && mu.allFinite() &&
         g.allFinite() && std::isfinite(sigma_d_m) && sigma_v_mps.allFinite() && std::isfinite(update_ms);
}

double angleBetweenDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const double na = a.norm();
  const double nb = b.norm();
  if (!(na > 0.0) || !(nb > 0.0) || !a.allFinite() || !b.allFinite()) return kNaN;
  return std::atan2(a.cross(b).norm(), a.dot(b)) * kRadToDeg;
}

double percentile(std::vector<double> values, double q) {
  if (values.empty()) return kNaN;
  std::sort(values.begin(), values.end());
  const double pos = std::clamp(q, 0.0, 100.0) / 100.0 * static_cast<double>(values.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(values.size() - 1, lo + 1);
  const double frac = pos - static_cast<double>(lo);
  return values[lo] + frac * (values[hi] - values[lo]);
}

Consistency consistency(const std::vector<EstimateRow>& estimates,
                        const std::vector<std::optional<TruthSample>>& truth, const std::vector<std::size_t>& indices) {
  Consistency c;
  c.coverage2_d = c.coverage2_v = c.nees_mean = c.nees_median = kNaN;
  std::vector<double> nees;
  int inside_d = 0, inside_v = 0;
  for (std::size_t i : indices) {
    const EstimateRow& est = estimates.at(i);
    const std::optional<TruthSample>& tr = truth.at(i);
    if (!tr) continue;
    const bool sigma_ok = std::isfinite(est.sigma_d_m) && est.sigma_d_m > 0.0 && est.sigma_v_mps.allFinite() &&
                          (est.sigma_v_mps.array() > 0.0).all();
    if (!sigma_ok) {
      ++c.excluded;
      continue;
    }
    const double zd = (est.d_m - tr->d_m) / est.sigma_d_m;
    const Eigen::Vector3d zv = (est.v_mps - tr->v_C_mps).cwiseQuotient(est.sigma_v_mps);
    // A NaN estimate is outside every band (and makes the NEES NaN, as it makes the RMSE NaN).
    if (std::abs(zd) <= 2.0) ++inside_d;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(zv[k]) <= 2.0) ++inside_v;
    }
    nees.push_back(zd * zd + zv.squaredNorm());
  }
  c.frames = static_cast<int>(nees.size());
  if (c.frames == 0) return c;
  const double n = static_cast<double>(c.frames);
  c.coverage2_d = static_cast<double>(inside_d) / n;
  c.coverage2_v = static_cast<double>(inside_v) / (3.0 * n);
  double sum = 0.0;
  for (double v : nees) sum += v;
  c.nees_mean = sum / n;
  // percentile() sorts, which puts NaN anywhere; a NaN NEES makes the median NaN too.
  bool any_nan = false;
  for (double v : nees) any_nan = any_nan || std::isnan(v);
  c.nees_median = any_nan ? kNaN : percentile(nees, 50.0);
  return c;
}

Evaluation evaluate(const std::vector<EstimateRow>& estimates, const std::vector<std::optional<TruthSample>>& truth,
                    const EvaluationOptions& options) {
  if (estimates.size() != truth.size()) {
    throw std::invalid_argument("evaluate: " + std::to_string(estimates.size()) + " estimates but " +
                                std::to_string(truth.size()) + " true values");
  }
  Evaluation ev;
  ev.frames_total = static_cast<int>(estimates.size());
  ev.rmse_distance_m = ev.rmse_height_m = ev.rmse_velocity_mps = kNaN;
  ev.rms_normal_deg = ev.rms_gravity_deg = ev.max_normal_deg = ev.max_gravity_deg = kNaN;
  ev.update_ms_mean = ev.update_ms_median = ev.update_ms_p99 = kNaN;
  ev.coverage2_d = ev.coverage2_v = ev.nees_mean = ev.nees_median = kNaN;
  ev.coverage2_d_last_half = ev.coverage2_v_last_half = ev.nees_mean_last_half = kNaN;
  ev.max_abs_z_d_tracking = ev.max_abs_z_v_tracking = kNaN;
  ev.eval_start_s = kNaN;
  if (estimates.empty()) {
    ev.diverged = true;
    ev.divergence_reason = "no estimates";
    return ev;
  }
  ev.duration_s = estimates.back().t_s - estimates.front().t_s;

  // Timing over every frame with an applied update.
  std::vector<double> update_ms;
  for (const EstimateRow& row : estimates) {
    if (row.updateApplied()) update_ms.push_back(row.update_ms);
  }
  if (!update_ms.empty()) {
    double sum = 0.0;
    for (double v : update_ms) sum += v;
    ev.update_ms_mean = sum / static_cast<double>(update_ms.size());
    ev.update_ms_median = percentile(update_ms, 50.0);
    ev.update_ms_p99 = percentile(update_ms, 99.0);
  }

  // The status's honesty over the whole run: |z_d| and the largest |z_v,i| on every frame that says tracking.
  int tracking_frames_v = 0;
  for (std::size_t i = 0; i < estimates.size(); ++i) {
    const EstimateRow& row = estimates[i];
    if (row.status != "tracking" || !truth[i] || !std::isfinite(row.sigma_d_m) || !(row.sigma_d_m > 0.0)) continue;
    const double z = std::abs(row.d_m - truth[i]->d_m) / row.sigma_d_m;
    ++ev.tracking_frames;
    if (z > 3.0) ++ev.tracking_beyond3_d;
    ev.max_abs_z_d_tracking = (ev.tracking_frames == 1 || std::isnan(z) || z > ev.max_abs_z_d_tracking)
                                  ? z : ev.max_abs_z_d_tracking;
    if (!row.sigma_v_mps.allFinite() || !(row.sigma_v_mps.minCoeff() > 0.0)) continue;
    const double zv = ((row.v_mps - truth[i]->v_C_mps).cwiseAbs().cwiseQuotient(row.sigma_v_mps)).maxCoeff();
    ++tracking_frames_v;
    if (zv > 3.0) ++ev.tracking_beyond3_v;
    ev.max_abs_z_v_tracking = (tracking_frames_v == 1 || std::isnan(zv) || zv > ev.max_abs_z_v_tracking)
                                  ? zv : ev.max_abs_z_v_tracking;
  }

  // Non-finite output anywhere: diverged.
  for (const EstimateRow& row : estimates) {
    if (!row.allFinite()) {
      ev.diverged = true;
      std::ostringstream reason;
      reason << "non-finite output at t = " << row.t_s << " s";
      ev.divergence_reason = reason.str();
      break;
    }
  }

  // Evaluation window: from the first applied update + start delay to the last estimate.
  const auto first_update = std::find_if(estimates.begin(), estimates.end(),
                                         [](const EstimateRow& r) { return r.updateApplied(); });
  if (first_update == estimates.end()) {
    if (!ev.diverged) {
      ev.diverged = true;
      ev.divergence_reason = "no image update was ever applied";
    }
    return ev;
  }
  ev.eval_start_s = first_update->t_s + options.start_delay_s;
  const double t_end = estimates.back().t_s;

  double sum_d2 = 0.0, sum_h2 = 0.0, sum_v2 = 0.0, sum_mu2 = 0.0, sum_g2 = 0.0;
  double max_mu = 0.0, max_g = 0.0;
  int n = 0;
  int window_frames = 0, window_bad = 0;
  std::vector<std::size_t> evaluated;  // indices of the evaluated frames, for the consistency metrics
  for (std::size_t i = 0; i < estimates.size(); ++i) {
    const EstimateRow& est = estimates[i];
    if (!truth[i] || est.t_s < ev.eval_start_s) continue;
    evaluated.push_back(i);
    const TruthSample& tr = *truth[i];
    const double ed = est.d_m - tr.d_m;
    const double eh = est.h_m - tr.h_m;
    const double ev2 = (est.v_mps - tr.v_C_mps).squaredNorm();
    const double emu = angleBetweenDeg(est.mu, tr.mu_C);
    const double eg = angleBetweenDeg(est.g, tr.g_C);
    sum_d2 += ed * ed;
    sum_h2 += eh * eh;
    sum_v2 += ev2;
    sum_mu2 += emu * emu;
    sum_g2 += eg * eg;
    // std::max would drop a NaN; keep it visible.
    max_mu = (std::isnan(emu) || emu > max_mu) ? emu : max_mu;
    max_g = (std::isnan(eg) || eg > max_g) ? eg : max_g;
    ++n;
    if (est.t_s >= t_end - options.divergence_window_s) {
      ++window_frames;
      if (!(std::abs(ed) <= options.divergence_relative_error * std::abs(tr.d_m))) ++window_bad;
    }
  }
  ev.frames = n;
  if (n > 0) {
    const double dn = static_cast<double>(n);
    ev.rmse_distance_m = std::sqrt(sum_d2 / dn);
    ev.rmse_height_m = std::sqrt(sum_h2 / dn);
    ev.rmse_velocity_mps = std::sqrt(sum_v2 / dn);
    ev.rms_normal_deg = std::sqrt(sum_mu2 / dn);
    ev.rms_gravity_deg = std::sqrt(sum_g2 / dn);
    ev.max_normal_deg = max_mu;
    ev.max_gravity_deg = max_g;
  }

  // Consistency over the evaluated frames, and over those in the second half (in time) of the window.
  const Consistency all = consistency(estimates, truth, evaluated);
  ev.consistency_frames = all.frames;
  ev.consistency_frames_excluded = all.excluded;
  ev.coverage2_d = all.coverage2_d;
  ev.coverage2_v = all.coverage2_v;
  ev.nees_mean = all.nees_mean;
  ev.nees_median = all.nees_median;
  const double t_half = ev.eval_start_s + 0.5 * (t_end - ev.eval_start_s);
  std::vector<std::size_t> last_half;
  for (std::size_t i : evaluated) {
    if (estimates[i].t_s >= t_half) last_half.push_back(i);
  }
  const Consistency late = consistency(estimates, truth, last_half);
  ev.coverage2_d_last_half = late.coverage2_d;
  ev.coverage2_v_last_half = late.coverage2_v;
  ev.nees_mean_last_half = late.nees_mean;
  if (!ev.diverged && window_frames > 0 &&
      static_cast<double>(window_bad) > options.divergence_frame_fraction * static_cast<double>(window_frames)) {
    ev.diverged = true;
    std::ostringstream reason;
    reason << "distance error above " << options.divergence_relative_error * 100.0 << " % of the true distance on "
           << window_bad << " of " << window_frames << " frames in the last " << options.divergence_window_s
           << " s";
    ev.divergence_reason = reason.str();
  }
  return ev;
}

}  // namespace eval
}  // namespace diekf
