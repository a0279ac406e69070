// Iterated photometric update (docs/algorithm.md §3): whole-image residual between the reference and current
// working images under the continuous homography of the plane, Gauss-Newton gain in information form.
#pragma once

#include "diekf/camera_model.h"
#include "diekf/image_preprocessor.h"
#include "diekf/params.h"
#include "diekf/state.h"

#include <array>
#include <cstdint>
#include <vector>

namespace diekf {

struct UpdateStats {
  bool applied = false;          ///< false if skipped (too few valid pixels, non-finite system)
  int passes = 0;                ///< Gauss-Newton passes run
  /// RMS of the photometric residual over the valid pixels at the LAST LINEARISATION POINT, i.e. the estimate
  /// before the final Gauss-Newton step (the prior for a one-pass update: the innovation RMS; x_{J-1} for J
  /// passes). Normalised intensity units. It is what the last pass already computed, so no extra sweep over
  /// the image is needed; for divergence detection the innovation is the meaningful quantity anyway.
  double rms_residual = 0.0;
  double valid_ratio = 0.0;      ///< fraction of pixels inside the bounds mask (last linearisation)
  double last_step_norm = 0.0;   ///< |delta| of the last pass
  // Noise model and gate (docs/noise_model.md); 0 where not computed.
  double residual_sigma = 0.0;   ///< robust scale of the residual at the last linearisation (normalised units)
  double correlation = 0.0;      ///< score-correlation factor of the last linearisation (pixels per independent one)
  double noise_sigma = 0.0;      ///< per-pixel noise 1-sigma used in this update (normalised units)
  /// The sensor noise's share of the residual: 1-sigma of the pair's residual from sensor noise alone
  /// (sensor_noise_grey through the resampling and blur, both images), normalised units (docs/noise_model.md
  /// section 2). Near 0 on well-textured ground; it approaches sqrt(2) as the ground's contrast sinks into the noise.
  double noise_floor_sigma = 0.0;
  double noise_correlation = 0.0;  ///< pixels per independent measurement used in this update
  double nis = 0.0;              ///< normalised innovation squared of the first pass (chi-square(8) if consistent)
  double nis_scale = 1.0;        ///< innovation-based noise inflation used in this update (>= 1)
  double gate_inflation = 1.0;   ///< factor the measurement noise was inflated by at the gate (1: passed)
  double outlier_fraction = 0.0; ///< share of the valid pixels' weight removed by the outlier weights (0..1)
  /// Variance of the scene's inverse depth relative to the plane (relative units, squared) over the image the
  /// outlier weights were made for, beyond what noise and the normal's uncertainty explain: how far the scene is
  /// from one plane (boxes, plants, movers; docs/noise_model.md section 13). Smoothed over the updates like the
  /// noise estimates (photometric/noise_time_constant_s; the first after a reset as it is); 0 without parallax
  /// sums.
  double relief_var = 0.0;
  bool gated = false;            ///< the innovation failed the gate: the update was down-weighted
  /// The update held these states as consider states (Schmidt: their mean and variance the prior's): the time
  /// offset, readout and focal scale together (an improbable frame, or the offset not yet estimated), or the
  /// readout alone, or the offset and the focal scale with the readout estimated (offset_held).
  bool time_states_held = false;
  bool readout_held = false;
  bool offset_held = false;
  /// Brightness change of the pair (PhotometricParams::brightness_model): the current image is modelled as
  /// brightness_gain I_r + brightness_offset (normalised units); 1 and 0 when not estimated.
  double brightness_gain = 1.0;
  double brightness_offset = 0.0;
  /// Brightness model kRows: brightness_gain is the mean of the row gains, this their spread (largest less
  /// smallest); 0 otherwise.
  double brightness_row_spread = 0.0;
  /// Bands of the rows (a rolling shutter under flickering light; docs/noise_model.md section 12): the RMS over
  /// the rows of the pair's relative gain per row (what the row gains fitted plus what the residual still holds),
  /// this frame's and smoothed; whether the bands are found (brightness model auto: the row gains are estimated
  /// from the next update on), and whether this update estimated row gains. 0 / false when not computed.
  double row_gain_rms = 0.0;
  double row_banding = 0.0;
  bool row_bands_found = false;
  bool row_gains = false;
  /// Brightness model kLevels (or auto): this pair's mean residual said the light or the exposure changed, and the
  /// pair was compared as standardised.
  bool light_change = false;
  /// The image pair's own measurement of vartheta, without its prior (1/s): one Gauss-Newton step from the last
  /// linearisation point on the image's information alone, with mu and b_w marginalised under their prior; and
  /// its covariance. For the batch start-up of the distance (docs/algorithm.md section 7.1). Valid when
  /// vartheta_image_valid (computed only after setReportImageVartheta(true)).
  bool vartheta_image_valid = false;
  Vec3 vartheta_image = Vec3::Zero();
  Mat3 vartheta_image_cov = Mat3::Zero();
};

/// Observed error-state columns: vartheta (3), mu (2), b_w (3).
using WarpJacobian = Eigen::Matrix<double, 2, 8>;
/// Information block over the observed columns (8x8) and the matching information vector (8).
using ObservedInfo = Eigen::Matrix<double, 8, 8>;
using ObservedVec = Eigen::Matrix<double, 8, 1>;
/// Parameters of the pair's brightness model: (gain, offset), or the gains at the row knots (kRows).
using BrightnessVec = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, PhotometricParams::kMaxBrightnessRowKnots, 1>;

/// The timing of an image pair beyond its stamps (docs/algorithm.md sections 3.6 and 3.7): what the camera-IMU
/// time offset and the rolling shutter need.
struct ImageTiming {
  bool estimate_offset = false;       ///< the update estimates x.t_d_s (its column: timeOffsetMap)
  /// The offset's column is in the update but x.t_d_s is held (a consider state, Schmidt): its uncertainty widens
  /// the innovation and its cross-covariance with the other states builds up before it is estimated.
  bool consider_offset = false;
  /// While the offset is considered, the readout is estimated (with estimate_readout): the update holds the offset
  /// and the focal scale only (readout_with_considered_offset); false: every time state with the offset.
  bool readout_with_considered_offset = false;
  bool rates_valid = false;           ///< accel_C and rate_change_C are filled (stateRateMap is not zero)
  Vec3 accel_C = Vec3::Zero();        ///< filtered specific force at the state's time (bias not removed), m/s^2
  Vec3 rate_change_C = Vec3::Zero();  ///< filtered rate at the current image minus at the reference image, rad/s
  /// The gyro's white-noise density, (rad/s)^2/Hz: its angle over the interval is uncertain by this times dt
  /// (part of the rotation model error, docs/noise_model.md section 6).
  double gyro_noise_density_sq = 0.0;
  /// Noise variances (per axis of C) of the acceleration accel_C + g0 g the rates are computed from, (m/s^2)^2,
  /// and of rate_change_C, (rad/s)^2: while the readout is estimated, the rows of a rolling shutter take the
  /// expected rates given these noisy readings (stateRateMap with `expected`; zero: the readings as they are).
  Vec3 accel_noise_var = Vec3::Zero();
  Vec3 rate_change_noise_var = Vec3::Zero();
  /// The rate change's mean square over the recent frames (rates_window_s; ImageUpdate), (rad/s)^2 per axis of C:
  /// its expected value shrinks the reading by the share of that power its noise explains (expectedGivenReading).
  /// Zero: the reading's own square.
  Vec3 rate_change_mean_sq = Vec3::Zero();
  double gravity_mps2 = 9.81;         ///< magnitude of gravity, m/s^2
  /// Rolling shutter: working row y is captured readout row_weight[y] after the image's time, with the readout
  /// time (first to last raw row) of the state (State::readout_s; 0: global shutter); row_weight[y] is the
  /// row's mean raw row minus the middle one, over (raw rows - 1) (readoutRowWeights). Null: no rolling shutter.
  const float* row_weight = nullptr;
  int rows = 0;                       ///< length of row_weight (the working image's height)
  /// Per pixel (readoutPixelWeights; null or another size: the row's time for every pixel of the row).
  const cv::Mat* pixel_weight = nullptr;
  bool estimate_readout = false;      ///< the update estimates x.readout_s
  /// The readout's column is in the update but x.readout_s and its variance are held (a consider state, Schmidt),
  /// while it is not estimated yet: a rolling shutter it cannot yet model widens the update instead of biasing it.
  bool consider_readout = false;
  /// The readout's column is in the update (estimated or considered): the sweep needs the row moments.
  bool readoutColumn() const { return estimate_readout || consider_readout; }
  bool estimate_focal_scale = false;  ///< the update estimates x.focal_scale (its column: focalScaleMap)
  /// The focal scale is a consider parameter (focal_scale_consider, Schmidt): its column widens the update while
  /// estimate_focal_scale is set, but x.focal_scale and its own variance are held (its cross-covariances are the
  /// update's), whether or not its column is in the update.
  bool consider_focal_scale = false;
};

/// The rate of what the warp sees when the pair is taken later: an image pair taken delta later than assumed
/// sees the state of delta later (its rates: d vartheta/dt, the tangent rate of mu) and the gyro window shifted
/// by delta (mean rate + delta (w_cur - w_ref) / dt, i.e. b_w - delta (w_cur - w_ref) / dt):
///   m = (alpha (a + g0 g) - w x vartheta + (mu . vartheta) vartheta,  -N(mu)^T w,  -(w_cur - w_ref) / dt)
/// with a = accel - b_a and w = gyro_mean - b_w; over [d_vartheta, d_mu, d_b_w]. Zero unless in.rates_valid.
/// `expected`: the acceleration a + g0 g and the rate change, each a reading of one or two filtered samples, are
/// replaced by their expected values given the readings, r max(0, 1 - var / p) per component (var:
/// in.accel_noise_var, in.rate_change_noise_var; p the reading's own square, for the rate change its mean square
/// over the recent frames, in.rate_change_mean_sq, when set): in slow flight the readings are mostly noise (and the
/// tilt's and the bias's errors), a motion the images do not show; a state fitted against them (the readout, from
/// the rows' times) is pulled toward zero (errors in the variables; docs/algorithm.md section 3.7).
ObservedVec stateRateMap(const State& x, const Vec3& gyro_mean_C, const ImageTiming& in, double dt_s,
                         bool expected = false);
/// The acceleration a + g0 g of stateRateMap (m/s^2, C; with `expected` its expected value given the reading), whose
/// product with alpha is vartheta's rate: alpha's column in the rolling-shutter rows is the rows' shift along
/// (T_ro times this, 0, ..., 0) (docs/algorithm.md section 3.7). Zero unless in.rates_valid.
Vec3 stateRateAcceleration(const State& x, const ImageTiming& in, bool expected = false);
/// The time offset's Jacobian column as a combination of the observed ones, J_t_d = J_obs m: stateRateMap with
/// `expected` (the readings' expected values given their noise) when in.estimate_offset, else zero.
ObservedVec timeOffsetMap(const State& x, const Vec3& gyro_mean_C, const ImageTiming& in, double dt_s);
/// The focal-length scale's Jacobian column as a combination of the observed ones, J_focal ~ J_obs m_f
/// (docs/algorithm.md section 3.8): scaling both focal lengths of K by (1 + e) moves every reference pixel by
/// d p_r / d e = (p_r - c) - D_r H (q_x, q_y, 0); to first order in the interval that is a change of the
/// homography, which the observed columns span, so m_f is the least-squares fit of J_obs m_f to it over a 5x5
/// grid of the working image. `K` is the working intrinsics the warp uses (with the state's focal scale).
/// Returns zero when the warp is undefined at the grid or the fit is singular.
ObservedVec focalScaleMap(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s,
                          double state_lag_s);
/// d p_r / d e of warpToReference's reference pixel when both focal lengths of K are scaled by (1 + e), at e = 0.
Vec2 focalScaleDerivative(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double px,
                          double py, double state_lag_s = 0.0);
/// Per working-image row y (rows of the working image of intrinsics K_working, from the camera `cam`): the
/// mean over the row's pixels of their raw (distorted) row, minus the middle raw row, over (raw rows - 1): the
/// row's capture time per second of rolling-shutter readout (docs/algorithm.md section 3.7).
std::vector<float> readoutRowWeights(const CameraModel& cam, const PinholeK& K_working);
/// Per working pixel, the same for the pixel itself (its own raw row: barrel distortion bends the rows, so the raw
/// row varies along a working row), as six planes of a CV_32FC1 Mat of 6 H rows and W columns: the pixel's
/// weight minus its row's (readoutRowWeights), the weight's derivatives along x and along y (per working px) and its
/// second derivatives xx, xy and yy (per working px squared; the reference pixel's time, docs/algorithm.md §3.7).
constexpr int kReadoutPixelPlanes = 6;  ///< readoutPixelWeights' planes
cv::Mat readoutPixelWeights(const CameraModel& cam, const PinholeK& K_working);

/// x as the warp sees it delta_s later along m (stateRateMap): vartheta + delta m_vartheta, mu [+] delta m_mu,
/// b_w + delta m_bw.
State shiftedAlong(const State& x, const ObservedVec& m, double delta_s);

/// Position in the reference image of current-image pixel (x, y) and its Jacobian w.r.t. the observed error
/// state [d_vartheta, d_mu, d_b_w]. `gyro_mean_C` is the raw mean gyro over the interval (bias subtracted
/// inside); the reference image is dt_s before the current one and the state x refers to the time
/// `state_lag_s` before the current image (0: the current image; dt_s / 2: the interval's midpoint).
/// Constant rate and velocity over the interval, rotation exact (see photometric_update.cpp).
/// NaN (and a NaN Jacobian) when the ray does not stay in front of the reference camera.
Vec2 warpToReference(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double px,
                     double py, WarpJacobian* J = nullptr, double state_lag_s = 0.0);

/// The vector instruction set the photometric sweep (and the image preprocessing) was compiled for, as OpenCV's
/// universal intrinsics resolved it in this build (CV_NEON / CV_SSE2 / CV_SIMD128, fixed at compile time):
/// "NEON (AArch64, 128-bit, fused multiply-add)", "NEON (ARMv7, 128-bit)", "SSE2 (x86-64, 128-bit)" (with
/// ", VEX-encoded" under -mavx and up: outside OpenCV's own build its headers use SSE2 whatever -march says), or
/// "scalar C++ (no SIMD)" for the plain C++ fallback. The ARM builds refuse to compile without NEON unless
/// DIEKF_ALLOW_SCALAR_SIMD is defined (src/core/photometric_update.cpp).
const char* photometricSweepSimd();

class PhotometricUpdate {
 public:
  PhotometricUpdate(const PhotometricParams& params, const PreprocessParams& preprocess);
  /// Updates x and P in place from the pair (ref, cur) separated by dt_s; x and P refer to the time
  /// state_lag_s before the current image (see warpToReference).
  /// With `timing.estimate_offset` the update also estimates x->t_d_s (its change within the update moves the
  /// state and the gyro window the warp sees: timeOffsetMap); with `timing.line_delay_s` each row of the current
  /// image is warped with the motion at its own capture time (rolling shutter, docs/algorithm.md section 3.7).
  UpdateStats update(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                     const Vec3& gyro_mean_C, double dt_s, State* x, ErrorCov* P, double state_lag_s = 0.0,
                     const ImageTiming& timing = ImageTiming());
  /// The image the outlier weights belong to was re-timed from from_s to to_s (Estimator: a changed time offset).
  void retimeWeights(double from_s, double to_s) {
    if (weight_map_t_s_ == from_s) weight_map_t_s_ = to_s;
  }
  /// Residual I_c(p) - I_r(p_r) of the last linearisation (the point rms_residual refers to; CV_32FC1, 0
  /// outside the mask and on pixels skipped by pixel_stride).
  const cv::Mat& residualImage() const { return residual_; }
  /// Outlier weights (CV_32FC1 in [0, 1], docs/noise_model.md section 10) of the last update's current image's
  /// pixels, for the next update; empty before the first update, after a reset or with the weights off.
  const cv::Mat& outlierWeights() const { return weight_map_; }

