#include "image_update.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace internal {

double maxPhotometricRms(double max_rms, double noise_floor_sigma) {
  const double floor_var = std::clamp(noise_floor_sigma * noise_floor_sigma, 0.0, 2.0);  // unrelated images: 2
  return std::sqrt(floor_var + 0.5 * max_rms * max_rms * (2.0 - floor_var));
}

PhotometricParams ImageUpdate::photometricParamsFor(const EstimatorParams& p) {
  PhotometricParams pp = p.photometric;
  if (p.mode == UpdateMode::kEkf) pp.max_passes = 1;
  return pp;
}

ImageUpdate::ImageUpdate(const CameraModel& camera, const EstimatorParams& params, const ImagePreprocessor& pre)
    : params_(params),
      pre_(pre),
      photometric_(photometricParamsFor(params), params.preprocess),
      feature_(params.feature, photometricParamsFor(params)) {
  photometric_.setPreprocessNoise(pre.noiseVarianceGain(), pre.noiseCorrelationAreaPx());
  // Rolling shutter (docs/algorithm.md section 3.7): each working row's mean raw row through the distortion.
  readout_row_weight_ = readoutRowWeights(camera, pre.workingK());
  // ... and each pixel's own (the distortion bends the raw rows).
  readout_pixel_weight_ = readoutPixelWeights(camera, pre.workingK());
  readout_configured_ = configuredLineDelay_s(params, camera) > 0.0;
}

bool ImageUpdate::usable(const cv::Mat& gray8, std::string* why) const {
  cv::Scalar mean, stddev;
  cv::meanStdDev(gray8, mean, stddev);
  const int total = gray8.rows * gray8.cols;
  int clipped = 0;
  for (int y = 0; y < gray8.rows; ++y) {
    const uint8_t* row = gray8.ptr<uint8_t>(y);
    int x = 0;
    {
      // 16 pixels at a time: a clipped pixel's lane is 0xFF in the mask, -1 as a signed byte, widened and
      // summed in 32-bit lanes.
      using namespace cv;
      const v_uint8x16 black = v_setzero_u8(), white = v_setall_u8(255);
      v_int32x4 count = v_setzero_s32();
      for (; x + 16 <= gray8.cols; x += 16) {
        const v_uint8x16 p = v_load(row + x);
        v_int16x8 lo, hi;
        v_expand(v_reinterpret_as_s8((p == black) | (p == white)), lo, hi);
        count -= v_dotprod(lo + hi, v_setall_s16(1));
      }
      clipped += v_reduce_sum(count);
    }
    for (; x < gray8.cols; ++x) clipped += (row[x] == 0 || row[x] == 255) ? 1 : 0;
  }
  const double unclipped = total > 0 ? 1.0 - static_cast<double>(clipped) / total : 0.0;
  if (unclipped >= params_.input.min_unclipped_ratio && stddev[0] >= params_.input.min_image_contrast_grey)
    return true;
  std::ostringstream os;
  if (unclipped < params_.input.min_unclipped_ratio) {
    os << "image unusable: " << static_cast<int>(std::lround(100.0 * (1.0 - unclipped)))
       << " % of the pixels black or saturated (mean grey " << std::lround(mean[0]) << ")";
  } else {
    os << "image unusable: no texture (grey-level std " << stddev[0] << " below "
       << params_.input.min_image_contrast_grey << ")";
  }
  *why = os.str();
  return false;
}

// The focal-length scale (section 3.8): it is seen through the dynamics of the states it is taken for (the gyro
// bias and vartheta), which must have converged first, and through the gyro's rotation of the image, which a time
// offset still uncertain by a few ms mis-predicts as much (over the slow start of the simulated flights a 3 ms
// offset error was taken for a 5-10 % focal error, which the later turns did not undo).
bool ImageUpdate::estimatesFocalScale(double t_img_s, const HealthMonitor& health, const ErrorCov& P) const {
  return params_.estimate_focal_scale && timeStatesSettled(t_img_s, health) &&
         offsetKnownTo(P, params_.focal_start_sigma_time_offset_s);
}

