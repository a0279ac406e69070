#include "diekf/estimator.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>
#include <utility>

#include "diekf/grey_image.h"
#include "diekf/fixed_pattern.h"
#include "diekf/image_preprocessor.h"
#include "diekf/imu_filter.h"
#include "diekf/photometric_update.h"
#include "diekf/stamp_check.h"
#include "dot_detector.h"
#include "dot_gain.h"
#include "frame_clock.h"
#include "gauss_newton.h"
#include "health_monitor.h"
#include "image_update.h"
#include "imu_propagator.h"
#include "interval_warp.h"
#include "restart_policy.h"
#include "scale_initializer.h"
#include "ring.h"

// The estimator is a manager over four parts, each in its own file (docs/algorithm.md section 9):
//   ImuPropagator  (imu_propagator.h)  filtered IMU samples, the state's time, prediction between images
//   ImageUpdate    (image_update.h)    the update from an image pair and its guards
//   HealthMonitor  (health_monitor.h)  divergence and consistency checks, the status state machine
//   RestartPolicy  (restart_policy.h)  what a run starts from (cold or warm prior), the restart count
// This file holds the input checks and queues, and the order of the steps of one image (processImage).

namespace diekf {

using internal::FrameFacts;
using internal::kMessageCapacity;
using internal::Ring;

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

double FrameResult::sigma_distance_m() const { return sigmaDistance_m(state, covariance); }

Vec3 FrameResult::sigma_velocity_mps() const { return sigmaVelocity_mps(state, covariance); }

namespace {

struct PendingImage {
  double t_s = 0.0;      // IMU clock
  double stamp_s = 0.0;  // the stamp it was given (camera clock)
  double stamp_correction_s = 0.0;  // the stamp less the frame clock's time (FrameResult::stamp_correction_s)
  double stamp_jitter_s = 0.0;      // the frame clock's 1-sigma (FrameResult::stamp_jitter_s)
  ResampledImage stage;  // the image resampled to the working size on arrival (reused buffers; no raw copy kept)
  double resample_ms = 0.0;  // time of that stage, added to the frame's update_ms
  bool dots_sampled = false; // the projector-dot detector sampled the raw image (DotDetector::addImage)
  cv::Mat raw;               // a copy of the raw grey image while the dots' gain is learned (DotGainLearner)
  bool raw_kept = false;     // `raw` holds this image
};

constexpr size_t kResultCapacity = 64;  // unread results kept (oldest dropped): nobody reads, memory bounded

}  // namespace

struct Estimator::Impl {
  Impl(const CameraModel& cam, const EstimatorParams& p)
      : camera(cam),
        params(p),
        imu_pre(cam.T_cam_imu, p.imu),
        img_pre(cam, preprocessParamsFor(p)),
        fixed_pattern(p.fixed_pattern, img_pre.workingSize().width, img_pre.workingSize().height,
                      p.fixed_pattern.vignetting_file.empty()
                          ? cv::Mat()
                          : loadFlatField(p.fixed_pattern.vignetting_file, cam, preprocessParamsFor(p)),
                      Vec2(img_pre.workingK().cx, img_pre.workingK().cy)),
        imu(params),
        update(cam, params, img_pre),
        health(params),
        restarts(params),
        images(static_cast<size_t>(std::max(1, p.max_queued_images))),
        results(kResultCapacity),
        scale_losses_s(static_cast<size_t>(std::max(1, p.fixed_pattern.scale_losses_waive_patches))) {
    // Result slots keep their message buffers: no allocation per frame for the usual messages.
    for (size_t i = 0; i < kResultCapacity; ++i) {
      FrameResult& slot = results.emplaceSlot();
      slot.message.reserve(kMessageCapacity);
      slot.last_reset_reason.reserve(kMessageCapacity);
    }
    results.clear();
    const int decimation = std::max(1, p.imu.decimation_factor);
    imu.setFilterNoise(imu_pre.noiseAutocovariances(decimation));
    // Rolling shutter (docs/algorithm.md section 3.7): the stamp at the middle raw row.
    configured_readout_s = configuredLineDelay_s(p, cam) * std::max(0, cam.K.height - 1);
    stamp_shift_s = imageStampShift(p.image_stamp, p.exposure_time_s, configured_readout_s);
    internal::ScaleInitializer::Config sc;
    sc.window_s = p.init.scale_window_s;
    sc.max_window_s = std::max(p.init.scale_window_s, p.init.scale_max_window_s);
    sc.max_relative_sigma = p.init.scale_max_relative_sigma;
    sc.accel_noise_density = p.imu.accel_noise_density;
    sc.gravity_mps2 = p.imu.gravity_mps2;
    scale_init.configure(sc);
    const int dot_px = p.fixed_pattern.auto_dot_removal_px;
    for (const auto& [key, px] : {std::pair<const char*, int>{"auto_dot_removal_px", dot_px},
                                  {"max_dot_removal_px", p.fixed_pattern.max_dot_removal_px}}) {
      if (!ImagePreprocessor::validDotRemovalPx(px)) {
        throw std::invalid_argument(std::string("fixed_pattern/") + key + " = " + std::to_string(px) +
                                    " is not 0 or odd in [1, 31]");
      }
    }
    if (dot_px > 1 && p.fixed_pattern.dot_detect_share > 0.0 && img_pre.dotRemovalPx() == 0 &&
        p.mode != UpdateMode::kFeature && internal::DotDetector::fits(cam.K.width, cam.K.height)) {
      dots.configure(cam.K.width, cam.K.height, dot_px, p.fixed_pattern.dot_detect_contrast,
                     p.fixed_pattern.dot_detect_share, p.fixed_pattern.dot_detect_levels);
    }
    resetFilter();
  }

  /// The fixed pattern's patch condition is waived while the last fixed_pattern.scale_losses_waive_patches
  /// restarts without scale before convergence (HealthMonitor::scaleLost) all fall within scale_loss_window_s of
  /// t_s (docs/noise_model.md section 11, "Holding a position").
  bool patchConditionWaived(double t_s) const {
    const int n = params.fixed_pattern.scale_losses_waive_patches;
    return n > 0 && scale_losses_s.full() && t_s - scale_losses_s[0] <= params.fixed_pattern.scale_loss_window_s;
  }

  static PreprocessParams preprocessParamsFor(const EstimatorParams& p) {
    PreprocessParams pp = p.preprocess;
    if (p.mode == UpdateMode::kFeature) {
      pp.working_width_px = p.feature.working_width_px;
      pp.working_height_px = 0;
    }
    return pp;
  }

  void warn(const std::string& text) {
    if (!warning.empty()) warning += "; ";
    warning += text;
  }

  /// A new run from the initial state and covariance of the parameters; nothing referenced, not started.
  void resetFilter() {
    restarts.coldStart(health.converged(), configured_readout_s, &x, &P);
    have_reference = false;
    state_initialized = false;
    imu.clearInterval();
    health.startRun();
    skip_reason.clear();
    update.resetNoiseModel();
    relief_var = 0.0;
    scale_init.reset();
    if (!params.init.scale_batch) scale_init.finish();
    dots.restartMotion();  // (the new run's first pair starts the ground's track again)
  }

  /// Start-up while the camera is still (ScaleInitializer): the update leaves alpha and its variance as they were
  /// before it (`alpha0`, `var_alpha0`; a "consider" state) and its correlations are dropped (P stays positive
  /// definite).
  void holdAlpha(double alpha0, double var_alpha0) {
    x.alpha = alpha0;
    P.row(ErrIdx::kAlpha).setZero();
    P.col(ErrIdx::kAlpha).setZero();
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = var_alpha0;
  }

  /// The warm prior of a restart (RestartPolicy::applyWarmPrior); a run that starts from a known distance needs
  /// no start-up of the scale.
  void applyWarmPrior(double t_s) {
    restarts.applyWarmPrior(t_s, &x, &P);
    if (restarts.warmStarted()) scale_init.finish();
  }

