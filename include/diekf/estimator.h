// Estimator facade: the only class the ROS layer and the offline tools talk to. Feed raw IMU samples (IMU frame,
// 500 Hz) and images (camera clock) in any realistic interleaving; read one FrameResult per processed image.
// Single-threaded; the caller serialises calls.
#pragma once

#include <array>
#include <deque>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/params.h"
#include "diekf/state.h"

namespace diekf {

/// kDegraded: converged, but the last consistency checks failed (updates gated or rejected, residuals
/// anomalous, a bridged IMU gap); the message says which. Tracking again once they pass for
/// divergence.degraded_hold_s.
enum class FilterStatus { kInitializing, kTracking, kReset, kDegraded };
const char* toString(FilterStatus status);

/// What happened at one image.
struct FrameResult {
  double t_s = 0.0;                  ///< the image's time on the IMU clock (stamp + timeshift + stamp convention + estimated offset), s
  double stamp_s = 0.0;              ///< the image's stamp as given to addImage, s
  /// The stamp less the frame clock's time for it (input/stamp_smoothing; 0 while the clock is not fitted or the
  /// smoothing is off), s: the part of the arrival delay removed.
  double stamp_correction_s = 0.0;
  double stamp_jitter_s = 0.0;       ///< the frame clock's robust 1-sigma of the stamps about its line, s (0: not fitted)
  /// Centres of the IMU's vibration notches (imu/aliased_notch at a rate that folds the vibration), Hz; 0: none.
  std::array<double, 2> imu_notch_hz{};
  State state;                       ///< posterior state
  /// Covariance of the posterior state: the filter's, plus, along the scale direction of (alpha, vartheta), the
  /// plane's ambiguity over a scene that is not one plane (relief_sigma; photometric/relief_in_covariance), the
  /// same relative variance along vartheta alone, the velocity's (photometric/relief_in_velocity_covariance), plus
  /// the calibration's focal-length uncertainty carried through the updates and the dynamics,
  /// sigma_focal_scale^2 s s^T (photometric/focal_scale_in_covariance; s = focal_sensitivity).
  ErrorCov covariance = ErrorCov::Zero();
  /// The state's error per unit relative error e of the calibration's focal lengths (true = (1 + e) x
  /// calibration) while the focal scale is not estimated, to first order: each image update moves the state by
  /// K H (u - s), u the observed states' change that the focal error's flow equals (focalScaleMap), and each
  /// prediction step carries it by F. Zero at a start, and from the focal scale's start on (estimate_focal_scale:
  /// folded into the covariance then; docs/noise_model.md section 9, docs/algorithm.md section 3.8).
  ErrorVec focal_sensitivity = ErrorVec::Zero();
  FilterStatus status = FilterStatus::kInitializing;
  bool update_applied = false;       ///< false for the first frame after (re)start or a skipped update
  int passes = 0;                    ///< Gauss-Newton passes used
  double update_ms = 0.0;            ///< wall time of preprocessing + iterations + covariance update, ms
  double photometric_rms = 0.0;      ///< RMS residual at the last linearisation (normalised intensity units;
                                     ///< px for LK at the final estimate); see UpdateStats::rms_residual
  double valid_ratio = 0.0;          ///< fraction of pixels (or features) used
  double nis = 0.0;                  ///< normalised innovation squared of the update (chi-square(8)); 0: none
  double noise_sigma = 0.0;          ///< per-pixel photometric noise 1-sigma used (normalised units); 0: none
  double noise_correlation = 0.0;    ///< pixels per independent measurement used; 0: none
  double noise_floor_sigma = 0.0;    ///< the sensor noise's part of the residual 1-sigma (normalised units); 0: none
  double nis_scale = 1.0;            ///< innovation-based noise inflation used (>= 1)
  double gate_inflation = 1.0;       ///< noise inflation applied by the innovation gate (1: passed)
  double outlier_fraction = 0.0;     ///< share of the pixels' weight removed by the outlier weights and the
                                     ///< fixed pattern's confidence (0..1)
  /// Relative 1-sigma of the plane's distance over a scene that is not one plane (boxes, plants, movers), from
  /// the spread of the inverse depth about the plane beyond noise, smoothed (docs/noise_model.md section 13); in
  /// `covariance` when photometric/relief_in_covariance (and the velocity's relative 1-sigma when
  /// photometric/relief_in_velocity_covariance). 0: a plane, or not measured.
  double relief_sigma = 0.0;
  bool fixed_pattern_active = false; ///< the camera-fixed pattern model corrects the images (start-up done)
  double fixed_pattern_fraction = 0.0;  ///< share of the image under a strong camera-fixed pattern (0..1)
  double fixed_pattern_contrast_share = 0.0;  ///< the learned pattern's share of the image's gradient energy (0..1)
  /// The lens's radial vignetting divided out of the images, at the working image's farthest corner (relative to
  /// the principal point; 1: none). Corrected from the first significant estimate, before the start-up too.
  double vignetting_corner = 1.0;
  /// Side (raw px) of the opening that removes bright dots from the raw images (preprocess/dot_removal_px, or
  /// switched on by fixed_pattern/auto_dot_removal_px); 0: off.
  int dot_removal_px = 0;
  /// Share of the raw image (%) whose projector dots are filled from the ground around them (fixed_pattern/dot_fill,
  /// once the raw-image test found dots); 0: none.
  double dot_fill_pct = 0.0;
  /// Share of the raw image (%) divided by the projector dots' gain learned from the motion (fixed_pattern/dot_gain;
  /// then only the dots' cores stay filled, dot_fill_pct); 0: not (yet).
  double dot_gain_pct = 0.0;
  /// The projector-dot test on the raw images (fixed_pattern/dot_detect_share; docs/noise_model.md section 11): the
  /// share of the image held by bright specks that stayed on the same pixels while the ground moved, at its verdict
  /// (the dots were found when it reached dot_detect_share); -1 while the test runs, when it is off, or when it gave up
  /// (the ground's motion never qualified within its samples: the learned pattern's switch still applies).
  double projector_dot_share = -1.0;
  /// The pair's brightness change (photometric/brightness_model): current = gain reference + offset, in
  /// normalised units; 1 and 0 when not estimated.
  double brightness_gain = 1.0;
  double brightness_offset = 0.0;
  /// Bands of the rows (a rolling shutter under flickering light; docs/noise_model.md section 12): the smoothed
  /// RMS over the rows of the pair's common relative gain per row; whether such bands are found (said in
  /// `message`), and whether this update estimated the pair's gain per row (photometric/brightness_model rows, or
  /// auto while bands are found).
  double row_banding = 0.0;
  bool row_bands_found = false;
  bool row_gains = false;
  /// Brightness model levels (or auto): this pair's light or exposure changed (its mean residual), and the pair
  /// was compared as standardised (docs/noise_model.md section 12).
  bool light_change = false;
  std::string message;               ///< why initializing / reset / skipped (empty when tracking normally)
  int resets = 0;                    ///< filter restarts since construction (automatic and requested)
  std::string last_reset_reason;     ///< why the filter last restarted (empty if it never did)