// The time offset (docs/algorithm.md section 3.6): the state's rates at its time and the change of the filtered
// rate over the interval. Only once the distance has converged and time_offset_start_s later (and not from frames
// the innovation test flags: PhotometricUpdate): before that the state's rates in m are unknown themselves, and
// the offset absorbed the start-up transient (a 15 ms offset was estimated at 36 ms within 0.5 s of a start at
// 1 m/s, then divergence; on a clean fast flight a dash just after convergence moved it to -37 ms, truth 0). Not
// while degraded was tried too: realistic flights are often degraded (exposure steps), and a wrong offset keeps
// the status degraded, so it was never corrected (5 sigma off). A rolling shutter (section 3.7) needs the same
// rates for its rows' times.
ImageTiming ImageUpdate::timingFor(double t_img_s, const ImuPropagator& imu, const HealthMonitor& health,
                                   const State& x, const ErrorCov& P) {
  ImageTiming timing;
  const bool settled = timeStatesSettled(t_img_s, health);
  timing.estimate_offset = params_.estimate_time_offset && settled;
  timing.consider_offset = params_.estimate_time_offset && !settled && health.converged() &&
                           params_.time_offset_consider;
  timing.row_weight = readout_row_weight_.data();
  timing.rows = static_cast<int>(readout_row_weight_.size());
  timing.pixel_weight = &readout_pixel_weight_;
  // The readout with the offset (by default) or once the offset is known to readout_start_sigma_time_offset_s.
  // Waiting for 3 ms was the default until session 51: before the offset's column took the expected rates and the
  // readout was considered until estimated, a 20 ms offset on a global-shutter flight was partly taken for a 19 ms
  // readout; since, both together find both (test RollingShutter.TheReadoutStartsWithTheOffset), and the wait left
  // a slow flight over sparse ground with the rolling shutter taken for an offset (docs/results.md).
  // An unknown readout from the first image (readout_from_first_image; docs/algorithm.md section 3.7, "From the first
  // image"): waiting for the offset left an unknown 16 ms readout unmodelled through a take-off, which it kept from
  // converging (fast flights of 5 s: 6.3 cm mean distance RMSE against 0.5 cm rendered global-shutter).
  const double readout_start_s = params_.readout_start_sigma_time_offset_s;
  timing.estimate_readout =
      readoutFromFirstImage() ||
      (params_.estimate_readout && settled && (readout_start_s <= 0.0 || offsetKnownTo(P, readout_start_s)));
  // Until then, from convergence, a consider state (docs/algorithm.md section 3.7): its column widens the update,
  // its estimate and variance are held, so a rolling shutter not yet modelled is not taken for motion.
  timing.consider_readout = params_.estimate_readout && params_.readout_consider && !timing.estimate_readout &&
                            health.converged();
  // From convergence the offset's column widens the update: a readout estimated from the first image then goes on
  // with it instead of being held with the offset (readout_with_considered_offset; docs/algorithm.md section 3.7).
  timing.readout_with_considered_offset =
      timing.consider_offset && timing.estimate_readout && params_.readout_with_considered_offset;
  timing.rates_valid = timing.estimate_offset || timing.consider_offset || timing.estimate_readout ||
                       timing.consider_readout || x.readout_s != 0.0;
  timing.estimate_focal_scale = estimatesFocalScale(t_img_s, health, P);
  timing.consider_focal_scale = params_.focal_scale_consider;
  // The gyro's noise in the interval's rotation (docs/noise_model.md section 6), measured from its samples.
  timing.gyro_noise_density_sq = imu.gyroNoiseDensitySq();
  if (timing.rates_valid) {
    timing.accel_C = imu.imuAt(imu.stateTime()).accel_mps2;
    timing.rate_change_C = imu.rateChangeSinceReference(t_img_s);
    // Their noise: one sample's (the acceleration's, with the gravity direction's and the bias's uncertainty),
    // two samples' (the rate change: the samples a frame apart are uncorrelated after the low-pass).
    const Mat3 N_g = x.g.N() * P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) * x.g.N().transpose();
    timing.accel_noise_var = imu.accelSampleVariance() +
                             params_.imu.gravity_mps2 * params_.imu.gravity_mps2 * N_g.diagonal() +
                             P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa).diagonal();
    timing.rate_change_noise_var = 2.0 * imu.gyroSampleVariance();
    timing.gravity_mps2 = params_.imu.gravity_mps2;
    // The readings' power over the recent frames, against which their noise is weighed (docs/algorithm.md section
    // 3.7, "The rates' expected values"): one reading's own square is noise too, and in a hover it left a regressor of
    // noise that pulled the readout toward 0 (flight 2 of seed 2, 16 ms: 14.7 -> 11.3 +- 0.9 ms over 10 s).
    if (params_.rates_window_s > 0.0)
      timing.rate_change_mean_sq = rate_change_power_.add(timing.rate_change_C, t_img_s, params_.rates_window_s);
  }
  return timing;
}

