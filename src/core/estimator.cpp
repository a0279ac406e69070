#include "diekf/estimator.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "diekf/feature_update.h"
#include "diekf/grey_image.h"
#include "diekf/fixed_pattern.h"
#include "diekf/image_preprocessor.h"
#include "diekf/imu_filter.h"
#include "diekf/photometric_update.h"
#include "diekf/prediction.h"
#include "gauss_newton.h"
#include "imu_propagation.h"

namespace diekf {

const char* toString(FilterStatus status) {
  switch (status) {
    case FilterStatus::kInitializing:
      return "initializing";
    case FilterStatus::kTracking:
      return "tracking";
    case FilterStatus::kReset:
      return "reset";
    case FilterStatus::kDegraded:
      return "degraded";
  }
  return "unknown";
}

double FrameResult::sigma_distance_m() const {
  // d = 1/alpha  =>  sigma_d = sigma_alpha / alpha^2.
  const double var_alpha = std::max(0.0, covariance(ErrIdx::kAlpha, ErrIdx::kAlpha));
  return std::sqrt(var_alpha) / (state.alpha * state.alpha);
}

Vec3 FrameResult::sigma_velocity_mps() const {
  // v = vartheta / alpha  =>  dv = dvartheta / alpha - vartheta / alpha^2 dalpha.
  Eigen::Matrix<double, 3, 4> J;
  J.col(0) = -state.vartheta / (state.alpha * state.alpha);
  J.rightCols<3>() = Mat3::Identity() / state.alpha;
  const Eigen::Matrix4d S = covariance.topLeftCorner<4, 4>();
  const Mat3 C = J * S * J.transpose();
  return C.diagonal().cwiseMax(0.0).cwiseSqrt();
}

namespace {

/// Fixed-capacity ring buffer (no allocation after construction).
template <typename T>
class Ring {
 public:
  explicit Ring(size_t capacity) : data_(capacity) {}
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == data_.size(); }
  T& operator[](size_t i) { return data_[(head_ + i) % data_.size()]; }
  const T& operator[](size_t i) const { return data_[(head_ + i) % data_.size()]; }
  const T& back() const { return (*this)[size_ - 1]; }
  /// Appends; drops the oldest element when full.
  void push(const T& value) {
    if (full()) pop();
    data_[(head_ + size_) % data_.size()] = value;
    ++size_;
  }
  /// Slot for a new element at the back (caller fills it in place).
  T& emplaceSlot() {
    if (full()) pop();
    ++size_;
    return data_[(head_ + size_ - 1) % data_.size()];
  }
  void pop() {
    head_ = (head_ + 1) % data_.size();
    --size_;
  }
  void clear() { head_ = size_ = 0; }

 private:
  std::vector<T> data_;
  size_t head_ = 0, size_ = 0;
};

struct PendingImage {
  double t_s = 0.0;      // IMU clock
  double stamp_s = 0.0;  // the stamp it was given (camera clock)
  cv::Mat gray;      // CV_8UC1 at calibration resolution (reused buffer)
};

constexpr size_t kImuBufferCapacity = 1024;  // filtered samples (about 10 s at 100 Hz)
constexpr size_t kResultCapacity = 64;       // unread results kept (oldest dropped): nobody reads, memory bounded
constexpr size_t kMessageCapacity = 160;     // chars reserved per result message (formatted without allocation)
constexpr double kReportOutlierFraction = 0.05;  // outlier weight share named in the status message

}  // namespace

struct Estimator::Impl {
  Impl(const CameraModel& cam, const EstimatorParams& p)
      : camera(cam),
        params(p),
        imu_pre(cam.T_cam_imu, p.imu),
        img_pre(cam, preprocessParamsFor(p)),
        photometric(photometricParamsFor(p), p.preprocess),
        fixed_pattern(p.fixed_pattern, img_pre.workingSize().width, img_pre.workingSize().height,
                      p.fixed_pattern.vignetting_file.empty()
                          ? cv::Mat()
                          : loadFlatField(p.fixed_pattern.vignetting_file, cam, preprocessParamsFor(p))),
        feature(p.feature, photometricParamsFor(p)),
        imu_buffer(kImuBufferCapacity),
        images(static_cast<size_t>(std::max(1, p.max_queued_images))),
        results(kResultCapacity) {
    // Result slots keep their message buffers: no allocation per frame for the usual messages.
    for (size_t i = 0; i < kResultCapacity; ++i) {
      FrameResult& slot = results.emplaceSlot();
      slot.message.reserve(kMessageCapacity);
      slot.last_reset_reason.reserve(kMessageCapacity);
    }
    results.clear();
    photometric.setPreprocessNoise(img_pre.noiseVarianceGain(), img_pre.noiseCorrelationAreaPx());
    // Rolling shutter (docs/algorithm.md section 3.7): each working row's mean raw row through the distortion,
    // the stamp at the middle raw row.
    const double line_delay_raw_s = p.line_delay_s > 0.0 ? p.line_delay_s : cam.line_delay_s;
    configured_readout_s = line_delay_raw_s * std::max(0, cam.K.height - 1);
    readout_row_weight = readoutRowWeights(cam, img_pre.workingK());
    stamp_shift_s = imageStampShift(p.image_stamp, p.exposure_time_s, configured_readout_s);
    resetFilter();
  }

  static PreprocessParams preprocessParamsFor(const EstimatorParams& p) {
    PreprocessParams pp = p.preprocess;
    if (p.mode == UpdateMode::kFeature) {
      pp.working_width_px = p.feature.working_width_px;
      pp.working_height_px = 0;
    }
    return pp;
  }
  static PhotometricParams photometricParamsFor(const EstimatorParams& p) {
    PhotometricParams pp = p.photometric;
    if (p.mode == UpdateMode::kEkf) pp.max_passes = 1;
    return pp;
  }