  /// The camera-fixed pattern just learned holds a share s of the image's contrast (FixedPattern::contrastShare):
  /// before it was removed, that share of every update's information voted for "no motion", so what the images
  /// said about the velocity over distance and the inverse distance may be short by up to s of their values.
  /// That bias is allowed for once, as an unknown of that size: s^2 alpha^2 and s^2 |vartheta|^2 are added to
  /// their variances (the estimate is kept; fixed_pattern.discount_biased_updates); a share that grows later adds
  /// the difference. The status names the pattern (degraded for divergence.degraded_hold_s) when s reaches
  /// fixed_pattern.dominant_contrast_share. docs/noise_model.md section 11.
  void discountPatternBiasedInformation(double t_s) {
    const FixedPatternParams& fp = params.fixed_pattern;
    const double share = fixed_pattern.contrastShare();
    if (share > discounted_share && fp.discount_biased_updates) {
      const double f = share * share - discounted_share * discounted_share;
      P(ErrIdx::kAlpha, ErrIdx::kAlpha) += f * x.alpha * x.alpha;
      P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta).diagonal().array() += f * x.vartheta.squaredNorm();
    }
    // The mark stays at the largest share allowed for (the share wavers from one refresh to the next) until the
    // pattern has mostly gone (below half of it): one that comes back is allowed for again.
    if (share > discounted_share || share < 0.5 * discounted_share) discounted_share = share;
    if (fp.dominant_contrast_share > 0.0 && share >= fp.dominant_contrast_share && !pattern_named) {
      pattern_named = true;
      char why[kMessageCapacity];
      std::snprintf(why, sizeof(why), "camera-fixed pattern found (%.0f %% of the image's contrast)%s",
                    100.0 * share, fp.discount_biased_updates ? ": distance and velocity discounted" : "");
      health.noteDegraded(t_s, why);
    }
    if (share < 0.5 * fp.dominant_contrast_share) pattern_named = false;
  }

  /// A camera-fixed pattern that dominates the image's contrast (fixed_pattern.dominant_contrast_share) while the
  /// raw images are not opened is taken for an IR projector's dots: the images resampled from now on are opened
  /// (fixed_pattern.auto_dot_removal_px; 0 = never), the pattern is learned anew from them, and the distance and
  /// velocity over distance get their initial uncertainty back; the first opened image starts a new pair
  /// (processImage). Once per estimator: the opening stays on. docs/noise_model.md §11.
  void switchOnDotRemovalIfDominant(double t_s) {
    const FixedPatternParams& fp = params.fixed_pattern;
    const double share = fixed_pattern.contrastShare();
    if (!(fp.dominant_contrast_share > 0.0) || share < fp.dominant_contrast_share) return;
    char why[kMessageCapacity];
    std::snprintf(why, sizeof(why),
                  "camera-fixed pattern of %.0f %% of the image's contrast taken for projector dots: raw images "
                  "opened over %d px from now on (fixed_pattern/auto_dot_removal_px)",
                  100.0 * share, fp.auto_dot_removal_px);
    switchOnDotRemoval(t_s, why);
  }

  /// The projector-dot detector on the raw images (DotDetector; fixed_pattern.dot_detect_share): the pair's
  /// estimated shift of the ground at the raw image's centre with its 1-sigma (from the observed states'
  /// covariance through the warp's Jacobian), the sampled image's position, and the verdict once the ground has
  /// moved enough. Called after the pair's update, with the state at the update's time.
  void detectDots(const PendingImage& img, bool pair_updated, bool first_of_run) {
    if (!dots.armed()) return;
    if (pair_updated) {
      using internal::DotDetector;
      constexpr int kObserved[8] = {ErrIdx::kVartheta, ErrIdx::kVartheta + 1, ErrIdx::kVartheta + 2, ErrIdx::kMu,
                                    ErrIdx::kMu + 1,    ErrIdx::kBw,         ErrIdx::kBw + 1,      ErrIdx::kBw + 2};
      Eigen::Matrix<double, 8, 8> P_obs;
      for (int i = 0; i < 8; ++i)
        for (int j = 0; j < 8; ++j) P_obs(i, j) = P(kObserved[i], kObserved[j]);
      std::array<Vec2, DotDetector::kBlocks> shift, sigma;
      for (int b = 0; b < DotDetector::kBlocks; ++b) {
        WarpJacobian J;
        const Vec2 c = dots.blockCentre(b);
        const Vec2 p_ref = warpToReference(x, camera.K, update.lastGyroMean(), update.lastInterval(), c.x(), c.y(),
                                           &J, img.t_s - imu.stateTime());
        shift[static_cast<size_t>(b)] = c - p_ref;
        sigma[static_cast<size_t>(b)] = (J * P_obs * J.transpose()).diagonal().cwiseMax(0.0).cwiseSqrt();
      }
      dots.addMotion(shift, sigma);
    }
    if (img.dots_sampled) dots.notePosition(pair_updated || first_of_run);
    const internal::DotDetector::Verdict verdict = dots.decide();
    if (verdict == internal::DotDetector::Verdict::kDots) {
      dot_share = dots.share();
      char why[kMessageCapacity];
      if (params.fixed_pattern.dot_fill && params.fixed_pattern.auto_dot_removal_px > 1) {
        // The pixels the dots light (their tails too) filled from the ground around them; their gain learned from
        // the motion meanwhile, to divide them out instead (learnDotGain).
        const double filled = dots.fillMask(&dot_mask);
        std::snprintf(why, sizeof(why),
                      "projector dots found (fixed bright specks on %.1f %% of the image): raw images filled over "
                      "%.1f %% of the image",
                      100.0 * dots.share(), 100.0 * filled);
        switchOnDotRemoval(img.t_s, why, 0, &dot_mask);
        if (params.fixed_pattern.dot_gain && dot_removal_switched && img_pre.dotFillId() != 0) startDotGain();
      } else {
        // The opening's side from the dots' own extent on the last sample (their tails, clusters).
        const int side = dots.removalElement(params.fixed_pattern.max_dot_removal_px);
        std::snprintf(why, sizeof(why),
                      "projector dots found (fixed bright specks on %.1f %% of the image): raw images opened over "
                      "%d px",
                      100.0 * dots.share(), side);
        switchOnDotRemoval(img.t_s, why, side);
      }
    } else if (verdict == internal::DotDetector::Verdict::kNoDots) {
      dot_share = dots.share();
    }
    if ((!dots.armed() || dots.level() > 0) && !dot_removal_switched && img_pre.dotFillId() != 0) {
      setFill(cv::Mat());  // no dots at the first contrast (or no verdict): the interim fill ends
    } else if (verdict == internal::DotDetector::Verdict::kUndecided && dots.armed() && dots.level() == 0 &&
               img.dots_sampled &&
               params.fixed_pattern.dot_fill && params.fixed_pattern.auto_dot_removal_px > 1 &&
               dots.samples() > internal::DotDetector::kStableSamples) {
      // Interim fill while the test runs: past its first samples M holds the dots and what of the ground's specks
      // has not moved off yet; filling M from then on keeps the dots from biasing the start-up until the verdict.
      // Only once M has stopped falling (its last sample kept kStableFraction of it: the ground's chance agreements
      // halve or more per sample, dots stay), while it holds twice the share dots must hold and at most
      // kInterimFillMaxShare, and its blobs (DotDetector::blobShare: a dot's speck is about half blob) the share
      // itself; made again when M has shrunk by a tenth (each change starts a new pair). A fine checkerboard's specks
      // keep M falling as slowly as dots (its periodic ground brings them back), but they are wedges, not blobs.
      const double m = dots.wholeShare();
      if (m >= 2.0 * params.fixed_pattern.dot_detect_share && m <= kInterimFillMaxShare &&
          dots.blobShare() >= params.fixed_pattern.dot_detect_share &&
          dots.wholeShareRatio() >= internal::DotDetector::kStableFraction &&
          (img_pre.dotFillId() == 0 || m < 0.9 * interim_m_share)) {
        const bool first = img_pre.dotFillId() == 0;
        dots.fillMask(&dot_mask, 0);
        setFill(dot_mask);
        interim_m_share = m;
        // What the filter holds of the distance and the velocity over distance came from images with the dots
        // (their vote for "no motion"): given back their initial uncertainty, as at the verdict below when there was
        // no interim fill.
        if (first) restarts.setInitialScaleCovariance(&P);
      }
    }
  }