  /// Noise propagation of the preprocessing (ImagePreprocessor::noiseVarianceGain / noiseCorrelationAreaPx):
  /// the floors of the per-pixel variance and of the correlation area. Defaults 1 and 1.
  void setPreprocessNoise(double variance_gain, double correlation_area_px);
  /// Per-pixel confidence (CV_32FC1 in [0, 1], the image size; not owned, must outlive the next update) that
  /// multiplies the pixels' weights in the next updates, with the outlier weights when there are any
  /// (FixedPattern::confidence, docs/noise_model.md section 11); null: none.
  void setPixelConfidence(const cv::Mat* confidence) { confidence_ = confidence; }
  /// Per-pixel confidence of the reference image's pixels (CV_32FC1 in [0, 1], the image size; not owned, must
  /// outlive the next update), sampled (bilinear) where the warp lands and multiplied into the weights with the
  /// reference's outlier weights: a residual is as good as the worse of its two samples. For what is fixed in the
  /// image on both images of the pair (the projector dots' fill, docs/noise_model.md section 11); null: none.
  void setReferenceConfidence(const cv::Mat* confidence) { ref_confidence_ = confidence; }
  /// Whether update() also computes UpdateStats::vartheta_image (the batch start-up needs it; off by default).
  void setReportImageVartheta(bool on) { report_image_vartheta_ = on; }
  /// Forgets the smoothed noise estimates (the next update starts from its own residuals). The outlier weights
  /// stay: they describe an image (where its content did not move with the plane), not the state, and apply
  /// only to the pair whose reference they were drawn for (docs/noise_model.md section 10).
  void resetNoiseModel() {
    noise_ = NoiseEstimate();
    last_rate_valid_ = false;
  }
  /// Forgets the outlier weights (and with them the parallax sums they carry over).
  void forgetWeights() {
    weight_map_.release();
    weight_map_has_outliers_ = false;
  }