UpdateStats ImageUpdate::apply(const PreprocessedFrame& ref, const PreprocessedFrame& cur, double t_img_s,
                               const ImuPropagator& imu, double last_imu_gap_end_s, HealthMonitor* health,
                               State* x_io, ErrorCov* P_io, std::string* skip_reason) {
  State& x = *x_io;
  ErrorCov& P = *P_io;
  UpdateStats stats;
  const double dt = cur.t_s - ref.t_s;
  const double state_lag = std::max(0.0, cur.t_s - imu.stateTime());  // the state's time before the image, s
  // Mean gyro over the whole interval: what was integrated so far plus the samples up to the image.
  const Vec3 gyro_mean = imu.meanGyroOverInterval(t_img_s);
  last_pair_photometric_ = false;
  last_gyro_mean_ = gyro_mean;
  last_interval_s_ = dt;
  if (dt > params_.input.max_frame_interval_s) {
    std::ostringstream os;
    os << "update skipped: " << dt << " s since the reference image (max_frame_interval_s = "
       << params_.input.max_frame_interval_s << " s); this image is the new reference";
    *skip_reason = os.str();
  } else if (ref.t_s < last_imu_gap_end_s) {
    // The gyro over the interval is unknown (held across the gap): the warp cannot be predicted.
    *skip_reason = "update skipped: the image interval spans a bridged IMU gap; this image is the new reference";
    health->noteDegraded(t_img_s, "IMU gap bridged: covariance grown, one image pair skipped");
  } else if (params_.mode == UpdateMode::kFeature) {
    stats = feature_.update(ref, cur, pre_.workingK(), gyro_mean, dt, &x, &P, state_lag);
  } else {
    const State x_prior = x;
    const ErrorCov P_prior = P;
    const ImageTiming timing = timingFor(t_img_s, imu, *health, x, P);
    last_pair_photometric_ = true;
    stats = photometric_.update(ref, cur, pre_.workingK(), gyro_mean, dt, &x, &P, state_lag, timing);
    x.t_d_s = std::clamp(x.t_d_s, -params_.max_time_offset_s, params_.max_time_offset_s);
    x.readout_s = std::clamp(x.readout_s, -params_.max_readout_s, params_.max_readout_s);
    x.focal_scale = std::clamp(x.focal_scale, -params_.max_focal_scale, params_.max_focal_scale);
    // alpha's step in prior sigmas: d must never jump by many sigma in one frame.
    const double step_sigma =
        std::abs(x.alpha - x_prior.alpha) / std::sqrt(std::max(1e-300, P_prior(ErrIdx::kAlpha, ErrIdx::kAlpha)));
    const double max_rms = maxPhotometricRms(params_.divergence.max_photometric_rms, stats.noise_floor_sigma);
    if (stats.applied && !(stats.rms_residual <= max_rms)) {
      // The images do not fit the plane model (occlusion, unrelated or corrupt image): keep the prior.
      x = x_prior;
      P = P_prior;
      stats.applied = false;
      std::ostringstream os;
      os << "update rejected: photometric RMS " << stats.rms_residual << " above " << max_rms;
      *skip_reason = os.str();
      health->noteDegraded(t_img_s, *skip_reason);
    } else if (stats.applied && !(step_sigma <= params_.divergence.max_step_sigma)) {
      x = x_prior;
      P = P_prior;
      stats.applied = false;
      std::ostringstream os;
      os << "update rejected: it moved the inverse distance by " << step_sigma << " prior sigmas (max_step_sigma = "
         << params_.divergence.max_step_sigma << ")";
      *skip_reason = os.str();
      health->noteDegraded(t_img_s, *skip_reason);
    } else if (stats.applied && stats.gated) {
      char why[kMessageCapacity];
      std::snprintf(why, sizeof(why), "update gated: NIS %.3g above %.3g, measurement down-weighted x%.3g", stats.nis,
                    params_.photometric.gate_nis, stats.gate_inflation);
      health->noteDegraded(t_img_s, why);
    }
    if (stats.applied && std::isfinite(stats.nis)) health->noteInnovation(t_img_s, dt, stats.nis);
    // Before convergence this frame's relief is reported as it is, but not remembered.
    if (!health->converged()) photometric_.forgetRelief();
  }
  if (skip_reason->empty() && !stats.applied) *skip_reason = "update skipped: too few valid pixels or non-finite system";
  return stats;
}

}  // namespace internal
}  // namespace diekf