  /// Starts learning the dots' gain over the fill's mask (dot_mask), with the learner's grid points unprojected once
  /// (the undistorted normalised coordinates of each; NaN where the lens model has none).
  void startDotGain() {
    dot_gain.start(dot_mask);
    dot_gain_rays.resize(static_cast<size_t>(dot_gain.gridCols()) * static_cast<size_t>(dot_gain.gridRows()));
    for (int j = 0; j < dot_gain.gridRows(); ++j) {
      for (int i = 0; i < dot_gain.gridCols(); ++i) {
        Vec2 xn;
        if (!camera.unproject(Vec2(i * internal::DotGainLearner::kGridPx, j * internal::DotGainLearner::kGridPx), &xn))
          xn = Vec2::Constant(std::numeric_limits<double>::quiet_NaN());
        dot_gain_rays[static_cast<size_t>(j * dot_gain.gridCols() + i)] = xn;
      }
    }
  }

  /// The warp of the pair just updated by the updated state, at the update's time (the state's lag behind image
  /// `img`): where a current pixel's ground lies in the reference, for the learners of the dots' gain and the
  /// vignetting.
  internal::IntervalWarp updatedPairWarp(const PendingImage& img) const {
    return internal::IntervalWarp(x, update.lastGyroMean(), update.lastInterval(), img.t_s - imu.stateTime());
  }

  /// The working image of frame slot `slot` before the fixed pattern's correction (FixedPattern::lastImage), kept
  /// for the vignetting's learner while fixed_pattern/radial_vignetting is on (a copy into the slot's buffer).
  void keepUncorrected(int slot) {
    const auto k = static_cast<size_t>(slot);
    uncorrected_valid[k] = false;
    if (!params.fixed_pattern.enabled || !params.fixed_pattern.radial_vignetting || !fixed_pattern.lastImageKept())
      return;
    fixed_pattern.lastImage().copyTo(uncorrected[k]);
    uncorrected_valid[k] = true;
  }

  /// Learns the lens's radial vignetting from the pair just updated (docs/noise_model.md section 11, "Vignetting
  /// from the motion"; VignettingLearner): the current image's working pixels mapped into the reference's by the
  /// updated state (the warp at the update's time, on the learner's grid), both images before the correction.
  /// `pair_ok`: the pair was updated and accepted.
  void learnVignetting(const PendingImage& img, bool pair_ok) {
    const auto cur = static_cast<size_t>(1 - ref_index), ref = static_cast<size_t>(ref_index);
    if (!pair_ok || !uncorrected_valid[cur] || !uncorrected_valid[ref]) return;
    VignettingLearner& learner = fixed_pattern.vignettingLearner();
    if (!learner.due()) return;
    const PinholeK K = scaledFocal(img_pre.workingK(), img_pre.focalScale());
    const internal::IntervalWarp warp = updatedPairWarp(img);
    Vec2* target = learner.gridTargets();
    for (int j = 0; j < learner.gridRows(); ++j)
      for (int i = 0; i < learner.gridCols(); ++i)
        target[j * learner.gridCols() + i] = internal::warpWith(warp, K, i * VignettingLearner::kGridPx,
                                                                j * VignettingLearner::kGridPx, nullptr);
    learner.observe(uncorrected[cur].ptr<float>(), uncorrected[ref].ptr<float>());
  }

  /// Learns the projector dots' gain from the pair just updated (docs/noise_model.md section 11, "Dots divided out";
  /// DotGainLearner): the raw pixels of the current image mapped into the reference's by the updated state (the
  /// warp at the update's time, through the lens distortion, on the learner's grid). Once every pixel of the dots'
  /// region has its samples, the raw images are divided by the gains from then on and only the dots' cores stay
  /// filled. `pair_ok`: the pair was updated and accepted.
  void learnDotGain(const PendingImage& img, bool pair_ok) {
    if (!dot_gain.learning()) return;
    if (!pair_ok || !img.raw_kept || !ref_raw_valid || !health.converged()) return;
    const PinholeK& K = camera.K;
    const internal::IntervalWarp warp = updatedPairWarp(img);  // (pixel-independent: once for the grid)
    Vec2* target = dot_gain.gridTargets();
    const size_t n = dot_gain_rays.size();
    for (size_t k = 0; k < n; ++k) {
      const Vec2& xn = dot_gain_rays[k];
      if (!std::isfinite(xn.x())) {
        target[k] = xn;
        continue;
      }
      const Vec2 p_r = internal::warpWith(warp, K, K.fx * xn.x() + K.cx, K.fy * xn.y() + K.cy, nullptr);
      const Vec2 xd = camera.distort(Vec2((p_r.x() - K.cx) / K.fx, (p_r.y() - K.cy) / K.fy));
      target[k] = Vec2(K.fx * xd.x() + K.cx, K.fy * xd.y() + K.cy);
    }
    dot_gain.observe(img.raw.data, ref_raw.data);
    if (!dot_gain.ready()) return;
    cv::Mat inv_gain, core;
    const double core_share = dot_gain.result(&inv_gain, &core);
    dot_gain.stop();
    std::vector<Vec2>().swap(dot_gain_rays);
    ref_raw.release();
    ref_raw_valid = false;
    img_pre.setDotGain(inv_gain);
    setFill(core);
    char msg[kMessageCapacity];
    std::snprintf(msg, sizeof(msg),
                  "projector dots: their gain learned, raw images divided by it; the dots' cores filled over %.1f %% "
                  "of the image",
                  100.0 * core_share);
    warn(msg);
  }

  /// Fills the raw pixels of `mask` from now on (empty: no fill), and weighs the working pixels under it
  /// (weighFill) for the last update's per-pixel noise.
  void setFill(const cv::Mat& mask) {
    img_pre.setDotFill(mask);
    if (mask.empty()) {
      fill_confidence.release();
      return;
    }
    weighFill(last_noise_sigma > 0.0 ? last_noise_sigma : params.photometric.intensity_noise_sigma);
  }

  /// The working pixels' confidence under the fill for the per-pixel noise 1-sigma `sigma` (normalised units): the
  /// fill is an interpolation fixed in the image, and a pixel whose resampling footprint lies on filled raw pixels
  /// by the share f carries its error, at most f times the ground's detail it replaces, which is at most the working
  /// image's own spread (unit variance): its variance sigma^2 + f^2 against sigma^2, so the weight
  /// 1 / (1 + f^2 / sigma^2) (docs/noise_model.md section 11). Made again when the noise has moved by a fifth.
  void weighFill(double sigma) {
    const cv::Mat& coverage = img_pre.dotFillCoverage();
    fill_confidence.create(coverage.size(), CV_32FC1);  // (no allocation after the first fill)
    const float inv_var = static_cast<float>(1.0 / (sigma * sigma));
    for (int y = 0; y < coverage.rows; ++y) {
      const float* f = coverage.ptr<float>(y);
      float* w = fill_confidence.ptr<float>(y);
      for (int xx = 0; xx < coverage.cols; ++xx) w[xx] = 1.0f / (1.0f + f[xx] * f[xx] * inv_var);
    }
    fill_sigma = sigma;
  }