  void warn(const std::string& text) {
    if (!warning.empty()) warning += "; ";
    warning += text;
  }

  /// Initial state and covariance from the parameters (gravity from the accelerometer when available).
  void resetFilter() {
    const InitParams& in = params.init;
    // The time offset is a property of the sensors, not of the flight: a restart keeps a converged estimate
    // (with the initial 1-sigma around it), otherwise it starts at the calibration's (0 on top of it).
    const bool keep_t_d = converged && std::isfinite(x.t_d_s);
    const double t_d_s = keep_t_d ? x.t_d_s : 0.0;
    const bool keep_readout = converged && params.estimate_readout && std::isfinite(x.readout_s);
    const double readout_s = keep_readout ? x.readout_s : configured_readout_s;
    x = State();
    x.t_d_s = t_d_s;
    x.readout_s = readout_s;
    x.alpha = in.alpha0_inv_m;
    x.vartheta = in.vartheta0_inv_s;
    x.mu = UnitVector(in.mu0);
    x.g = UnitVector(in.g0);
    P.setZero();
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = in.sigma_alpha0_inv_m * in.sigma_alpha0_inv_m;
    P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) =
        Mat3::Identity() * in.sigma_vartheta0_inv_s * in.sigma_vartheta0_inv_s;
    P.block<2, 2>(ErrIdx::kMu, ErrIdx::kMu) = Mat2::Identity() * in.sigma_mu0_rad * in.sigma_mu0_rad;
    P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = Mat2::Identity() * in.sigma_g0_rad * in.sigma_g0_rad;
    P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa) = Mat3::Identity() * in.sigma_ba0_mps2 * in.sigma_ba0_mps2;
    P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw) = Mat3::Identity() * in.sigma_bw0_radps * in.sigma_bw0_radps;
    P(ErrIdx::kTd, ErrIdx::kTd) = in.sigma_time_offset_s * in.sigma_time_offset_s;
    P(ErrIdx::kRo, ErrIdx::kRo) = in.sigma_readout_s * in.sigma_readout_s;
    have_reference = false;
    state_initialized = false;
    gyro_integral = Vec3::Zero();
    gyro_time_s = 0.0;
    bad_frames = 0;
    updates_since_reset = 0;
    converged = false;
    converged_since_s = HUGE_VAL;
    skip_reason.clear();
    warm_started = false;
    photometric.resetNoiseModel();
    nis_smoothed = 0.0;
    degraded_until_s = -HUGE_VAL;
    degraded_reason[0] = '\0';
  }

  /// Gravity direction from the mean specific force of the recent filtered samples (if the vehicle is near
  /// rest: |mean| within 10 % of g). Specific force at rest points up, gravity down: g = -f/|f|.
  bool gravityFromAccel(double up_to_t_s, UnitVector* g) const {
    Vec3 sum = Vec3::Zero();
    int n = 0;
    for (size_t i = imu_buffer.size(); i-- > 0;) {
      const ImuSample& s = imu_buffer[i];
      if (s.t_s > up_to_t_s) continue;
      if (up_to_t_s - s.t_s > 0.5) break;
      sum += s.accel_mps2;
      ++n;
    }
    if (n == 0) return false;
    const Vec3 f = sum / n;
    const double g0 = params.imu.gravity_mps2;
    if (!f.allFinite() || std::abs(f.norm() - g0) > 0.1 * g0) return false;
    *g = UnitVector(-f);
    return true;
  }

  /// Nominal period of the filtered samples, s.
  double filteredPeriod() const {
    return std::max(1, params.imu.decimation_factor) / std::max(1e-9, params.imu.input_rate_hz);
  }

  /// Integral of the filtered gyro over (t0, t1] with the interpolation of propagateTo, rad.
  Vec3 gyroIntegral(double t0, double t1) const {
    Vec3 sum = Vec3::Zero();
    internal::forEachImuPiece(imu_buffer, t0, t1, 2.0 * filteredPeriod(),
                              [&](double a_s, double b_s, const ImuSample& in) { sum += in.gyro_radps * (b_s - a_s); });
    return sum;
  }

  /// The filtered IMU sample at t_s: linear interpolation between the buffered samples around it (the nearest
  /// one outside the buffer's span).
  ImuSample imuAt(double t_s) const {
    ImuSample out;
    out.t_s = t_s;
    if (imu_buffer.empty()) return out;
    size_t i = 0;
    while (i < imu_buffer.size() && imu_buffer[i].t_s < t_s) ++i;
    if (i == 0 || i == imu_buffer.size()) {
      const ImuSample& s = imu_buffer[i == 0 ? 0 : imu_buffer.size() - 1];
      out.accel_mps2 = s.accel_mps2;
      out.gyro_radps = s.gyro_radps;
      return out;
    }
    const ImuSample& a = imu_buffer[i - 1];
    const ImuSample& b = imu_buffer[i];
    const double u = b.t_s > a.t_s ? (t_s - a.t_s) / (b.t_s - a.t_s) : 1.0;
    out.accel_mps2 = a.accel_mps2 + u * (b.accel_mps2 - a.accel_mps2);
    out.gyro_radps = a.gyro_radps + u * (b.gyro_radps - a.gyro_radps);
    return out;
  }

  /// Propagates the state from t_state to t_target with the filtered samples, split at their stamps. Each step
  /// is fed the mean of the linear interpolation between the samples around it (internal::forEachImuPiece);
  /// across a bridged IMU gap the sample after it is held (zero-order hold) and the gap is integrated in steps
  /// of at most one nominal period. Accumulates the gyro integral for the update.
  void propagateTo(double t_target) {
    const double nominal_dt_s = filteredPeriod();
    internal::forEachImuPiece(imu_buffer, t_state_s, t_target, 2.0 * nominal_dt_s,
                              [&](double t0_s, double t1_s, const ImuSample& s) {
      const double dt = t1_s - t0_s;
      const bool gap = dt > 2.0 * nominal_dt_s;
      const int steps = gap ? static_cast<int>(std::ceil(dt / nominal_dt_s)) : 1;
      const double h = dt / steps;
      // Across a bridged IMU gap the held sample stands for unknown motion: an unknown acceleration and rate
      // change, constant over the gap, add variance (sigma T)^2, i.e. a white-noise density sigma^2 T.
      ImuParams imu = params.imu;
      if (gap) {
        imu.accel_noise_density = std::sqrt(imu.accel_noise_density * imu.accel_noise_density +
                                            params.input.gap_accel_sigma_mps2 * params.input.gap_accel_sigma_mps2 * dt);
        imu.gyro_noise_density = std::sqrt(imu.gyro_noise_density * imu.gyro_noise_density +
                                           params.input.gap_gyro_sigma_radps * params.input.gap_gyro_sigma_radps * dt);
      }
      for (int k = 0; k < steps; ++k) predict(s.accel_mps2, s.gyro_radps, h, imu, params.process, &x, &P);
      gyro_integral += s.gyro_radps * dt;
      gyro_time_s += dt;
    });
    t_state_s = t_target;
    // Drop samples no longer needed (keep the last one at or before t_state: the next piece interpolates from it).
    while (imu_buffer.size() > 1 && imu_buffer[1].t_s <= t_state_s) imu_buffer.pop();
  }

  void checkDivergence(const UpdateStats& stats, bool image_usable, std::string* reason) {
    const DivergenceParams& dv = params.divergence;
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
    const double sigma_d = std::sqrt(std::max(0.0, P(0, 0))) / (x.alpha * x.alpha);
    if (!(sigma_d <= dv.max_sigma_distance_m)) {
      std::ostringstream os;
      os << "distance 1-sigma " << sigma_d << " m above " << dv.max_sigma_distance_m << " m";
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
    FrameResult probe;
    probe.state = x;
    probe.covariance = P;
    const double sigma_v = probe.sigma_velocity_mps().maxCoeff();
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
    bad_frames = stats.applied ? 0 : bad_frames + 1;
    if (bad_frames >= dv.bad_frames_before_reset && updates_since_reset > 0) {
      std::ostringstream os;
      os << bad_frames << " consecutive frames with a bad or skipped update (last: " << skip_reason << ")";
      *reason = os.str();
    }
  }

  /// After an automatic restart: start from the distance, normal, gravity and biases of the last frame that was
  /// tracking (if init.warm_restart and it is at most init.warm_restart_max_age_s old), with the initial
  /// covariance, so that the filter does not have to converge from the far-off start-up prior again. The
  /// velocity starts from the prior (it is what the fault makes unknown).
  /// The snapshot used is the newest one taken at least kWarmRestartLagS before t_now_s: a fault is usually
  /// detected within a second of its start, so the estimate it had already corrupted is not reused.
  void applyWarmPrior(double t_now_s) {
    if (!params.init.warm_restart) return;
    const GoodSnapshot* best = nullptr;
    for (const GoodSnapshot& g : good_history) {
      const double age_s = t_now_s - g.t_s;
      if (g.valid && age_s >= kWarmRestartLagS && age_s <= params.init.warm_restart_max_age_s &&
          (best == nullptr || g.t_s > best->t_s)) {
        best = &g;
      }
    }
    if (best == nullptr) return;
    x.alpha = best->x.alpha;
    // The remembered distance is at most warm_restart_max_age_s old: a relative 1-sigma, not the wide start-up
    // one. With the wide one, the first updates at speed explain the unknown velocity by a wrong distance.
    const double sigma_alpha = params.init.warm_restart_sigma_alpha_relative * x.alpha;
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = sigma_alpha * sigma_alpha;
    x.mu = best->x.mu;
    x.g = best->x.g;
    x.b_a = best->x.b_a;
    x.b_w = best->x.b_w;
    warm_started = true;
  }

  /// Keeps a snapshot of a healthy tracking state every kSnapshotSpacingS.
  void rememberGood(double t_s) {
    GoodSnapshot* newest = nullptr;
    GoodSnapshot* oldest = &good_history[0];
    for (GoodSnapshot& g : good_history) {
      if (g.valid && (newest == nullptr || g.t_s > newest->t_s)) newest = &g;
      if (!g.valid || (oldest->valid && g.t_s < oldest->t_s)) oldest = &g;
    }
    if (newest != nullptr && t_s - newest->t_s < kSnapshotSpacingS && t_s >= newest->t_s) return;
    oldest->valid = true;
    oldest->t_s = t_s;
    oldest->x = x;
  }

  /// A consistency check failed at `t_s`: the status is degraded (with `why`) for divergence.degraded_hold_s.
  void noteDegraded(double t_s, const std::string& why) { noteDegraded(t_s, why.c_str()); }
  void noteDegraded(double t_s, const char* why) {
    degraded_until_s = t_s + params.divergence.degraded_hold_s;
    std::snprintf(degraded_reason, sizeof(degraded_reason), "%s", why);
  }

  /// Records a restart (counted, reason kept for the status of later frames).
  void noteRestart(const std::string& reason) {
    ++resets;
    last_reset_reason = reason;
  }

  /// Starts the filter at image `t_s`: gravity from the accelerometer, no propagation before.
  void startAt(double t_s) {
    UnitVector g;
    if (params.init.g0_from_accel && gravityFromAccel(t_s, &g)) x.g = g;
    if (params.init.mu0_from_gravity) x.mu = x.g;  // level-ground prior; sigma_mu0_rad covers inclines
    t_state_s = t_s;
    last_usable_image_t_s = t_s;
    state_initialized = true;
    while (imu_buffer.size() > 1 && imu_buffer[1].t_s <= t_state_s) imu_buffer.pop();
  }

  /// Whether the working image carries enough texture for a photometric update; says why not.
  bool imageUsable(const cv::Mat& gray8, std::string* why) const {
    cv::Scalar mean, stddev;
    cv::meanStdDev(gray8, mean, stddev);
    const int total = gray8.rows * gray8.cols;
    int clipped = 0;
    for (int y = 0; y < gray8.rows; ++y) {
      const uint8_t* row = gray8.ptr<uint8_t>(y);
      for (int x = 0; x < gray8.cols; ++x) clipped += (row[x] == 0 || row[x] == 255) ? 1 : 0;
    }
    const double unclipped = total > 0 ? 1.0 - static_cast<double>(clipped) / total : 0.0;
    std::ostringstream os;
    if (unclipped < params.input.min_unclipped_ratio) {
      os << "image unusable: " << static_cast<int>(std::lround(100.0 * (1.0 - unclipped)))
         << " % of the pixels black or saturated (mean grey " << std::lround(mean[0]) << ")";
    } else if (!(stddev[0] >= params.input.min_image_contrast_grey)) {
      os << "image unusable: no texture (grey-level std " << stddev[0] << " below "
         << params.input.min_image_contrast_grey << ")";
    } else {
      return true;
    }
    *why = os.str();
    return false;
  }

  void processImage(PendingImage& img) {
    const auto t0 = std::chrono::steady_clock::now();
    FrameResult r;
    r.t_s = img.t_s;
    r.stamp_s = img.stamp_s;
    std::string restart_reason;  // set when the filter restarts at this image before any update
    char msg[kMessageCapacity] = "";  // the result's message, formatted without allocation

    PreprocessedFrame& cur = frames[1 - ref_index];
    const bool pattern_on = params.fixed_pattern.enabled || !params.fixed_pattern.vignetting_file.empty();
    img_pre.process(img.gray, img.t_s, &cur, pattern_on ? &fixed_pattern : nullptr);
    std::string usable_why;
    const bool usable = imageUsable(cur.gray8, &usable_why);

    if (state_initialized && img.t_s - last_usable_image_t_s > params.input.max_image_gap_s) {
      // The state has been dead-reckoned on the IMU alone for too long: restart, and wait (without
      // propagating) for the next usable image, which becomes the reference of the new run.
      std::ostringstream os;
      os << "no usable image for " << (img.t_s - last_usable_image_t_s) << " s (more than max_image_gap_s = "
         << params.input.max_image_gap_s << " s)";
      restart_reason = os.str();
      noteRestart(restart_reason);
      warn("filter reset: " + restart_reason);
      resetFilter();
      applyWarmPrior(img.t_s);
    }
    if (!state_initialized) {
      if (usable) startAt(img.t_s);  // otherwise the filter keeps waiting for a usable image
    } else if (usable && have_reference && params.update_at_interval_midpoint) {
      // The image pair sees the displacement over the whole interval, i.e. its mean velocity, not the velocity
      // at the current image: update the state of the interval's midpoint (exact to second order in the
      // interval), then predict on to the image.
      propagateTo(std::max(t_state_s, 0.5 * (frames[ref_index].t_s + img.t_s)));
    } else {
      propagateTo(img.t_s);
    }

    UpdateStats stats;
    skip_reason.clear();
    if (!usable) {
      // Keep the reference and the gyro integral: the next usable image is compared with the old reference.
      skip_reason = usable_why;
    } else if (have_reference) {
      const PreprocessedFrame& ref = frames[ref_index];
      const double dt = cur.t_s - ref.t_s;
      const double state_lag = std::max(0.0, cur.t_s - t_state_s);  // the state's time before the image, s
      // Mean raw gyro over the whole interval: what was integrated so far plus the samples up to the image.
      const double rest_s = img.t_s - t_state_s;
      const double total_s = gyro_time_s + rest_s;
      const Vec3 gyro_mean =
          total_s > 0.0 ? Vec3((gyro_integral + gyroIntegral(t_state_s, img.t_s)) / total_s) : Vec3::Zero();
      if (dt > params.input.max_frame_interval_s) {
        std::ostringstream os;
        os << "update skipped: " << dt << " s since the reference image (max_frame_interval_s = "
           << params.input.max_frame_interval_s << " s); this image is the new reference";
        skip_reason = os.str();
      } else if (ref.t_s < last_imu_gap_end_s) {
        // The gyro over the interval is unknown (held across the gap): the warp cannot be predicted.
        skip_reason = "update skipped: the image interval spans a bridged IMU gap; this image is the new reference";
        noteDegraded(img.t_s, "IMU gap bridged: covariance grown, one image pair skipped");
      } else {
        if (params.mode == UpdateMode::kFeature) {
          stats = feature.update(ref, cur, img_pre.workingK(), gyro_mean, dt, &x, &P, state_lag);
        } else {
          const State x_prior = x;
          const ErrorCov P_prior = P;
          // The time offset (docs/algorithm.md section 3.6): the state's rates at its time and the change of the
          // filtered rate over the interval.
          // Only once the distance has converged and time_offset_start_s later (and not from frames the
          // innovation test flags: PhotometricUpdate): before that the state's rates in m are unknown themselves,
          // and the offset absorbed the start-up transient (a 15 ms offset was estimated at 36 ms within 0.5 s of
          // a start at 1 m/s, then divergence; on a clean fast flight a dash just after convergence moved it to
          // -37 ms, truth 0). Not while degraded was tried too: realistic flights are often degraded (exposure
          // steps), and a wrong offset keeps the status degraded, so it was never corrected (5 sigma off).
          // A rolling shutter (section 3.7) needs the same rates for its rows' times.
          ImageTiming timing;
          const bool settled = converged && img.t_s - converged_since_s >= params.time_offset_start_s;
          timing.estimate_offset = params.estimate_time_offset && settled;
          timing.row_weight = readout_row_weight.data();
          timing.rows = static_cast<int>(readout_row_weight.size());
          // The readout once the offset is known to a few ms (when it is estimated): early on, with both
          // uncertain, a large offset was partly taken for a readout (19 ms of readout for a 20 ms offset on a
          // global-shutter flight, the offset then 10 s late).
          const double gate_s = params.readout_start_sigma_time_offset_s;
          timing.estimate_readout = params.estimate_readout && settled &&
                                    (!params.estimate_time_offset || P(ErrIdx::kTd, ErrIdx::kTd) < gate_s * gate_s);
          timing.rates_valid = timing.estimate_offset || timing.estimate_readout || x.readout_s != 0.0;
          if (timing.rates_valid) {
            timing.accel_C = imuAt(t_state_s).accel_mps2;
            timing.rate_change_C = imuAt(img.t_s).gyro_radps - ref_rate_C;
            timing.gravity_mps2 = params.imu.gravity_mps2;
          }
          photometric.setPixelConfidence(fixed_pattern.confidence());
          stats = photometric.update(ref, cur, img_pre.workingK(), gyro_mean, dt, &x, &P, state_lag, timing);
          x.t_d_s = std::clamp(x.t_d_s, -params.max_time_offset_s, params.max_time_offset_s);
          x.readout_s = std::clamp(x.readout_s, -params.max_readout_s, params.max_readout_s);
          // alpha's step in prior sigmas: d must never jump by many sigma in one frame.
          const double step_sigma =
              std::abs(x.alpha - x_prior.alpha) / std::sqrt(std::max(1e-300, P_prior(ErrIdx::kAlpha, ErrIdx::kAlpha)));
          if (stats.applied && !(stats.rms_residual <= params.divergence.max_photometric_rms)) {
            // The images do not fit the plane model (occlusion, unrelated or corrupt image): keep the prior.
            x = x_prior;
            P = P_prior;
            stats.applied = false;
            std::ostringstream os;
            os << "update rejected: photometric RMS " << stats.rms_residual << " above "
               << params.divergence.max_photometric_rms;
            skip_reason = os.str();
            noteDegraded(img.t_s, skip_reason);
          } else if (stats.applied && !(step_sigma <= params.divergence.max_step_sigma)) {
            x = x_prior;
            P = P_prior;
            stats.applied = false;
            std::ostringstream os;
            os << "update rejected: it moved the inverse distance by " << step_sigma << " prior sigmas (max_step_sigma = "
               << params.divergence.max_step_sigma << ")";
            skip_reason = os.str();
            noteDegraded(img.t_s, skip_reason);
          } else if (stats.applied && stats.gated) {
            char why[kMessageCapacity];
            std::snprintf(why, sizeof(why), "update gated: NIS %.3g above %.3g, measurement down-weighted x%.3g",
                          stats.nis, params.photometric.gate_nis, stats.gate_inflation);
            noteDegraded(img.t_s, why);
          }
          if (stats.applied && std::isfinite(stats.nis)) {
            // Smoothed NIS over about a second: persistently above its mean = the noise model does not fit.
            const double a = 1.0 - std::exp(-dt / 1.0);
            nis_smoothed = nis_smoothed > 0.0 ? nis_smoothed + a * (stats.nis - nis_smoothed) : stats.nis;
            if (nis_smoothed > params.divergence.max_nis_ratio * internal::kObsDim) {
              char why[kMessageCapacity];
              std::snprintf(why, sizeof(why), "innovations too large: smoothed NIS %.3g (expected %d)", nis_smoothed,
                            internal::kObsDim);
              noteDegraded(img.t_s, why);
            }
          }
          // The camera-fixed pattern learns by how far the ground moved: the rotation (gyro) always, the
          // translation once the filter has converged and accepted the image (docs/noise_model.md section 11).
          const bool trusted = stats.applied && !stats.gated && converged;
          if (fixed_pattern.learn(imageMotionPx(trusted ? x.vartheta : Vec3::Zero(), gyro_mean - x.b_w,
                                                img_pre.workingK(), dt)))
            img_pre.reapplyPattern(&fixed_pattern, &cur);  // the next pair: one correction in both images
        }
      }
      if (skip_reason.empty() && !stats.applied) skip_reason = "update skipped: too few valid pixels or non-finite system";
    }
    if (state_initialized && t_state_s < img.t_s) propagateTo(img.t_s);  // from the interval's midpoint
    const bool had_reference = have_reference;
    if (usable) {
      last_usable_image_t_s = img.t_s;
      ref_rate_C = imuAt(img.t_s).gyro_radps;
      gyro_integral.setZero();
      gyro_time_s = 0.0;
      ref_index = 1 - ref_index;
      have_reference = true;
    }

    const auto t1 = std::chrono::steady_clock::now();
    r.update_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    r.update_applied = stats.applied;
    r.passes = stats.passes;
    r.photometric_rms = std::isfinite(stats.rms_residual) ? stats.rms_residual : 0.0;
    r.nis = std::isfinite(stats.nis) ? stats.nis : 0.0;
    r.noise_sigma = std::isfinite(stats.noise_sigma) ? stats.noise_sigma : 0.0;
    r.noise_correlation = std::isfinite(stats.noise_correlation) ? stats.noise_correlation : 0.0;
    r.gate_inflation = std::isfinite(stats.gate_inflation) ? stats.gate_inflation : 1.0;
    r.nis_scale = std::isfinite(stats.nis_scale) ? stats.nis_scale : 1.0;
    r.outlier_fraction = std::isfinite(stats.outlier_fraction) ? stats.outlier_fraction : 0.0;
    r.valid_ratio = std::isfinite(stats.valid_ratio) ? stats.valid_ratio : 0.0;
    r.fixed_pattern_active = fixed_pattern.active();
    r.fixed_pattern_fraction = fixed_pattern.strongFraction();
    if (stats.applied) ++updates_since_reset;

    std::string reason;
    checkDivergence(stats, usable, &reason);
    if (reason.empty() && had_reference && state_initialized && !stats.applied && updates_since_reset == 0) {
      // No update has succeeded since the (re)start: do not dead-reckon the prior on the IMU alone; start the
      // run again at this image instead (its covariance would only grow, and the first real update would
      // then be linearised far from the truth).
      const bool warm = warm_started;
      const int bad = bad_frames;
      const std::string skipped = skip_reason;
      resetFilter();
      if (warm) applyWarmPrior(img.t_s);
      warm_started = warm;
      bad_frames = bad;
      skip_reason = skipped;
      if (usable) startAt(img.t_s);
      have_reference = usable;
    }
    if (!reason.empty()) {
      noteRestart(reason);
      warn("filter reset: " + reason);
      resetFilter();
      applyWarmPrior(img.t_s);
      // Restart from this image: it becomes the new reference (if it has texture).
      if (usable) startAt(img.t_s);
      have_reference = usable;
      r.status = FilterStatus::kReset;
      std::snprintf(msg, sizeof(msg), "%s", reason.c_str());
    } else if (!restart_reason.empty()) {
      r.status = FilterStatus::kReset;
      std::snprintf(msg, sizeof(msg), "%s", restart_reason.c_str());
    } else if (!pending_reset_reason.empty()) {
      // The first frame after a restart triggered by the input (time jump, IMU gap, internal error).
      r.status = FilterStatus::kReset;
      std::snprintf(msg, sizeof(msg), "%s", pending_reset_reason.c_str());
    } else if (!converged) {
      const double relative_sigma_d = std::sqrt(std::max(0.0, P(0, 0))) / x.alpha;  // sigma_d / d
      converged = updates_since_reset > 0 && relative_sigma_d < params.init.tracking_max_relative_sigma_d;
      if (converged) converged_since_s = img.t_s;
      r.status = converged ? FilterStatus::kTracking : FilterStatus::kInitializing;
      if (!usable) {
        std::snprintf(msg, sizeof(msg), "%s", usable_why.c_str());
      } else if (!had_reference) {
        std::snprintf(msg, sizeof(msg), "first image: reference set");
      } else if (updates_since_reset == 0) {
        std::snprintf(msg, sizeof(msg), "%s",
                      skip_reason.empty() ? "waiting for a valid image update" : skip_reason.c_str());
      } else if (!converged) {
        std::snprintf(msg, sizeof(msg), "converging: sigma_d/d = %g (tracking below %g)", relative_sigma_d,
                      params.init.tracking_max_relative_sigma_d);
      }
      if (!converged && !last_reset_reason.empty()) {
        const size_t used = std::strlen(msg);
        std::snprintf(msg + used, sizeof(msg) - used, " (last reset: %s%s", last_reset_reason.c_str(),
                      warm_started ? "; restarted from the last good distance)" : ")");
      }
    } else if (img.t_s <= degraded_until_s) {
      r.status = FilterStatus::kDegraded;
      std::snprintf(msg, sizeof(msg), "%s", degraded_reason);
    } else {
      r.status = FilterStatus::kTracking;
      std::snprintf(msg, sizeof(msg), "%s", skip_reason.c_str());
    }
    if (r.outlier_fraction >= kReportOutlierFraction && r.status != FilterStatus::kReset) {
      // Objects or clutter not moving with the plane (docs/noise_model.md section 10): say how much is ignored.
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, sizeof(msg) - used, "%soutliers: %.0f %% of the image down-weighted",
                    used > 0 ? "; " : "", 100.0 * r.outlier_fraction);
    }
    if (r.fixed_pattern_fraction >= params.fixed_pattern.report_fraction && params.fixed_pattern.report_fraction > 0.0) {
      // A strong camera-fixed pattern (docs/noise_model.md section 11): an IR projector, the drone's shadow, dirt.
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, sizeof(msg) - used, "%sfixed pattern (projector, shadow, dirt?) on %.0f %% of the image",
                    used > 0 ? "; " : "", 100.0 * r.fixed_pattern_fraction);
    }
    pending_reset_reason.clear();
    if (r.status == FilterStatus::kTracking && stats.applied && bad_frames == 0) rememberGood(img.t_s);
    status = r.status;
    r.state = x;
    r.covariance = P;
    r.resets = resets;
    // Into a ring slot (the oldest unread result is dropped when full), reusing the slot's string buffers.
    FrameResult& slot = results.emplaceSlot();
    r.message.swap(slot.message);
    r.message.assign(msg);
    r.last_reset_reason.swap(slot.last_reset_reason);
    r.last_reset_reason.assign(last_reset_reason);
    slot = std::move(r);
  }

  /// Processes every pending image whose stamp is covered by filtered IMU data. Before the filter has started,
  /// images older than the oldest buffered IMU sample (e.g. images before any IMU data) are dropped.
  void processReady() {
    while (!images.empty()) {
      PendingImage& img = images[0];
      // The image's time on the IMU clock with the estimated offset on top of the calibration's
      // (docs/algorithm.md section 3.6); never before the state's time.
      double t_img_s = params.estimate_time_offset ? img.t_s + x.t_d_s : img.t_s;
      if (state_initialized) t_img_s = std::max(t_img_s, t_state_s + 1e-6);
      if (imu_buffer.empty() || imu_buffer.back().t_s < t_img_s) return;
      if (!state_initialized && img.t_s < imu_buffer[0].t_s) {
        std::ostringstream os;
        os << "image at " << img.t_s << " s older than the IMU data (from " << imu_buffer[0].t_s << " s) dropped";
        warn(os.str());
        images.pop();
        continue;
      }
      img.t_s = t_img_s;
      processImage(img);
      images.pop();
    }
  }

  /// Back to the initial state with an empty IMU pipeline and image queue. `automatic`: caused by the input
  /// (the next frame reports status reset with the reason); otherwise requested by the user.
  void restart(const std::string& reason, bool automatic, bool warm = false, double t_now_s = 0.0) {
    warn((automatic ? "filter reset: " : "reset: ") + reason);
    noteRestart(reason);
    resetFilter();
    if (warm) {
      applyWarmPrior(t_now_s);
    } else {
      for (GoodSnapshot& g : good_history) g.valid = false;  // e.g. a time jump: the history is from other data
    }
    imu_pre.reset();
    imu_buffer.clear();
    images.clear();
    have_raw_imu = false;
    last_image_t_s = -HUGE_VAL;
    status = FilterStatus::kInitializing;
    pending_reset_reason = automatic ? reason : std::string();
  }

  CameraModel camera;
  EstimatorParams params;
  ImuPreprocessor imu_pre;
  ImagePreprocessor img_pre;
  PhotometricUpdate photometric;
  FixedPattern fixed_pattern;  // camera-fixed gain and offset fields (docs/noise_model.md section 11)
  FeatureUpdate feature;

  Ring<ImuSample> imu_buffer;   // filtered samples in C, delay-compensated stamps
  Ring<PendingImage> images;    // images waiting for IMU coverage
  Ring<FrameResult> results;    // unread results
  PreprocessedFrame frames[2];
  int ref_index = 0;

  State x;
  ErrorCov P = ErrorCov::Zero();
  double t_state_s = 0.0;
  double last_usable_image_t_s = 0.0;  // stamp of the last image with texture (or of the start), IMU clock
  bool state_initialized = false;
  bool have_reference = false;
  FilterStatus status = FilterStatus::kInitializing;
  Vec3 gyro_integral = Vec3::Zero();      // integral of the raw gyro (C) since the reference image, rad
  Vec3 ref_rate_C = Vec3::Zero();         // filtered rate at the reference image, rad/s
  double converged_since_s = HUGE_VAL;    // image time at which the current run converged, s
  double configured_readout_s = 0.0;      // rolling shutter: line delay x (rows - 1) from the parameters, s
  std::vector<float> readout_row_weight;  // per working row: its capture time per second of readout
  double stamp_shift_s = 0.0;             // image stamp -> capture time of the middle row's mid-exposure, s
  double gyro_time_s = 0.0;               // time covered by gyro_integral, s
  int bad_frames = 0;
  int updates_since_reset = 0;
  bool converged = false;  // sigma_d / d has fallen below the tracking threshold since the last reset
  int resets = 0;
  std::string last_reset_reason;     // reason of the last restart (kept for the status text)
  std::string pending_reset_reason;  // the next frame reports status reset with this reason
  std::string skip_reason;           // why the current frame's update was not applied
  struct GoodSnapshot {
    bool valid = false;
    double t_s = 0.0;                // IMU clock, s
    State x;
  };
  static constexpr double kWarmRestartLagS = 1.0;    // warm restarts use a state at least this old, s
  static constexpr double kSnapshotSpacingS = 0.25;  // spacing of the kept snapshots, s
  std::array<GoodSnapshot, 12> good_history;  // healthy tracking states, about the last 3 s
  bool warm_started = false;         // the current run started from last_good
  double nis_smoothed = 0.0;         // NIS smoothed over about 1 s (0: none yet)
  double degraded_until_s = -HUGE_VAL;  // status degraded up to this image time (IMU clock), s
  char degraded_reason[kMessageCapacity] = "";  // the last failed consistency check (no allocation per frame)
  double last_imu_gap_end_s = -HUGE_VAL;  // IMU-clock stamp of the first sample after the last bridged gap

  bool have_raw_imu = false;
  double last_raw_imu_t_s = 0.0;
  double last_image_t_s = -HUGE_VAL;
  std::string warning;
};