  /// The smoothed relief (UpdateStats::relief_var) starts again from the next update's value: while the state has
  /// not converged the parallax statistics measure its error, not the scene (docs/noise_model.md section 13).
  void forgetRelief() { noise_.relief_valid = false; }

  /// One linearisation at x (what every Gauss-Newton pass accumulates), without the solve:
  /// A = sum w_p S_p^T S_p (full symmetric 8x8) and b = sum w_p S_p^T r_p over the observed columns
  /// [d_vartheta, d_mu, d_b_w]. Returns the number of valid pixels; `candidates` (optional) receives the number
  /// of pixels tried. Frames must be valid CV_32FC1 of equal size (not checked here; update() checks).
  /// Also writes residualImage().
  int linearize(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                const Vec3& gyro_mean_C, double dt_s, const State& x, ObservedInfo* A, ObservedVec* b,
                int* candidates = nullptr, double state_lag_s = 0.0);

 private:
  /// linearize() against the reference whose spline coefficients are in ref_coeff_ (buffers prepared).
  /// Unit-weight sums of one linearisation and the statistics of its residual.
  struct PassSums {
    ObservedInfo A = ObservedInfo::Zero();  ///< sum w S^T S (w: Huber / gradient weights only, no 1/sigma^2)
    ObservedVec b = ObservedVec::Zero();    ///< sum w S^T r
    int valid = 0, candidates = 0;
    double sum_r2 = 0.0;
    double robust_sigma = 0.0;  ///< sqrt(pi/2) mean |r| over the valid pixels (outlier-weighted)
    double correlation = 1.0;   ///< variance of the tile scores over the variance of independent pixels
    double weight_sum = 0.0;    ///< sum of the outlier weights over the valid pixels (= valid without a map)
    double mean_residual = 0.0; ///< outlier-weighted mean residual over the valid pixels
    // Rolling-shutter readout (when estimated): row moments with w_y = ImageTiming::row_weight[y], the row's
    // capture time per second of readout.
    bool has_moments = false;
    ObservedInfo A1 = ObservedInfo::Zero();  ///< sum w_y S^T S
    ObservedInfo A2 = ObservedInfo::Zero();  ///< sum w_y^2 S^T S
    ObservedVec b1 = ObservedVec::Zero();    ///< sum w_y S^T r
    // Brightness model (when estimated): the step of (gain, offset) that minimises the residual at this
    // linearisation with the state held (A and b above already have its columns marginalised).
    bool has_brightness = false;
    BrightnessVec brightness_step;
  };
  struct NoiseEstimate {
    bool valid = false;
    double variance = 0.0;     ///< per-pixel residual variance, normalised units^2
    double correlation = 1.0;  ///< pixels per independent measurement
    double nis_scale = 1.0;    ///< innovation-based inflation (>= 1): E[NIS] = 8 when consistent
    bool relief_valid = false;
    double relief_var = 0.0;   ///< the scene's relief variance (reliefVariance), smoothed like the variance
  };
  /// `m_rows` (stateRateMap), `timing` and the readout time `readout_s` only for a rolling shutter;
  /// `brightness`: (gain, offset) of the pair's brightness model, or its row knots' gains (kRows); null: gain 1,
  /// offset 0 (used unless brightness_model is kNormalised).
  int accumulate(const PreprocessedFrame& cur, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s,
                 double state_lag_s, const State& x, double huber_sigma, PassSums* out,
                 const ObservedVec* m_rows = nullptr, const ImageTiming* timing = nullptr, double readout_s = 0.0,
                 const BrightnessVec* brightness = nullptr);
  /// The row gains' tables for images of `rows` rows (kRows; docs/noise_model.md section 12): per row the first
  /// of its four knots and the spline's basis values, slopes and half curvatures there, over the capture time of
  /// `timing` (its rows' and pixels' readout weights; null: the working rows).
  void prepareRowKnots(int rows, const ImageTiming* timing);
  /// The row gains' spline at row y (tables of prepareRowKnots) for the knots' coefficients `c`: its value, slope
  /// and half curvature over the spline coordinate, into g[0..2].
  void rowSpline(const BrightnessVec& c, int y, double g[3]) const;
  /// The pair's brightness model before its light-change test: the parameter's, auto resolved (kRows while bands
  /// of the rows are found, else kLevels), kLevels as kNormalised for images that are not standardised.
  BrightnessModel pairModel() const;
  /// The degree of ref_coeff_'s B-spline: PhotometricParams::spline_degree, 5 or else 3.
  int splineDegree() const { return params_.spline_degree == 5 ? 5 : 3; }
  /// The reference of the sweeps: its B-spline coefficients (ref_coeff_) and its level (ref_level_offset_).
  void setReference(const PreprocessedFrame& ref);
  /// The bands of the rows after an update (UpdateStats::row_gain_rms, row_banding, row_bands_found) from the last
  /// linearisation's residual and the fitted row gains `brightness` (when estimated); dt_s: the pair's interval.
  void rowBanding(const PreprocessedFrame& cur, const BrightnessVec& brightness, double dt_s, UpdateStats* stats);
  /// Residual image and row scratch for images of `size` (allocates only when the size changes).
  void prepareBuffers(const cv::Size& size);
  /// Outlier weights for the next image from this update's last residual (docs/noise_model.md, section 10).
  /// x, var_mu: the state after the update and the variance of its normal (per tangent axis), rad^2; variance:
  /// the per-pixel noise variance (section 2).
  void updateWeightMap(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K, const State& x,
                       double var_mu, double dt_s, double variance);
  /// UpdateStats::relief_var from the parallax sums and the weights of the map just made (mu: the normal after the
  /// update, var_mu its variance per tangent axis; var_corr: the variance of e times J).
  double reliefVariance(const PinholeK& K, const Vec3& mu, double var_mu, double var_corr) const;
  /// The outlier weights (and the parallax sums) of the last updateWeightMap belong to the pixels of `ref`.
  bool weightsBelongTo(const PreprocessedFrame& ref) const {
    return !weight_map_.empty() && weight_map_.size() == ref.intensity.size() && weight_map_t_s_ == ref.t_s;
  }
  static constexpr int kWindowChannels = 8;  ///< window sums of r^2, gx^2, gx gy, gy^2, gx r, gy r, a^2, a r