  /// Switches the opening of the raw images on (side_px, or fixed_pattern.auto_dot_removal_px when 0; never when
  /// auto_dot_removal_px is 0), or the fill of the pixels in `fill_mask` instead when given (fixed_pattern.dot_fill),
  /// once per estimator: the pattern is learned anew from the opened (filled) images, the
  /// distance and velocity over distance get their initial uncertainty back; the first opened image starts a new
  /// pair (processImage). `why`: the status's reason. docs/noise_model.md section 11.
  void switchOnDotRemoval(double t_s, const char* why, int side_px = 0, const cv::Mat* fill_mask = nullptr) {
    const FixedPatternParams& fp = params.fixed_pattern;
    if (fp.auto_dot_removal_px <= 1 || img_pre.dotRemovalPx() != 0 || dot_removal_switched) return;
    dot_removal_switched = true;
    const bool interim = img_pre.dotFillId() != 0;
    if (fill_mask != nullptr) {
      setFill(*fill_mask);
    } else {
      setFill(cv::Mat());
      img_pre.setDotRemoval(side_px > 0 ? side_px : fp.auto_dot_removal_px);
    }
    fixed_pattern.reset();
    dots.disarm();  // (when the learned pattern came first)
    health.noteDegraded(t_s, why);
    // What the filter holds of the distance and the velocity over distance came from images with the dots (their
    // vote for "no motion" biased every update before the model had learned them, by more than the share learned
    // so far): both are given back their initial uncertainty, uncorrelated (the estimates are kept; the attitude,
    // normal and biases are not affected). Measured better than a restart of the whole filter (docs/results.md).
    // With the interim fill on since the test's first samples the distance's uncertainty was reopened when it
    // started (detectDots) and the updates since saw no dots: the covariance is kept.
    if (!interim) restarts.setInitialScaleCovariance(&P);
  }

  /// The pixels' confidence for the next update: the camera-fixed pattern's, times the dots' fill's (each may be
  /// absent: null when neither is).
  const cv::Mat* pixelConfidence() {
    const cv::Mat* pattern = fixed_pattern.confidence();
    if (fill_confidence.empty()) return pattern;
    if (pattern == nullptr) return &fill_confidence;
    cv::multiply(*pattern, fill_confidence, combined_confidence);  // (allocates once: same size every time)
    return &combined_confidence;
  }

  /// The state's error per unit focal-length error (FrameResult::focal_sensitivity) after an applied update: the
  /// update saw the images of a camera whose focal lengths are (1 + e) x the calibration's, whose flow equals
  /// that of the observed states changed by u e (focalScaleMap, u in the error state), on a prior already off by
  /// s e. It moved the state by K H of what it saw, so s+ = s + K H (u - s), with K H = I - P+ P-^-1 for the
  /// update as it was applied (its noise model, gate and inflation included), but for the states it held (`stats`'
  /// time states, alpha while the start-up holds it: `alpha_held`).
  void carryFocalSensitivity(const ErrorCov& P_before, double lag_s, const UpdateStats& stats, bool alpha_held) {
    const ObservedVec m = focalScaleMap(x, img_pre.workingK(), update.lastGyroMean(), update.lastInterval(), lag_s);
    ErrorVec u = ErrorVec::Zero();
    for (int k = 0; k < internal::kObsDim; ++k) u(internal::kObsToErr[k]) = m(k);
    ErrorVec& s = imu.focalSensitivity();
    const Eigen::LDLT<ErrorCov> ldlt(P_before);
    if (ldlt.info() != Eigen::Success) return;
    const ErrorVec du = u - s;
    ErrorVec kh = du - P * ldlt.solve(du);
    // (P_before - P) P_before^-1 is the update's K H only in the rows of the states it estimated. A state it held
    // (a consider state: gain row zero, mean and variance the prior's) keeps its carried error: read through that
    // identity, the held time offset's grew from 0 until its reported 1-sigma was twice its prior's.
    if (stats.time_states_held) kh.segment<ErrIdx::kTimeStates>(ErrIdx::kTd).setZero();
    if (stats.readout_held) kh(ErrIdx::kRo) = 0.0;
    if (stats.offset_held) kh(ErrIdx::kTd) = kh(ErrIdx::kFs) = 0.0;
    if (alpha_held) kh(ErrIdx::kAlpha) = 0.0;
    if (kh.allFinite()) s += kh;
  }

  /// The focal-length scale starts to be estimated (estimate_focal_scale; ImageUpdate::estimatesFocalScale): until
  /// now the state's estimate moved by s e for the true focal error e, while the scale's own estimate stayed at its
  /// prior, off by -e. Their errors are therefore correlated: P_xx += var_f s s^T, P_xf = -var_f s, with var_f the
  /// scale's variance so far. The carried error becomes P's own (it is no longer added to the report, nor dropped);
  /// docs/algorithm.md section 3.8.
  void foldFocalSensitivity() {
    ErrorVec& s = imu.focalSensitivity();
    s(ErrIdx::kFs) = 0.0;
    const double var_f = P(ErrIdx::kFs, ErrIdx::kFs);
    if (s.allFinite() && var_f > 0.0) {
      P.noalias() += var_f * s * s.transpose();
      P.col(ErrIdx::kFs) -= var_f * s;
      P.row(ErrIdx::kFs) -= var_f * s.transpose();
    }
    s.setZero();
    focal_folded = true;
  }

  /// The readout estimated from the first image (readout_from_first_image) learned from the images while the time
  /// offset was not in their model (before convergence), and while the rows' rates were uncertain (errors in the
  /// variables, a pull toward 0): a flight that hovers until 12 s read 8 +- 1.6 ms against 16. At convergence, when
  /// the offset's column enters the update (readout_with_considered_offset; else when the offset's estimate starts,
  /// the readout held with the offset until then), the readout keeps its estimate but gets back its prior variance,
  /// without its correlations (a principal block of P and a variance: P stays positive definite), and its carried
  /// focal error is dropped with them (docs/algorithm.md section 3.7, "From the first image"). Once per convergence.
  void reopenReadout(double t_img_s) {
    if (!health.converged()) readout_reopened = false;
    const bool reopen_now = params.readout_with_considered_offset ? health.converged()
                                                                  : update.timeStatesSettled(t_img_s, health);
    if (readout_reopened || !update.readoutFromFirstImage() || !reopen_now) return;
    readout_reopened = true;
    const double prior_var_s2 = params.init.sigma_readout_s * params.init.sigma_readout_s;
    const double var_s2 = std::max(P(ErrIdx::kRo, ErrIdx::kRo), prior_var_s2);
    P.row(ErrIdx::kRo).setZero();
    P.col(ErrIdx::kRo).setZero();
    P(ErrIdx::kRo, ErrIdx::kRo) = var_s2;
    imu.focalSensitivity()(ErrIdx::kRo) = 0.0;
  }

  /// A gravity direction in C and its tangent covariance, carried through a restart (gravityToKeep).
  struct KeptGravity {
    bool valid = false;  // false: none kept (the accelerometer's, or g0)
    UnitVector g;
    Mat2 P = Mat2::Zero();
  };

  /// The gravity direction an automatic restart at this image keeps (init.keep_gravity_on_restart): the running
  /// filter's estimate, propagated by the gyro to this image, and its covariance, when it knows it at least as well
  /// as the start-up prior (startAt then tests it against the accelerometer). The restart is for the scale; taken
  /// again from the accelerometer, gravity would point along the thrust (a multirotor's specific force hardly tilts
  /// with it) and a restart in a manoeuvre started as far off as the vehicle was tilted (fast flights: 0.5-6 deg RMS
  /// over the next 1.5 s; docs/algorithm.md section 4).
  KeptGravity gravityToKeep() const {
    KeptGravity kept;
    if (!params.init.keep_gravity_on_restart || !state_initialized) return kept;
    const double prior_var = params.init.sigma_g0_rad * params.init.sigma_g0_rad;
    const Mat2 P_g = P.block<2, 2>(ErrIdx::kG, ErrIdx::kG);
    if (!x.g.vector().allFinite() || !P_g.allFinite() || P_g.trace() > 2.0 * prior_var) return kept;
    kept.valid = true;
    kept.g = x.g;
    kept.P = P_g;
    return kept;
  }