Estimator::Estimator(const CameraModel& camera, const EstimatorParams& params)
    : impl_(new Impl(camera, params)) {}

Estimator::~Estimator() = default;

bool Estimator::addImu(const ImuSample& raw) {
  Impl& m = *impl_;
  try {
    if (!std::isfinite(raw.t_s) || !raw.accel_mps2.allFinite() || !raw.gyro_radps.allFinite()) {
      m.warn("IMU sample with a non-finite value rejected");
      return false;
    }
    if (raw.accel_mps2.norm() > m.params.input.max_accel_mps2 || raw.gyro_radps.norm() > m.params.input.max_gyro_radps) {
      std::ostringstream os;
      os << "implausible IMU sample rejected (|f| = " << raw.accel_mps2.norm() << " m/s^2, |w| = "
         << raw.gyro_radps.norm() << " rad/s)";
      m.warn(os.str());
      return false;
    }
    if (m.have_raw_imu) {
      const double dt = raw.t_s - m.last_raw_imu_t_s;
      if (dt < -m.params.input.time_jump_reset_s) {
        // Time jumped backwards (e.g. a looping bag): start again with this sample.
        std::ostringstream os;
        os << "IMU time jumped back by " << -dt << " s";
        m.restart(os.str(), true);
      } else if (dt <= 0.0) {
        m.warn(dt == 0.0 ? "duplicated IMU stamp rejected" : "out-of-order IMU sample rejected");
        return false;
      } else if (dt > m.params.input.max_imu_bridge_s) {
        std::ostringstream os;
        os << "IMU gap of " << dt << " s (more than max_imu_bridge_s = " << m.params.input.max_imu_bridge_s << " s)";
        m.restart(os.str(), true, true, raw.t_s);
      } else if (dt > m.params.max_imu_gap_s) {
        // Bridged: the low-pass restarts from this sample, the state is propagated through the gap.
        std::ostringstream os;
        os << "IMU gap of " << dt << " s bridged";
        m.warn(os.str());
        m.imu_pre.reset();
        m.last_imu_gap_end_s = raw.t_s;
      }
    }
    m.have_raw_imu = true;
    m.last_raw_imu_t_s = raw.t_s;
    ImuSample filtered;
    if (m.imu_pre.push(raw, &filtered)) {
      if (!std::isfinite(filtered.t_s) || !filtered.accel_mps2.allFinite() || !filtered.gyro_radps.allFinite()) {
        m.warn("IMU low-pass produced a non-finite value: filter memory cleared");
        m.imu_pre.reset();
        return true;
      }
      if (!m.imu_buffer.empty() && filtered.t_s <= m.imu_buffer.back().t_s) return true;
      m.imu_buffer.push(filtered);
      m.processReady();
    }
    return true;
  } catch (const std::exception& e) {
    m.restart(std::string("internal error while processing IMU data: ") + e.what(), true);
    return false;
  }
}

