// The metrics of docs/conventions.md section 5, on estimate rows paired with true values. ROS-free.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "diekf/eval/ground_truth.h"

namespace diekf {
namespace eval {

/// One row of estimates.csv (docs/conventions.md section 4).
struct EstimateRow {
  double t_s = 0.0;                                      ///< image stamp, IMU clock, s
  double d_m = 0.0;                                      ///< distance to the plane, m
  double h_m = 0.0;                                      ///< height along gravity, m
  Eigen::Vector3d v_mps = Eigen::Vector3d::Zero();       ///< velocity in C, m/s
  Eigen::Vector3d mu = Eigen::Vector3d::UnitZ();         ///< plane normal in C
  Eigen::Vector3d g = Eigen::Vector3d::UnitZ();          ///< gravity direction in C
  double sigma_d_m = 0.0;                                ///< 1-sigma of d, m
  Eigen::Vector3d sigma_v_mps = Eigen::Vector3d::Zero(); ///< 1-sigma per velocity axis, m/s
  int iterations = 0;                                    ///< Gauss-Newton passes (0: no update at this frame)
  double update_ms = 0.0;                                ///< wall time of the image update, ms
  std::string status = "initializing";                   ///< initializing | tracking | reset

  /// An image update was applied at this frame (the CSV encodes it as iterations > 0).
  bool updateApplied() const { return iterations > 0; }
  /// Every numeric output is finite.
  bool allFinite() const;
};

struct EvaluationOptions {
  double start_delay_s = 3.0;              ///< evaluation starts this long after the first image update, s
  double divergence_window_s = 10.0;       ///< the divergence rule looks at the last this many seconds, s
  double divergence_relative_error = 0.5;  ///< |d_est - d_true| above this fraction of d_true is a bad frame
  double divergence_frame_fraction = 0.5;  ///< diverged when more than this fraction of those frames is bad
};

/// The contents of evaluation.json. Error metrics are NaN when nothing could be evaluated or the outputs are
/// non-finite (written as JSON null).
struct Evaluation {
  std::string sequence;
  int frames = 0;                  ///< frames inside the evaluation window that have a true value
  int frames_total = 0;            ///< every estimate row
  double duration_s = 0.0;         ///< sequence duration: last minus first estimate stamp, s
  double eval_start_s = 0.0;       ///< stamp where evaluation starts (first update + start delay), s
  double rmse_distance_m = 0.0;
  double rmse_height_m = 0.0;
  double rmse_velocity_mps = 0.0;  ///< RMS of the 3-D velocity error norm, m/s
  double rms_normal_deg = 0.0;
  double rms_gravity_deg = 0.0;
  double max_normal_deg = 0.0;
  double max_gravity_deg = 0.0;
  bool diverged = false;
  std::string divergence_reason;   ///< empty unless diverged
  double update_ms_mean = 0.0;     ///< over frames where an update was applied, ms
  double update_ms_median = 0.0;
  double update_ms_p99 = 0.0;
  double realtime_factor = 0.0;    ///< wall time of the whole run / duration_s (set by the caller)
  double wall_time_s = 0.0;        ///< wall time of the whole run, s (set by the caller)

  // Consistency of the reported 1-sigma (the sigma_* columns) with the actual errors, over the evaluated frames
  // whose sigma_d and sigma_v are all finite and positive. Normalised errors z_d = (d_est - d_true) / sigma_d,
  // z_v,i = (v_est,i - v_true,i) / sigma_v,i (i = x, y, z). For a consistent filter with Gaussian errors the
  // coverages are about 0.95 and the NEES about 4 (chi-square with 4 degrees of freedom).
  int consistency_frames = 0;           ///< evaluated frames that enter the consistency metrics
  int consistency_frames_excluded = 0;  ///< evaluated frames left out: a sigma non-positive or non-finite
  double coverage2_d = 0.0;             ///< fraction of frames with |z_d| <= 2
  double coverage2_v = 0.0;             ///< fraction of (frame, axis) pairs with |z_v,i| <= 2
  double nees_mean = 0.0;               ///< mean over frames of z_d^2 + sum_i z_v,i^2
  double nees_median = 0.0;             ///< median of the same
  double coverage2_d_last_half = 0.0;   ///< coverage2_d over the second half (in time) of the evaluation window
  double coverage2_v_last_half = 0.0;   ///< coverage2_v over the second half of the evaluation window
  double nees_mean_last_half = 0.0;     ///< nees_mean over the second half of the evaluation window

  // The status's honesty over the whole run, the start included (the evaluation window leaves out the first
  // seconds, where a filter may already say `tracking`): the frames with status tracking, a true value and a
  // finite positive sigma_d.
  int tracking_frames = 0;               ///< such frames
  int tracking_beyond3_d = 0;            ///< of them, those with |z_d| > 3
  double max_abs_z_d_tracking = 0.0;     ///< largest |z_d| over them (NaN when there are none)
  /// The same for the velocity, over those of the tracking frames whose three sigma_v are finite and positive:
  int tracking_beyond3_v = 0;            ///< frames with max_i |z_v,i| > 3 (about 0.8 % for consistent Gaussian errors)
  double max_abs_z_v_tracking = 0.0;     ///< largest |z_v,i| over them and the axes (NaN when there are none)
};

/// Consistency figures of one set of frames (the fields of the same names in Evaluation).
struct Consistency {
  int frames = 0;           ///< frames used (every sigma finite and positive)
  int excluded = 0;         ///< frames left out for a non-positive or non-finite sigma
  double coverage2_d = 0.0;
  double coverage2_v = 0.0;
  double nees_mean = 0.0;
  double nees_median = 0.0;
};

/// Consistency of `estimates[i]` against `truth[i]` for every index in `indices` (all must have a true value);
/// NaN figures when no frame can be used.
Consistency consistency(const std::vector<EstimateRow>& estimates,
                        const std::vector<std::optional<TruthSample>>& truth, const std::vector<std::size_t>& indices);

/// Angle between two directions, degrees (atan2 form, exact near 0 and 180; NaN for a zero vector).
double angleBetweenDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b);

/// Percentile `q` in [0, 100] by linear interpolation between order statistics; NaN for an empty input.
double percentile(std::vector<double> values, double q);

/// Evaluates `estimates` (in stamp order) against `truth` (same length; nullopt where no true value exists).
/// Throws std::invalid_argument when the lengths differ.
Evaluation evaluate(const std::vector<EstimateRow>& estimates,
                    const std::vector<std::optional<TruthSample>>& truth,
                    const EvaluationOptions& options = EvaluationOptions());

}  // namespace eval
}  // namespace diekf