  /// Starts the filter at image `t_s`: gravity from the accelerometer (or `kept`'s, gravityToKeep), no propagation
  /// before.
  void startAt(double t_s, const KeptGravity& kept) {
    UnitVector g;
    double spread_var_rad2 = 0.0;
    const bool from_accel = params.init.g0_from_accel && imu.gravityFromAccel(t_s, &g, &spread_var_rad2);
    bool keep = kept.valid;
    if (keep && from_accel) {
      // The kept direction against the accelerometer's: kept unless they differ beyond what the mean specific force
      // may be off by (its spread and the frame's turn over the window, the accelerometer bias's prior) and the kept
      // direction's own variance, chi-square(2) at 99 %. Images of objects moving on their own had turned a run's
      // gravity 9 deg within 0.3 s of hovering, and restarts that kept it never recovered (docs/algorithm.md §4).
      const double sigma_ba_rad = params.init.sigma_ba0_mps2 / params.imu.gravity_mps2;
      const double var_rad2 = spread_var_rad2 + sigma_ba_rad * sigma_ba_rad + 0.5 * kept.P.trace();
      const double angle_rad = std::acos(std::clamp(kept.g.vector().dot(g.vector()), -1.0, 1.0));
      keep = angle_rad * angle_rad <= kGravityKeepChi2 * var_rad2;
    }
    if (keep) {
      x.g = kept.g;
      P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = kept.P;
    } else if (from_accel) {
      x.g = g;
    }
    if (params.init.mu0_from_gravity) x.mu = x.g;  // level-ground prior; sigma_mu0_rad covers inclines
    imu.startAt(t_s);
    imu.focalSensitivity().setZero();
    focal_folded = false;
    last_usable_image_t_s = t_s;
    state_initialized = true;
  }

  /// An automatic restart at image t_s (the health checks or the image gap): counted, warned, a new run from
  /// the warm prior (when there is one).
  void restartAtImage(double t_s, const std::string& reason) {
    restarts.noteRestart(reason);
    warn("filter reset: " + reason);
    resetFilter();
    applyWarmPrior(t_s);
  }

  /// The steps of one image, in order: preprocessing, restart after a long image gap, prediction (to the
  /// interval's midpoint or the image), update from the pair, prediction to the image, new reference, health
  /// checks (a restart from this image if one fails), status, result.
  void processImage(PendingImage& img) {
    const auto t0 = std::chrono::steady_clock::now();
    FrameResult r;
    r.t_s = img.t_s;
    r.stamp_s = img.stamp_s;
    r.stamp_correction_s = img.stamp_correction_s;
    r.stamp_jitter_s = img.stamp_jitter_s;
    if (const VibrationNotch* notch = imu_pre.notch()) {
      const int n = std::min(notch->activeNotches(), static_cast<int>(r.imu_notch_hz.size()));
      for (int i = 0; i < n; ++i) r.imu_notch_hz[static_cast<size_t>(i)] = notch->frequencyHz(i);
    }
    std::string restart_reason;  // set when the filter restarts at this image
    KeptGravity kept_g;               // the gravity direction a restart at this image keeps (gravityToKeep)
    char msg[kMessageCapacity] = "";  // the result's message, formatted without allocation

    // Preprocessing.
    PreprocessedFrame& cur = frames[1 - ref_index];
    const bool pattern_on = params.fixed_pattern.enabled || !params.fixed_pattern.vignetting_file.empty();
    img_pre.finish(&img.stage, img.t_s, &cur, pattern_on ? &fixed_pattern : nullptr);
    keepUncorrected(1 - ref_index);
    std::string usable_why;
    const bool usable = update.usable(cur.gray8, &usable_why);

    if (state_initialized && img.t_s - last_usable_image_t_s > params.input.max_image_gap_s) {
      // The state has been dead-reckoned on the IMU alone for too long: restart, and wait (without
      // propagating) for the next usable image, which becomes the reference of the new run.
      std::ostringstream os;
      os << "no usable image for " << (img.t_s - last_usable_image_t_s) << " s (more than max_image_gap_s = "
         << params.input.max_image_gap_s << " s)";
      restart_reason = os.str();
      kept_g = gravityToKeep();
      restartAtImage(img.t_s, restart_reason);
    }

    // The IMU of this interval for the start-up of the distance (while it collects).
    if (state_initialized && scale_init.phase() == internal::ScaleInitializer::Phase::kCollecting) {
      scale_init.integrate(imu.stateTime(), img.t_s, x, [this](double t) { return imu.imuAt(t); });
    }

    // The reference was placed with the time offset of its own processing; the pair's interval is the cameras'
    // (the offset is one constant), so a changed estimate moves the reference too (docs/algorithm.md section
    // 3.6). Otherwise the interval would be off by the change: a 9 ms step of the estimate made the next pair's
    // NIS 257 on a clean render, and the offset took up the transient.
    if (state_initialized && have_reference && img_t_d_s != ref_t_d_s) {
      const double from_s = frames[ref_index].t_s, to_s = from_s + (img_t_d_s - ref_t_d_s);
      if (to_s < img.t_s && to_s > imu.oldest().t_s) {
        imu.moveReference(from_s, to_s);
        update.retimeReference(from_s, to_s);
        frames[ref_index].t_s = to_s;
      }
    }

    // Prediction.
    if (!state_initialized) {
      if (usable) startAt(img.t_s, kept_g);  // otherwise it waits for a usable image
    } else if (usable && have_reference && params.update_at_interval_midpoint) {
      // The image pair sees the displacement over the whole interval, i.e. its mean velocity, not the velocity
      // at the current image: update the state of the interval's midpoint (exact to second order in the
      // interval), then predict on to the image.
      imu.propagateTo(std::max(imu.stateTime(), 0.5 * (frames[ref_index].t_s + img.t_s)), &x, &P);
    } else {
      imu.propagateTo(img.t_s, &x, &P);
    }

    // Update.
    UpdateStats stats;
    bool pair_updated = false;  // the pair went to the update (the state at its time estimates the pair's motion)
    skip_reason.clear();
    if (!usable) {
      // Keep the reference and the gyro integral: the next usable image is compared with the old reference.
      skip_reason = usable_why;
    } else if (have_reference && (frames[ref_index].dot_removal_px != cur.dot_removal_px ||
                                  frames[ref_index].dot_fill_id != cur.dot_fill_id)) {
      // The dot removal (opening or fill) was switched on between the two images: not a pair; this image is the
      // next reference.
      skip_reason =
          "raw images opened or their dots filled from this image on (dots fixed in the image): new reference";
    } else if (have_reference && frames[ref_index].resample_id != cur.resample_id) {
      // The resampling was re-made for the focal-length estimate between the two images: not a pair.
      skip_reason = "raw images resampled for the focal-length estimate from this image on: new reference";
    } else if (have_reference) {
      update.setPixelConfidence(pixelConfidence());
      update.setReferenceConfidence(fill_confidence.empty() ? nullptr : &fill_confidence);  // the same fill on both
      const double alpha0 = x.alpha, var_alpha0 = P(ErrIdx::kAlpha, ErrIdx::kAlpha);
      update.setReportImageVartheta(scale_init.phase() != internal::ScaleInitializer::Phase::kDone);
      // The focal-length scale's estimate starts with this update: its carried error folded into P first.
      if (!focal_folded && update.estimatesFocalScale(img.t_s, health, P)) foldFocalSensitivity();
      reopenReadout(img.t_s);
      // The prior and the state's lag behind the image, for the focal length's carried error.
      const bool carry_focal = !focal_folded;
      const ErrorCov P_before = P;
      const double lag_s = std::max(0.0, img.t_s - imu.stateTime());
      stats = update.apply(frames[ref_index], cur, img.t_s, imu, last_imu_gap_end_s, &health, &x, &P, &skip_reason);
      imu.holdColumnAccel();  // the next predictions' distance column: none of the next innovation's noise
      if (stats.applied && scale_init.holdsAlpha()) holdAlpha(alpha0, var_alpha0);
      if (carry_focal && stats.applied && update.lastPairPhotometric())
        carryFocalSensitivity(P_before, lag_s, stats, scale_init.holdsAlpha());
      // The focal-length estimate in the resampling (docs/algorithm.md section 3.8): a camchain's focal lengths
      // multiply the distorted coordinates, so the working image is a pinhole image only when it is resampled for
      // the camera's own focal lengths. Re-made when the estimate has moved by kFocalResampleStep.
      if (params.estimate_focal_scale && std::abs(x.focal_scale - img_pre.focalScale()) > kFocalResampleStep) {
        img_pre.setFocalScale(x.focal_scale);
      }
      if (update.lastPairPhotometric()) {
        // The camera-fixed pattern learns by how far the ground moved: the rotation (gyro) always, the translation
        // of an accepted image, until the filter has converged only its lower bound (docs/noise_model.md
        // section 11).
        const bool accepted = stats.applied && !stats.gated;
        const Mat3 cov_vartheta = P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta);
        const Vec3 vartheta = !accepted            ? Vec3::Zero()
                              : health.converged() ? x.vartheta
                                                   : lowerBoundVartheta(x.vartheta, cov_vartheta);
        const Vec3 rate = update.lastGyroMean() - x.b_w;
        const double interval_s = update.lastInterval();
        const bool waived = patchConditionWaived(img.t_s);
        if (waived && !health.converged()) {
          // Said while it lasts and the filter converges again: a user learns that something holds the image still
          // (a projector left on). Not a degraded status once converged: an IMU fault loses the scale the same
          // way, and the filter that has recovered from it is tracking.
          char why[kMessageCapacity];
          std::snprintf(why, sizeof(why),
                        "images and IMU disagree (no scale %dx in %.0f s): camera-fixed pattern? learned "
                        "without the hold test",
                        params.fixed_pattern.scale_losses_waive_patches, params.fixed_pattern.scale_loss_window_s);
          health.noteDegraded(img.t_s, why);
        }
        fixed_pattern.waivePatchCondition(waived);
        if (fixed_pattern.learn(imageMotionPx(vartheta, rate, img_pre.workingK(), interval_s),
                                groundShiftPx(vartheta, rate, img_pre.workingK(), interval_s),
                                groundTurnScale(vartheta, rate, interval_s))) {
          img_pre.reapplyPattern(&fixed_pattern, &cur);  // the next pair: one correction in both images
          discountPatternBiasedInformation(img.t_s);
          switchOnDotRemovalIfDominant(img.t_s);
        }
      }
      pair_updated = true;
    }
    detectDots(img, pair_updated, usable && !have_reference);
    learnDotGain(img, pair_updated && stats.applied && !stats.gated);
    learnVignetting(img, pair_updated && stats.applied && !stats.gated);
    const double t_update_s = imu.stateTime();
    if (state_initialized && imu.stateTime() < img.t_s) imu.propagateTo(img.t_s, &x, &P);  // from the midpoint
    internal::ScaleInitializer::ImageVartheta image_vartheta;
    if (stats.vartheta_image_valid) {
      image_vartheta.vartheta = stats.vartheta_image;
      image_vartheta.cov = stats.vartheta_image_cov;
      image_vartheta.lag_s = img.t_s - t_update_s;
    }
    if (stats.applied &&
        scale_init.addFrame(img.t_s, x, P, stats.vartheta_image_valid ? &image_vartheta : nullptr)) {
      // The batch's distance, fused as a measurement of alpha = 1 / d.
      const double d = scale_init.distance(), sigma_alpha = scale_init.sigmaDistance() / (d * d);
      const double S = P(ErrIdx::kAlpha, ErrIdx::kAlpha) + sigma_alpha * sigma_alpha;
      const ErrorVec K = P.col(ErrIdx::kAlpha) / S;
      x = x.boxplus(K * (1.0 / d - x.alpha));
      const ErrorCov KP = K * P.row(ErrIdx::kAlpha);
      P -= KP;
      P = 0.5 * (P + P.transpose()).eval();
    }
    const bool had_reference = have_reference;
    if (usable) {  // this image is the next reference
      last_usable_image_t_s = img.t_s;
      imu.setReference(img.t_s);
      ref_t_d_s = img_t_d_s;
      ref_index = 1 - ref_index;
      have_reference = true;
      ref_raw_valid = img.raw_kept;
      if (img.raw_kept) std::swap(ref_raw, img.raw);  // (the slot keeps the older buffer: no allocation)
    }