  PhotometricParams params_;
  PreprocessParams preprocess_;
  cv::Mat residual_;
  cv::Mat depth_jac_;  ///< CV_32FC1 dr / d rho of the last linearisation: a relative change of a pixel's inverse depth
  cv::Mat ref_x_, ref_y_;  ///< CV_32FC1 where the last linearisation's warp lands in the reference (-1: nowhere)
  cv::Mat parallax_sums_;       ///< CV_32FC2 per cell: carried window sums of a r and a^2 (a = dr / d rho)
  cv::Mat parallax_sums_prev_;  ///< the same of the previous image (swapped)
  cv::Mat ref_coeff_;   ///< CV_32FC1 B-spline coefficients of the reference's intensity, reused between calls
  std::vector<float> spline_scratch_;  ///< the spline prefilter's row block (4 x width), reused between calls
  cv::Mat scratch_;     ///< CV_32FC1 13 x (width rounded up to 4): row buffers of the sweep
  // Brightness model kRows (prepareRowKnots, SweepConfig::row_gain):
  std::vector<float> row_gain_;   ///< per row: the gain, its slope and half curvature over the spline coordinate
  std::vector<int> row_knot_;     ///< per row: the first of its four knots
  std::vector<float> row_basis_;  ///< per row and knot: the basis value, slope and half curvature at the row
  float row_gain_u_to_s_ = 0.0f;  ///< spline coordinate per unit of capture time (0: no per-pixel times)
  int row_knot_tables_knots_ = 0;                   ///< the knot count the tables were made for
  const cv::Mat* row_knot_tables_pixel_ = nullptr;  ///< the per-pixel times they were made with (not owned)
  const float* row_knot_tables_rows_ = nullptr;     ///< the per-row times they were made with (not owned)
  const ImageTiming* row_timing_ = nullptr;         ///< the current update's timing (set within update())
  /// The brightness model of the current update (params' unless auto: kRows while bands are found, else kLevels;
  /// kNormalised for a pair kLevels finds a light change in).
  BrightnessModel effective_model_ = BrightnessModel::kNormalised;
  double ref_grey_per_unit_ = 0.0;  ///< the reference's grey levels per unit (setReference; kLevels)
  double bands_rms_ = 0.0;    ///< smoothed row gain RMS (rowBanding)
  bool bands_valid_ = false;
  bool bands_found_ = false;  ///< bands of the rows found (hysteresis, rowBanding)
  double ref_level_offset_ = 0.0;  ///< PreprocessedFrame::level_offset of the reference (ref_coeff_'s image)
  double noise_variance_gain_ = 1.0;
  double noise_correlation_floor_ = 1.0;
  NoiseEstimate noise_;
  double pending_nis_scale_ = 1.0;  ///< the inflation to keep after the current update
  cv::Mat weight_map_;      ///< CV_32FC1 outlier weights in [0, 1] for the next update (empty: none yet)
  // The weights are computed on cells of 2 x 2 pixels (updateWeightMap):
  cv::Mat weight_cells_;    ///< CV_32FC1, 8 planes of cells: the sums of r^2, gx^2, gx gy, gy^2, gx r, gy r, a^2, a r
  cv::Mat weight_window_;   ///< CV_32FC1, the same planes: their window sums
  cv::Mat weight_cell_w_;   ///< CV_32FC1 per cell: the shift statistic q, then the weight
  std::vector<float> weight_colsum_;  ///< running column sums of the vertical window
  std::vector<double> weight_qx_;     ///< per cell column: the ray's x-coordinate (qx of q = K^-1 p)
  std::vector<float> weight_lanes_;  ///< 4 rows of window sums transposed (rows as lanes), in and out
  cv::Mat weight_inv_pixels_;  ///< CV_32FC1 per cell: 1 / pixels in its window (depends only on the sizes)
  int weight_inv_pixels_hc_ = -1;  ///< the window half-side the table was made for
  std::vector<float> weight_median_buf_;  ///< per-cell values, for their medians; then the rows' flags (border minimum)
  std::array<uint32_t, 2048> weight_median_counts_{};  ///< the medians' histogram (internal::kthSmallest)
  bool use_weight_map_ = false;  ///< weight_map_ applies to the sweeps of the current update
  const cv::Mat* confidence_ = nullptr;  ///< per-pixel confidence (setPixelConfidence), not owned
  bool report_image_vartheta_ = false;
  const cv::Mat* active_map_ = nullptr;  ///< the weights the sweeps of the current update use (null: none)
  const cv::Mat* ref_confidence_ = nullptr;  ///< the reference pixels' confidence (setReferenceConfidence), not owned
  const cv::Mat* ref_map_ = nullptr;  ///< the reference weights the sweeps of the current update use (null: none)
  cv::Mat ref_map_buf_;               ///< outlier weights times the reference's confidence, when both apply
  bool weight_map_has_outliers_ = false;  ///< some weight of weight_map_ is below 1
  double relief_var_ = 0.0;               ///< reliefVariance() of the last map (0: none), not smoothed
  double weight_map_t_s_ = 0.0;           ///< stamp of the image weight_map_'s pixels (and parallax_sums_) belong to
  Vec3 last_rate_C_ = Vec3::Zero();  ///< rotation rate of the previous update's interval, rad/s (camera frame)
  bool last_rate_valid_ = false;
};

}  // namespace diekf
