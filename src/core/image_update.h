// Internal part of the estimator (docs/algorithm.md section 9): the update of the state from one image pair
// (reference -> current working image). Decides whether an image can be used at all, runs the photometric
// (or feature) update with the pair's timing, and guards it: an update whose residual or inverse-distance step
// is implausible is undone; a gated or rejected update and an inconsistent innovation are reported to the
// health monitor.
#pragma once

#include <string>
#include <vector>

#include "diekf/camera_model.h"
#include "diekf/feature_update.h"
#include "diekf/image_preprocessor.h"
#include "diekf/params.h"
#include "diekf/photometric_update.h"
#include "diekf/state.h"
#include "expected_value.h"
#include "health_monitor.h"
#include "imu_propagator.h"

namespace diekf {
namespace internal {

/// The photometric RMS above which an applied update is undone, for images whose sensor noise alone leaves a
/// residual of `noise_floor_sigma` (UpdateStats::noise_floor_sigma; both normalised units, where unrelated images
/// give sqrt(2)). `max_rms` (divergence.max_photometric_rms) holds for noise-free images: it allows the ground's
/// residual max_rms^2 / 2 of unrelated images'. The same share of the ground's part, with the noise's part added:
/// limit^2 = floor^2 + (max_rms^2 / 2) (2 - floor^2) (docs/noise_model.md section 4).
double maxPhotometricRms(double max_rms, double noise_floor_sigma);

class ImageUpdate {
 public:
  /// `params` must outlive the update (the estimator's own copy); `pre` is the estimator's preprocessor (its
  /// working intrinsics and noise propagation).
  ImageUpdate(const CameraModel& camera, const EstimatorParams& params, const ImagePreprocessor& pre);

  /// The photometric parameters the estimator runs with (mode ekf: one pass).
  static PhotometricParams photometricParamsFor(const EstimatorParams& p);

  /// Whether the working image carries enough texture for an update (input.min_unclipped_ratio,
  /// input.min_image_contrast_grey); says why not.
  bool usable(const cv::Mat& gray8, std::string* why) const;

  /// Updates (x, P), at the propagator's state time, from the pair (ref, cur) with cur taken at t_img_s (IMU
  /// clock). Skips the pair (a new reference follows) when it is too far apart (input.max_frame_interval_s) or
  /// spans a bridged IMU gap (its first sample after the gap at last_imu_gap_end_s); undoes an applied update
  /// whose photometric RMS is above divergence.max_photometric_rms or whose inverse-distance step is above
  /// divergence.max_step_sigma prior sigmas. *skip_reason says why the update was not applied (empty: applied).
  UpdateStats apply(const PreprocessedFrame& ref, const PreprocessedFrame& cur, double t_img_s,
                    const ImuPropagator& imu, double last_imu_gap_end_s, HealthMonitor* health, State* x,
                    ErrorCov* P, std::string* skip_reason);

  /// Per-pixel confidence for the next photometric updates (PhotometricUpdate::setPixelConfidence; the camera-fixed
  /// pattern's, docs/noise_model.md section 11); null: none.
  void setPixelConfidence(const cv::Mat* confidence) { photometric_.setPixelConfidence(confidence); }
  /// Per-pixel confidence of the reference image's pixels (PhotometricUpdate::setReferenceConfidence; the projector
  /// dots' fill); null: none.
  void setReferenceConfidence(const cv::Mat* confidence) { photometric_.setReferenceConfidence(confidence); }
  /// The reference image was re-timed from from_s to to_s (a changed time offset estimate): what the photometric
  /// update keeps of it (its outlier weights) follows.
  void retimeReference(double from_s, double to_s) { photometric_.retimeWeights(from_s, to_s); }
  /// Whether the photometric updates also report the image's own vartheta (PhotometricUpdate::setReportImageVartheta).
  void setReportImageVartheta(bool on) { photometric_.setReportImageVartheta(on); }
  /// Whether the last apply() ran the photometric update on its pair (not skipped, not the feature mode), and that
  /// pair's mean raw gyro (rad/s) and interval (s).
  bool lastPairPhotometric() const { return last_pair_photometric_; }
  /// Whether the readout is estimated from the first image on: estimate_readout and readout_from_first_image, and
  /// no line delay configured (a configured one is the calibration's, kept as given until the offset's start:
  /// before convergence the images pulled a correct 16 ms to 10 ms; docs/algorithm.md section 3.7).
  bool readoutFromFirstImage() const {
    return params_.estimate_readout && params_.readout_from_first_image && !readout_configured_;
  }
  /// Whether an image at t_img_s has the time states estimated (not merely considered): the filter has converged
  /// time_offset_start_s before it.
  bool timeStatesSettled(double t_img_s, const HealthMonitor& health) const {
    return health.converged() && t_img_s - health.convergedSince() >= params_.time_offset_start_s;
  }
  /// Whether the time offset, when estimated, is known to sigma_s (its variance in P); true when it is not estimated.
  bool offsetKnownTo(const ErrorCov& P, double sigma_s) const {
    return !params_.estimate_time_offset || P(ErrIdx::kTd, ErrIdx::kTd) < sigma_s * sigma_s;
  }
  /// Whether the update of an image at t_img_s estimates the focal-length scale (docs/algorithm.md section 3.8):
  /// estimate_focal_scale, the time states settled, and the time offset (when estimated) known to
  /// focal_start_sigma_time_offset_s (its variance in P).
  bool estimatesFocalScale(double t_img_s, const HealthMonitor& health, const ErrorCov& P) const;
  const Vec3& lastGyroMean() const { return last_gyro_mean_; }
  double lastInterval() const { return last_interval_s_; }

  /// Forgets the photometric noise estimates (a new run); the outlier weights stay (PhotometricUpdate).
  void resetNoiseModel() {
    photometric_.resetNoiseModel();
    rate_change_power_.reset();
  }
  /// Forgets the outlier weights (a new run without the last image).
  void forgetWeights() { photometric_.forgetWeights(); }
  /// Residual image of the last photometric update.
  const cv::Mat& residualImage() const { return photometric_.residualImage(); }
  /// Outlier weights drawn from the last photometric update's residual (PhotometricUpdate::outlierWeights).
  const cv::Mat& outlierWeights() const { return photometric_.outlierWeights(); }

 private:
  /// The timing of the pair (docs/algorithm.md sections 3.6, 3.7): which of the time offset and the readout
  /// are estimated in this update, and the rates they need.
  ImageTiming timingFor(double t_img_s, const ImuPropagator& imu, const HealthMonitor& health, const State& x,
                        const ErrorCov& P);

  const EstimatorParams& params_;
  const ImagePreprocessor& pre_;
  PhotometricUpdate photometric_;
  FeatureUpdate feature_;
  std::vector<float> readout_row_weight_;  // per working row: its capture time per second of readout
  cv::Mat readout_pixel_weight_;           // per working pixel: readoutPixelWeights
  bool last_pair_photometric_ = false;
  bool readout_configured_ = false;  // a line delay configured (parameter or camchain): the readout's prior is known
  Vec3 last_gyro_mean_ = Vec3::Zero();
  double last_interval_s_ = 0.0;
  // The rate change's mean square over the recent frames (rates_window_s; timingFor).
  MeanSquareWindow rate_change_power_;
};

}  // namespace internal
}  // namespace diekf