    const auto t1 = std::chrono::steady_clock::now();
    r.update_ms = img.resample_ms + std::chrono::duration<double, std::milli>(t1 - t0).count();
    fillStats(stats, &r);
    if (stats.applied && std::isfinite(stats.relief_var)) relief_var = stats.relief_var;  // (kept when not)
    if (stats.applied && std::isfinite(stats.noise_sigma) && stats.noise_sigma > 0.0) {
      last_noise_sigma = stats.noise_sigma;
      if (!fill_confidence.empty() && std::abs(std::log(last_noise_sigma / fill_sigma)) > std::log(1.2))
        weighFill(last_noise_sigma);
    }
    r.relief_sigma = std::sqrt(relief_var);
    r.fixed_pattern_active = fixed_pattern.active();
    r.fixed_pattern_fraction = fixed_pattern.strongFraction();
    r.fixed_pattern_contrast_share = fixed_pattern.contrastShare();
    r.vignetting_corner = fixed_pattern.corrects() ? fixed_pattern.vignettingAtCorner() : 1.0;
    r.dot_removal_px = img_pre.dotRemovalPx();
    r.dot_fill_pct = 100.0 * img_pre.dotFillShare();
    r.dot_gain_pct = 100.0 * img_pre.dotGainShare();
    r.projector_dot_share = dot_share;
    health.countUpdate(stats.applied);

    // Health checks and restarts.
    std::string reason;
    health.checkDivergence(x, P, stats.applied, usable, skip_reason, &reason);
    if (health.scaleLost()) scale_losses_s.push(img.t_s);
    if (reason.empty() && had_reference && state_initialized && !stats.applied && health.updatesSinceReset() == 0) {
      // No update has succeeded since the (re)start: do not dead-reckon the prior on the IMU alone; start the
      // run again at this image instead (its covariance would only grow, and the first real update would
      // then be linearised far from the truth). Not a restart: not counted, the status goes on.
      const bool warm = restarts.warmStarted();
      const int bad = health.badFrames();
      const std::string skipped = skip_reason;
      kept_g = gravityToKeep();
      resetFilter();
      if (warm) applyWarmPrior(img.t_s);
      restarts.setWarmStarted(warm);
      health.startRun(bad);
      skip_reason = skipped;
      if (usable) startAt(img.t_s, kept_g);
      have_reference = usable;
    }
    if (!reason.empty()) {
      kept_g = gravityToKeep();
      restartAtImage(img.t_s, reason);
      // Restart from this image: it becomes the new reference (if it has texture). Its outlier weights, drawn
      // in its own update just now, stay for the new run's first pair (docs/noise_model.md section 10): without
      // them that pair had no protection, and objects moving on their own set vartheta after every restart.
      if (usable) startAt(img.t_s, kept_g);
      have_reference = usable;
    }