  double distance_m() const { return state.distance_m(); }
  double height_m() const { return state.height_m(); }
  Vec3 velocity_mps() const { return state.velocity_mps(); }
  /// 1-sigma of distance, m (first-order from alpha's variance).
  double sigma_distance_m() const;
  /// 1-sigma of each velocity axis, m/s (first-order from alpha and vartheta).
  Vec3 sigma_velocity_mps() const;
};

class Estimator {
 public:
  Estimator(const CameraModel& camera, const EstimatorParams& params);
  ~Estimator();
  Estimator(const Estimator&) = delete;
  Estimator& operator=(const Estimator&) = delete;

  /// Raw IMU sample in the IMU frame, IMU clock. Non-finite, implausibly large, duplicated or out-of-order
  /// samples are rejected (returns false, takeWarning() says why). A stamp jumping back by more than
  /// input.time_jump_reset_s or forward by more than input.max_imu_bridge_s restarts the filter (the sample is
  /// then accepted as the first of the new run). Never throws (docs/robustness.md).
  bool addImu(const ImuSample& raw_imu);
  /// Image at the calibration resolution (8-bit grey, 16-bit grey, BGR or BGRA), stamp on the camera clock
  /// (timeshift applied inside). The image is resampled to the working size at once (converted to grey first if
  /// needed; the caller's buffer is not kept, nor copied for 8-bit grey) and processed as soon as filtered IMU
  /// data covers its stamp. Wrong size or type, non-finite, duplicated or out-of-order stamps are rejected
  /// (returns false). Never throws.
  bool addImage(double t_cam_s, const cv::Mat& image);
  /// Pops the oldest unread result; false when none is waiting.
  bool popResult(FrameResult* out);

  /// Back to the initial state; the next image becomes the new reference.
  void reset(const std::string& reason);

  const State& state() const;
  const ErrorCov& covariance() const;
  FilterStatus status() const;
  /// Time of the current state estimate (IMU clock), s.
  double stateTime() const;
  const EstimatorParams& params() const;
  /// Pinhole intrinsics of the working image.
  const PinholeK& workingK() const;
  /// Photometric residual of the last update at working resolution (CV_32FC1; empty before the first update).
  const cv::Mat& lastResidualImage() const;
  /// Outlier weights drawn from the last update's residual (CV_32FC1 in [0, 1], the residual's pixels; empty when
  /// there are none): what the next update will down-weight (docs/noise_model.md section 10).
  const cv::Mat& lastOutlierWeights() const;
  /// Human-readable reason of the last warning (rejected input etc.); empty if none since the last call.
  std::string takeWarning();
  /// Filter restarts since construction (automatic and requested) and the reason of the last one.
  int resetCount() const;
  const std::string& lastResetReason() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace diekf