bool Estimator::addImage(double t_cam_s, const cv::Mat& image) {
  Impl& m = *impl_;
  try {
    const double t_s = t_cam_s + m.camera.timeshift_cam_imu_s + m.stamp_shift_s;
    if (!std::isfinite(t_s)) {
      m.warn("image with a non-finite stamp rejected");
      return false;
    }
    if (image.empty() || image.dims != 2 || image.cols != m.camera.K.width || image.rows != m.camera.K.height) {
      std::ostringstream os;
      os << "image of " << image.cols << "x" << image.rows << " px rejected: calibration is " << m.camera.K.width
         << "x" << m.camera.K.height << " px";
      m.warn(os.str());
      return false;
    }
    const int depth = image.depth();
    const int channels = image.channels();
    const bool supported = (depth == CV_8U && (channels == 1 || channels == 3 || channels == 4)) ||
                           (depth == CV_16U && channels == 1);
    if (!supported) {
      m.warn("image of unsupported type rejected (expected 8-bit grey, 16-bit grey, BGR or BGRA)");
      return false;
    }
    if (t_s <= m.last_image_t_s) {
      if (t_s < m.last_image_t_s - m.params.input.time_jump_reset_s) {
        std::ostringstream os;
        os << "image time jumped back by " << (m.last_image_t_s - t_s) << " s";
        m.restart(os.str(), true);
      } else {
        m.warn(t_s == m.last_image_t_s ? "duplicated image stamp rejected" : "out-of-order image rejected");
        return false;
      }
    }
    if (m.images.full()) m.warn("image queue full (no IMU data covering the images): oldest image dropped");
    PendingImage& slot = m.images.emplaceSlot();
    slot.t_s = t_s;
    slot.stamp_s = t_cam_s;
    toGrey8(image, ChannelOrder::kBgr, &slot.gray);  // the package's one grey conversion (grey_image.h)
    m.last_image_t_s = t_s;
    m.processReady();
    return true;
  } catch (const std::exception& e) {
    m.restart(std::string("internal error while processing an image: ") + e.what(), true);
    return false;
  }
}

bool Estimator::popResult(FrameResult* out) {
  Impl& m = *impl_;
  if (m.results.empty()) return false;
  *out = m.results[0];  // copy: the slot keeps its message buffer, `out` reuses its own
  m.results.pop();
  return true;
}

void Estimator::reset(const std::string& reason) { impl_->restart(reason, false); }

const State& Estimator::state() const { return impl_->x; }
const ErrorCov& Estimator::covariance() const { return impl_->P; }
FilterStatus Estimator::status() const { return impl_->status; }
double Estimator::stateTime() const { return impl_->t_state_s; }
const EstimatorParams& Estimator::params() const { return impl_->params; }
const PinholeK& Estimator::workingK() const { return impl_->img_pre.workingK(); }
const cv::Mat& Estimator::lastResidualImage() const { return impl_->photometric.residualImage(); }

int Estimator::resetCount() const { return impl_->resets; }
const std::string& Estimator::lastResetReason() const { return impl_->last_reset_reason; }

std::string Estimator::takeWarning() {
  std::string w;
  w.swap(impl_->warning);
  return w;
}

}  // namespace diekf