    // Status.
    FrameFacts facts;
    facts.t_s = img.t_s;
    facts.reset_here = reason.empty() ? &restart_reason : &reason;
    facts.usable = usable;
    facts.usable_why = &usable_why;
    facts.had_reference = had_reference;
    facts.skip_reason = &skip_reason;
    facts.last_reset_reason = &restarts.lastReason();
    facts.warm_started = restarts.warmStarted();
    facts.outlier_fraction = r.outlier_fraction;
    facts.accel_mps2 = imu.smoothedAccelLevel().norm();
    r.status = health.frameStatus(facts, x, P, msg, sizeof(msg));
    if (patternReported(params.fixed_pattern, r.fixed_pattern_fraction, r.fixed_pattern_contrast_share)) {
      // A strong camera-fixed pattern (docs/noise_model.md section 11): an IR projector, the drone's shadow, dirt.
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, sizeof(msg) - used,
                    "%sfixed pattern (projector, shadow, dirt?) on %.0f %% of the image, %.0f %% of its contrast",
                    used > 0 ? "; " : "", 100.0 * r.fixed_pattern_fraction, 100.0 * r.fixed_pattern_contrast_share);
    }
    // Converged, but the relief widens the reported distance's relative 1-sigma (section 13) to the tracking
    // threshold or beyond: the status follows what is published, degraded (the estimate is not changed).
    const double relative_sigma_d = relativeSigmaDistance(x, P);
    const double relative_var_d = relative_sigma_d * relative_sigma_d;
    const double tracking_var_d = params.init.tracking_max_relative_sigma_d * params.init.tracking_max_relative_sigma_d;
    const bool relief_degrades = r.status == FilterStatus::kTracking && params.photometric.relief_in_covariance &&
                                 relative_var_d < tracking_var_d && relative_var_d + relief_var >= tracking_var_d;
    const FilterStatus health_status = r.status;  // (a good state to restart from is the health monitor's say)
    if (relief_degrades) {
      // The reason first (the message is bounded; the notes after it may be cut).
      r.status = FilterStatus::kDegraded;
      char rest[kMessageCapacity];
      static_assert(sizeof(rest) == sizeof(msg), "the message is copied whole");
      std::memcpy(rest, msg, sizeof(rest));
      const int n = std::snprintf(msg, sizeof(msg), "sigma_d/d = %.2g with the scene's relief (tracking below %g)%s%s",
                                  std::sqrt(relative_var_d + relief_var), params.init.tracking_max_relative_sigma_d,
                                  rest[0] != '\0' ? "; " : "", rest);
      if (n < 0) msg[0] = '\0';  // (an encoding error; a longer message is cut at the capacity, as intended)
    }
    if (relief_degrades ||
        (params.photometric.parallax_tolerance > 0.0 && r.relief_sigma >= params.photometric.parallax_tolerance)) {
      // The image's motion is not one plane's (section 13): relief, movers, or a state still settling after a
      // start (its error varies the inverse depth over the image too). Say by how much the distance is uncertain.
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, sizeof(msg) - used,
                    "%simage motion not one plane's (relief, movers, or settling): distance uncertain by %.0f %% "
                    "for it",
                    used > 0 ? "; " : "", 100.0 * r.relief_sigma);
    }
    if (r.row_bands_found) {
      // A rolling shutter under flickering light (docs/noise_model.md section 12): bands of the rows.
      const size_t used = std::strlen(msg);
      std::snprintf(msg + used, sizeof(msg) - used, "%slight flicker: rows banded by %.0f %%%s", used > 0 ? "; " : "",
                    100.0 * r.row_banding, r.row_gains ? " (row gains estimated)" : "");
    }
    if (health_status == FilterStatus::kTracking && stats.applied && health.badFrames() == 0)
      restarts.rememberGood(img.t_s, x);

    // Result.
    r.state = x;
    r.covariance = P;
    // The distance to which layer of a scene that is not one plane (section 13 of docs/noise_model.md).
    if (params.photometric.relief_in_covariance) addScaleAmbiguity(x, relief_var, &r.covariance);
    if (params.photometric.relief_in_velocity_covariance) addMotionAmbiguity(x, relief_var, &r.covariance);
    // The calibration's focal length, until it is estimated: its error carried through the updates and the dynamics
    // (carryFocalSensitivity; a scale error of the translation's flow, amplified where the gyro's rotation is
    // mis-predicted by it; docs/noise_model.md section 9), then folded into P (foldFocalSensitivity).
    r.focal_sensitivity = imu.focalSensitivity();
    if (params.photometric.focal_scale_in_covariance && !focal_folded) {
      r.covariance.noalias() += (params.init.sigma_focal_scale * params.init.sigma_focal_scale) *
                                r.focal_sensitivity * r.focal_sensitivity.transpose();
    }
    // The calibration's camera pointing (camera-IMU rotation, principal point): v, mu and g turned together.
    if (params.photometric.camera_rotation_in_covariance)
      addFrameRotationUncertainty(x, params.init.sigma_camera_rotation_rad * params.init.sigma_camera_rotation_rad,
                                  &r.covariance);
    r.resets = restarts.count();
    // Into a ring slot (the oldest unread result is dropped when full), reusing the slot's string buffers.
    FrameResult& slot = results.emplaceSlot();
    r.message.swap(slot.message);
    r.message.assign(msg);
    r.last_reset_reason.swap(slot.last_reset_reason);
    r.last_reset_reason.assign(restarts.lastReason());
    slot = std::move(r);
  }

  static void fillStats(const UpdateStats& stats, FrameResult* r) {
    const auto finiteOr = [](double v, double fallback) { return std::isfinite(v) ? v : fallback; };
    r->update_applied = stats.applied;
    r->passes = stats.passes;
    r->photometric_rms = finiteOr(stats.rms_residual, 0.0);
    r->nis = finiteOr(stats.nis, 0.0);
    r->noise_sigma = finiteOr(stats.noise_sigma, 0.0);
    r->noise_correlation = finiteOr(stats.noise_correlation, 0.0);
    r->noise_floor_sigma = finiteOr(stats.noise_floor_sigma, 0.0);
    r->gate_inflation = finiteOr(stats.gate_inflation, 1.0);
    r->nis_scale = finiteOr(stats.nis_scale, 1.0);
    r->outlier_fraction = finiteOr(stats.outlier_fraction, 0.0);
    r->valid_ratio = finiteOr(stats.valid_ratio, 0.0);
    r->brightness_gain = finiteOr(stats.brightness_gain, 1.0);
    r->brightness_offset = finiteOr(stats.brightness_offset, 0.0);
    r->row_banding = finiteOr(stats.row_banding, 0.0);
    r->row_bands_found = stats.row_bands_found;
    r->row_gains = stats.row_gains;
    r->light_change = stats.light_change;
  }

  /// Processes every pending image whose stamp is covered by filtered IMU data. Before the filter has started,
  /// images older than the oldest buffered IMU sample (e.g. images before any IMU data) are dropped.
  void processReady() {
    while (!images.empty()) {
      PendingImage& img = images[0];
      // The image's time on the IMU clock with the estimated offset on top of the calibration's
      // (docs/algorithm.md section 3.6); never before the state's time.
      const double t_d_s = params.estimate_time_offset ? x.t_d_s : 0.0;
      double t_img_s = img.t_s + t_d_s;
      if (state_initialized) t_img_s = std::max(t_img_s, imu.stateTime() + 1e-6);
      if (imu.empty() || imu.newest().t_s < t_img_s) return;
      if (!state_initialized && img.t_s < imu.oldest().t_s) {
        std::ostringstream os;
        os << "image at " << img.t_s << " s older than the IMU data (from " << imu.oldest().t_s << " s) dropped";
        warn(os.str());
        if (img.dots_sampled) dots.notePosition(false);  // (the detector samples one image at a time)
        images.pop();
        continue;
      }
      img_t_d_s = t_d_s;  // (the offset's part only: not the step to after the state's time)
      img.t_s = t_img_s;
      processImage(img);
      images.pop();
    }
  }

  /// Back to the initial state with an empty IMU pipeline and image queue. `automatic`: caused by the input
  /// (the next frame reports status reset with the reason); otherwise requested by the user. `warm`: from the
  /// warm prior at t_now_s (an IMU gap); otherwise the remembered states are forgotten (they are from other data).
  void restart(const std::string& reason, bool automatic, bool warm = false, double t_now_s = 0.0) {
    warn((automatic ? "filter reset: " : "reset: ") + reason);
    restarts.noteRestart(reason);
    resetFilter();
    update.forgetWeights();  // the images are dropped: the next reference is a new image
    if (warm) {
      applyWarmPrior(t_now_s);
    } else {
      restarts.forgetHistory();
    }
    imu_pre.reset();
    imu.clear();
    images.clear();
    have_raw_imu = false;
    last_image_t_s = -HUGE_VAL;
    health.setInitializing();
    health.announceReset(automatic ? reason : std::string());
  }

  CameraModel camera;
  EstimatorParams params;
  ImuPreprocessor imu_pre;           // raw IMU -> filtered samples in C
  ImagePreprocessor img_pre;         // raw image -> working image
  cv::Mat grey_scratch;              // colour or 16-bit input converted to 8-bit grey (reused buffer)
  FixedPattern fixed_pattern;        // camera-fixed gain and offset fields (docs/noise_model.md section 11)
  double discounted_share = 0.0;     // the pattern's contrast share the covariance allows for (discountPattern...)
  double relief_var = 0.0;           // the scene's smoothed relief variance of the last update, relative^2
  bool pattern_named = false;        // the status has named the dominant pattern in view
  internal::DotDetector dots;        // projector dots in the raw images (configured when enabled)
  cv::Mat dot_mask;                  // the raw pixels the dots light, once found (DotDetector::fillMask)
  cv::Mat fill_confidence;           // working pixels' confidence under the fill (weighFill)
  double fill_sigma = 0.0;           // the per-pixel noise 1-sigma fill_confidence was made for
  double last_noise_sigma = 0.0;     // the last applied update's per-pixel noise 1-sigma (0: none yet)
  cv::Mat combined_confidence;       // fill_confidence times the pattern's (pixelConfidence)
  bool dot_removal_switched = false; // the opening or the fill switched on for good (switchOnDotRemoval)
  internal::DotGainLearner dot_gain;  // the dots' gain, learned after the verdict (learnDotGain)
  std::vector<Vec2> dot_gain_rays;    // its grid points' normalised coordinates (startDotGain)
  cv::Mat ref_raw;                   // the reference image's raw copy while the gain is learned
  bool ref_raw_valid = false;        // ref_raw is the current reference's
  double interim_m_share = 0.0;      // M's share when the interim fill was last made
  static constexpr double kGravityKeepChi2 = 9.21;  // chi-square(2) at 99 % (startAt's test of a kept gravity)
  /// The interim fill is made while M holds at most this share of the image (more: the ground's specks, a ground the
  /// test cannot tell yet).
  static constexpr double kInterimFillMaxShare = 0.15;
  double dot_share = -1.0;           // the detector's share of fixed specks at its verdict (-1: none yet)
  internal::ImuPropagator imu;       // filtered samples, state time, prediction
  internal::ImageUpdate update;      // update from an image pair
  internal::HealthMonitor health;    // checks and status
  internal::RestartPolicy restarts;  // priors of a run, restart count
  internal::ScaleInitializer scale_init;  // start-up of the distance (hold alpha, then one batch solve)

  Ring<PendingImage> images;  // images waiting for IMU coverage
  Ring<FrameResult> results;  // unread results
  Ring<double> scale_losses_s;  // times of the last restarts without scale (patchConditionWaived), s
  PreprocessedFrame frames[2];
  int ref_index = 0;
  cv::Mat uncorrected[2];                  // per frame slot: the working image before the pattern's correction
  bool uncorrected_valid[2] = {false, false};
  double img_t_d_s = 0.0;  // time offset estimate (beyond the calibration's) the image in process was placed with, s
  double ref_t_d_s = 0.0;  // ... the reference image was placed with, s

  State x;
  ErrorCov P = ErrorCov::Zero();
  double last_usable_image_t_s = 0.0;  // stamp of the last image with texture (or of the start), IMU clock
  bool state_initialized = false;
  /// The focal-length scale is estimated (estimate_focal_scale) and its carried error has been folded into P at
  /// the first update that estimated it (foldFocalSensitivity); until then the sensitivity is carried.
  bool focal_folded = false;
  /// The focal-length estimate's change that re-makes the resampling (ImagePreprocessor::setFocalScale): the working
  /// image is then a pinhole image to within half of it at the corners of a strongly distorted lens (the MYNT EYE's
  /// radtan k1 = -0.32 turns a focal error e at the corner into a scale error of 1.5 e in the working image).
  static constexpr double kFocalResampleStep = 0.002;
  bool have_reference = false;
  double configured_readout_s = 0.0;  // rolling shutter: line delay x (rows - 1) from the parameters, s
  bool readout_reopened = false;      // reopenReadout: done since the last convergence
  double stamp_shift_s = 0.0;         // image stamp -> capture time of the middle row's mid-exposure, s
  std::string skip_reason;            // why the current frame's update was not applied
  double last_imu_gap_end_s = -HUGE_VAL;  // IMU-clock stamp of the first sample after the last bridged gap

  bool have_raw_imu = false;
  double last_raw_imu_t_s = 0.0;
  double last_image_t_s = -HUGE_VAL;
  internal::FrameClock frame_clock{params.input.stamp_smoothing_frames};  // image stamps -> frame times
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
      const StampStep step = classifyStampStep(m.last_raw_imu_t_s, raw.t_s, m.params.input.time_jump_reset_s);
      if (step == StampStep::kJumpBack) {
        // Time jumped backwards (e.g. a looping bag): start again with this sample.
        std::ostringstream os;
        os << "IMU time jumped back by " << -dt << " s";
        m.restart(os.str(), true);
      } else if (step != StampStep::kForward) {
        m.warn(step == StampStep::kDuplicate ? "duplicated IMU stamp rejected" : "out-of-order IMU sample rejected");
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
      if (!m.imu.push(filtered)) return true;
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
    const StampStep step = classifyStampStep(m.last_image_t_s, t_s, m.params.input.time_jump_reset_s);
    if (step == StampStep::kJumpBack) {
      std::ostringstream os;
      os << "image time jumped back by " << (m.last_image_t_s - t_s) << " s";
      m.restart(os.str(), true);
    } else if (step != StampStep::kForward) {
      m.warn(step == StampStep::kDuplicate ? "duplicated image stamp rejected" : "out-of-order image rejected");
      return false;
    }
    if (m.images.full()) {
      m.warn("image queue full (no IMU data covering the images): oldest image dropped");
      if (m.images[0].dots_sampled) m.dots.notePosition(false);
    }
    PendingImage& slot = m.images.emplaceSlot();
    // The frame's time from the camera's frame clock (arrival jitter removed; exact stamps unchanged).
    const double t_frame_s = m.params.input.stamp_smoothing ? m.frame_clock.frameTime(t_s) : t_s;
    slot.t_s = t_frame_s;
    slot.stamp_s = t_cam_s;
    slot.stamp_correction_s = t_s - t_frame_s;
    slot.stamp_jitter_s = m.frame_clock.fitted() ? m.frame_clock.jitter_s() : 0.0;  // (never fitted when off)
    // The first stage of the preprocessing now, straight from the caller's pixels (8-bit grey: no copy);
    // other types through the package's one grey conversion (grey_image.h) into a reused buffer.
    const auto t0 = std::chrono::steady_clock::now();
    const bool grey8 = depth == CV_8U && channels == 1;
    if (!grey8) toGrey8(image, ChannelOrder::kBgr, &m.grey_scratch);
    const cv::Mat& grey = grey8 ? image : m.grey_scratch;
    m.img_pre.resample(grey, &slot.stage);
    slot.raw_kept = m.dot_gain.learning();
    if (slot.raw_kept) grey.copyTo(slot.raw);  // (contiguous; allocated once per slot)
    slot.dots_sampled = m.dots.wantsImage();
    if (slot.dots_sampled) m.dots.addImage(grey);
    slot.resample_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
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
FilterStatus Estimator::status() const { return impl_->health.status(); }
double Estimator::stateTime() const { return impl_->imu.stateTime(); }
const EstimatorParams& Estimator::params() const { return impl_->params; }
const PinholeK& Estimator::workingK() const { return impl_->img_pre.workingK(); }
const cv::Mat& Estimator::lastResidualImage() const { return impl_->update.residualImage(); }
const cv::Mat& Estimator::lastOutlierWeights() const { return impl_->update.outlierWeights(); }

int Estimator::resetCount() const { return impl_->restarts.count(); }
const std::string& Estimator::lastResetReason() const { return impl_->restarts.lastReason(); }

std::string Estimator::takeWarning() {
  std::string w;
  w.swap(impl_->warning);
  return w;
}

}  // namespace diekf
