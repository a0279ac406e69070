// Every tuning parameter of the core, with units. The ROS layer and the offline tools fill this struct from
// the same YAML keys (config/*.yaml); defaults follow the method's paper where it states them.
#pragma once

#include <string>

#include "diekf/types.h"

namespace diekf {

enum class UpdateMode { kIterated, kEkf, kFeature };  ///< "iekf", "ekf" (one pass), "lk"

struct InitParams {
  double alpha0_inv_m = 3.0;                    ///< initial inverse distance, 1/m (0.33 m; the paper: 10)
  Vec3 vartheta0_inv_s = Vec3::Zero();          ///< initial velocity over distance, 1/s
  Vec3 mu0 = Vec3(0.2, -0.1, 0.97);             ///< initial plane normal in C (normalised on use)
  Vec3 g0 = Vec3(0.0, 0.0, 1.0);                ///< initial gravity direction in C (normalised on use)
  bool g0_from_accel = true;                    ///< initialise g from the first filtered accelerometer samples
  bool mu0_from_gravity = true;                 ///< initialise mu as the initial gravity direction (level ground)
  /// an automatic restart during a run keeps the gravity direction the filter carried, with its covariance, unless
  /// the accelerometer contradicts it, instead of taking it again from the accelerometer, which in flight points
  /// along the thrust (docs/algorithm.md §4)
  bool keep_gravity_on_restart = true;
  double sigma_alpha0_inv_m = 3.0;              ///< 1-sigma of alpha0, 1/m
  double sigma_vartheta0_inv_s = 1.0;           ///< 1-sigma of each vartheta0 axis, 1/s
  double sigma_mu0_rad = 0.5;                   ///< 1-sigma of each tangent axis of mu0, rad
  double sigma_g0_rad = 0.1;                    ///< 1-sigma of each tangent axis of g0, rad
  double sigma_ba0_mps2 = 0.1;                  ///< 1-sigma of the initial accelerometer bias, m/s^2
  double sigma_bw0_radps = 0.01;                ///< 1-sigma of the initial gyroscope bias, rad/s
  double sigma_time_offset_s = 0.01;            ///< 1-sigma of the camera-IMU time offset around the calibration's, s
  double sigma_readout_s = 0.01;                ///< 1-sigma of the rolling-shutter readout around the configured, s
  double sigma_focal_scale = 0.02;              ///< 1-sigma of the focal length's relative error (calibration), unitless
  /// 1-sigma per axis of the calibration's camera pointing: the camera-IMU rotation and the principal point (which
  /// tilts the rays as a small rotation does), rad (photometric.camera_rotation_in_covariance)
  double sigma_camera_rotation_rad = 0.0087;
  double tracking_max_relative_sigma_d = 0.15;  ///< status turns tracking once sigma_d / d falls below this
  bool scale_batch = false;                     ///< hold alpha until the images see translation, then solve the
                                                ///< scale in one batch (docs/algorithm.md section 7.1)
  double scale_window_s = 1.0;                  ///< seconds of motion the batch uses, s
  double scale_max_window_s = 3.0;              ///< longest wait for an accepted batch, then alpha is freed, s
  double scale_max_relative_sigma = 0.1;        ///< a batch is accepted when its 1-sigma of the scale is below this
  bool warm_restart = true;                     ///< automatic restarts start from the last tracked distance
  double warm_restart_max_age_s = 10.0;         ///< ... if it is at most this old, s
  double warm_restart_sigma_alpha_relative = 0.35;  ///< 1-sigma of alpha on a warm restart, relative to it
};

struct ImuParams {
  double accel_noise_density = 2.0e-2;          ///< m/s^2/sqrt(Hz) (Kalibr accelerometer_noise_density)
  double gyro_noise_density = 1.7e-3;           ///< rad/s/sqrt(Hz) (Kalibr gyroscope_noise_density)
  double accel_random_walk = 2.0e-3;            ///< m/s^3/sqrt(Hz) (Kalibr accelerometer_random_walk)
  double gyro_random_walk = 2.0e-5;             ///< rad/s^2/sqrt(Hz) (Kalibr gyroscope_random_walk)
  double input_rate_hz = 500.0;                 ///< nominal raw IMU rate, Hz
  double lowpass_cutoff_hz = 20.0;              ///< Butterworth cutoff, Hz
  int lowpass_order = 2;                        ///< Butterworth order (even, 2..8; 0 disables filtering)
  /// Highest propeller vibration frequency expected, Hz (small drones: rotors at 100-200 Hz). An IMU sampling
  /// below twice it folds the vibration into 0..input_rate_hz/2, where `lowpass_order` attenuates it too little.
  double max_vibration_hz = 200.0;
  /// Butterworth order (even, 0..8) used instead of `lowpass_order`, if higher, when input_rate_hz is below
  /// 2 max_vibration_hz (the MYNT EYE S's default 200 Hz IMU); 0: always `lowpass_order`.
  int aliased_lowpass_order = 4;
  /// At those rates also find the folded vibration tones in the stream's spectrum and notch them out before the
  /// low-pass (VibrationNotch).
  bool aliased_notch = true;
  int decimation_factor = 5;                    ///< keep every n-th filtered sample (500 Hz -> 100 Hz)
  /// Each kept sample is the mean of the decimation_factor filtered samples up to it (the lever-arm term
  /// included), stamped at their middle: a prediction step then integrates what the steps at the input rate
  /// would have (integrate-and-dump); false: the n-th filtered sample itself.
  bool decimation_mean = true;
  bool compensate_filter_delay = true;          ///< shift output stamps back by the filter's group delay
  bool lever_arm_compensation = true;           ///< add w x (w x r) for the IMU-camera translation
  bool prime_from_mean = true;                  ///< start the low-pass from the mean of its first samples (one
                                                ///< period of the cutoff) instead of the first raw sample, and
                                                ///< emit nothing until it has settled (settleSamples())
  double jacobian_accel_smoothing_s = 0.1;      ///< the distance's Jacobian column takes the acceleration
                                                ///< smoothed over this time constant (level and trend) and held
                                                ///< from the last image update (docs/algorithm.md 2.1), s;
                                                ///< negative: each step's own reading (the textbook EKF)
  double gravity_mps2 = 9.81;                   ///< magnitude of gravity, m/s^2
};

struct ProcessNoiseParams {
  double alpha_inv_m_per_sqrt_s = 0.01;         ///< random-walk density on alpha, (1/m)/sqrt(s)
  double alpha_rate_noise_sqrt_s = 0.03;        ///< plus k alpha |mu . vartheta| (relative, with the vertical rate), sqrt(s)
  double vartheta_inv_s_per_sqrt_s = 0.05;      ///< random-walk density on vartheta, (1/s)/sqrt(s)
  /// The distance's process noise (the two terms above) moves vartheta with alpha, v = vartheta / alpha unchanged:
  /// the ground's distance changes, the camera's velocity does not (docs/algorithm.md section 2). false: alpha alone.
  bool alpha_noise_keeps_velocity = true;
  /// The product of the distance's and the acceleration's errors in d vartheta / dt = alpha a + ..., which the
  /// linearisation drops, added to vartheta's process noise as if coherent over this time, s (0: off, the
  /// default; docs/algorithm.md section 2.1).
  double bilinear_accel_time_s = 0.0;
  double mu_rad_per_sqrt_s = 0.005;             ///< random-walk density on the normal, rad/sqrt(s)
  double g_rad_per_sqrt_s = 0.001;              ///< random-walk density on gravity, rad/sqrt(s)
  double time_offset_s_per_sqrt_s = 1.0e-4;     ///< random-walk density on the camera-IMU time offset, s/sqrt(s)
  double readout_s_per_sqrt_s = 1.0e-5;         ///< random-walk density on the rolling-shutter readout, s/sqrt(s)
  double focal_scale_per_sqrt_s = 1.0e-5;       ///< random-walk density on the focal-length scale, 1/sqrt(s)
};

struct PreprocessParams {
  int working_width_px = 180;                   ///< width of the image the update works on, px (paper: 90)
  int working_height_px = 0;                    ///< height, px; 0 keeps the calibration's aspect ratio
  double blur_sigma_px = 0.8;                   ///< Gaussian blur at working resolution, px (0 = off)
  double antialias_sigma_px = 0.4;              ///< Gaussian footprint of the resampling, working px (0 = box)
  bool normalize_brightness = true;             ///< zero-mean, unit-variance intensity per frame
  int border_px = 1;                            ///< pixels at the border excluded from the update, px
  /// Side of the square element (raw px, odd; 0 = off) of a grey-scale opening applied to the raw image before
  /// the resampling: removes bright dots smaller than it, such as an IR projector's (docs/noise_model.md §11).
  int dot_removal_px = 0;
};

/// How the photometric update models a brightness change between the two images of a pair
/// (PhotometricParams::brightness_model).
enum class BrightnessModel { kNormalised, kGain, kAffine, kRows, kAuto, kLevels };
/// "normalised" | "gain" | "affine" | "rows" | "auto" | "levels" -> BrightnessModel; throws std::invalid_argument naming the
/// value otherwise.
BrightnessModel parseBrightnessModel(const std::string& name);
const char* toString(BrightnessModel model);

struct PhotometricParams {
  int max_passes = 3;                           ///< Gauss-Newton passes per image (1 = plain EKF)
  double stop_threshold = 0.05;                 ///< stop iterating when |delta| < this
  /// Per-pixel photometric noise 1-sigma in normalised intensity units: with adaptive_noise the start value of
  /// the Huber scale only; without, the fixed noise of every pixel, taken as independent (the paper's model).
  double intensity_noise_sigma = 0.3;
  bool gradient_weighting = false;              ///< weight pixels by gradient magnitude
  /// Degree of the B-spline that interpolates the reference image: 3 (cubic, 4x4 taps) or 5 (quintic, 6x6 taps;
  /// docs/algorithm.md section 3.3).
  int spline_degree = 3;
  double huber_threshold = 0.0;                 ///< Huber threshold on residual / sigma (0 = off)
  double min_valid_ratio = 0.3;                 ///< skip the update if fewer pixels stay in view
  int pixel_stride = 1;                         ///< use every n-th pixel in x and y
  // Measurement noise model (docs/noise_model.md).
  bool adaptive_noise = true;                   ///< noise from the residuals and their correlation (else fixed sigma)
  double sensor_noise_grey = 2.0;               ///< 1-sigma sensor noise per raw pixel, grey levels (the floor)
  int noise_tiles_x = 8;                        ///< tiles across the image for the score-correlation estimate
  int noise_tiles_y = 6;                        ///< tiles down the image
  double noise_time_constant_s = 1.0;           ///< smoothing time constant of the noise estimates, s
  double gate_nis = 26.12;                      ///< chi-square(8) gate on the innovation (99.9 %); 0 = off
  double gate_target_nis = 8.0;                 ///< a gated frame is down-weighted until its NIS equals this
  double nis_time_constant_s = 2.0;             ///< smoothing of the innovation-based inflation, s (0 = off)
  /// Model error of the interval rotation the warp takes from the gyro (docs/noise_model.md, section 6):
  double rotation_scale_sigma = 0.02;           ///< relative 1-sigma of image rotation vs gyro (focal length, gyro scale)
  double time_offset_sigma_s = 0.002;           ///< 1-sigma of the camera-IMU time offset error, s
  /// Outlier weights (docs/noise_model.md, section 10): w = 1 / (1 + (m / (k^2 m_ref))^2), m the mean square
  /// residual of a pixel's neighbourhood, m_ref the larger of the noise variance and the median m; 0 = off.
  double outlier_threshold_sigma = 3.0;
  double outlier_window_fraction = 0.04;        ///< side of the neighbourhood as a fraction of the image width
  /// Parallax (section 10): a neighbourhood whose inverse depth, measured over the recent images, differs from the
  /// dominant plane's by this relative amount gets half weight (twice as much: 6 %); it is not the ground; 0 = off.
  double parallax_tolerance = 0.05;
  double parallax_time_constant_s = 0.5;        ///< memory of that measurement over the images, s
  /// The scene's spread of inverse depth about the plane beyond noise (UpdateStats::relief_var, smoothed over
  /// noise_time_constant_s) is added to the reported covariance along the scale direction of (alpha, vartheta):
  /// over boxes, plants or movers the images define "the plane" only to that relative accuracy. The filter's own
  /// covariance is not changed (docs/noise_model.md section 13).
  bool relief_in_covariance = true;
  /// The same relative variance added to the reported velocity's, along v (addMotionAmbiguity): where the image's
  /// parts move differently (movers), which motion is the ground's is known only to that accuracy, and the scale
  /// fitted to the images' motion with it (docs/noise_model.md section 13). The filter's own covariance is not changed.
  bool relief_in_velocity_covariance = true;
  /// While the focal length is not estimated (estimate_focal_scale false, or until its estimate starts), add its
  /// calibration uncertainty (init.sigma_focal_scale) to the reported covariance along the state's error per unit
  /// focal error (FrameResult::focal_sensitivity, carried through every update and prediction: a focal length off
  /// by e scales the translation's flow and mis-predicts the gyro's rotation of the image by e of itself). The
  /// estimates and the filter's own covariance are not changed (docs/noise_model.md section 9).
  bool focal_scale_in_covariance = true;
  /// Add the calibration's pointing uncertainty (init.sigma_camera_rotation_rad) to the reported covariance: the
  /// camera-IMU rotation and the principal point are not estimated, and a pointing off by the small rotation dtheta
  /// turns the estimated velocity, plane normal and gravity direction by dtheta in the camera frame (dv = dtheta x v;
  /// the distance unchanged). The filter's own covariance is not changed (docs/noise_model.md section 9).
  bool camera_rotation_in_covariance = true;
  /// Brightness change of the pair (docs/noise_model.md section 12): kNormalised compares the images as they are
  /// (each standardised to zero mean and unit variance on its own); kGain compares the current image with g I_r and kAffine with g I_r + o, the
  /// pair's gain g (and offset o) estimated in the update's Gauss-Newton passes and marginalised from the
  /// information.
  /// kRows: the pair's gain a smooth function of each pixel's capture time (a rolling shutter under flickering
  /// light: each row integrates its own part of the light's cycle); kAuto: kLevels, and kRows while bands of the
  /// rows are found.
  /// kLevels: the images compared at their grey levels (the standardisation undone: the content entering and
  /// leaving the view changes an image's mean and spread, which the standardisation would read as light), the
  /// light taken as steady unless the pair's mean residual says otherwise (light_change_threshold): that pair is
  /// compared as standardised.
  BrightnessModel brightness_model = BrightnessModel::kAuto;
  /// kLevels: a pair whose first linearisation leaves a mean residual above this fraction of the current image's
  /// grey level (its mean) is taken for a change of the light or the exposure (unitless).
  double light_change_threshold = 0.005;
  /// kRows: knots of the gain's cubic B-spline, spread evenly over the capture times of the working image.
  static constexpr int kMaxBrightnessRowKnots = 32;
  int brightness_row_knots = 12;
};

/// Camera-fixed photometric structure (docs/noise_model.md section 11, FixedPattern): per working pixel the image
/// is I = g R + a (ground radiance R; gain g: vignetting, the drone's shadow, lens dirt; additive a: projector
/// dots, glare), learned from the temporal statistics of the working image while the ground moves through it.
struct FixedPatternParams {
  bool enabled = true;                          ///< learn and remove the fixed pattern
  double decorrelation_px = 2.0;                ///< ground motion in the working image giving a new sample, px
  double memory_samples = 150.0;                ///< forgetting time constant, in independent samples
  double startup_samples = 30.0;                ///< samples gathered before anything is corrected
  /// Different patches of ground (cells of the local mean's window, 10 % of the width, along the ground's track:
  /// FixedPattern::independentPatches) the mean must hold for the fields to be computed; 0: no such condition.
  double min_ground_patches = 4.0;
  /// The min_ground_patches condition is waived while the distance's 1-sigma has run away before convergence (a
  /// restart) this many times within scale_loss_window_s: images that deny the motion the IMU measures (a pattern
  /// holding the state still), not a camera holding its position, whose images and IMU agree; 0: never.
  int scale_losses_waive_patches = 3;
  double scale_loss_window_s = 10.0;            ///< s, window of those restarts
  double significance_sigma = 3.0;              ///< a pixel's gain/offset is kept only this many sigmas above noise
  double min_gain = 0.3;                        ///< confidence (g / min_gain)^2 below this relative gain, unitless
  int refresh_frames = 8;                       ///< learning frames between recomputations of the fields
  /// The smooth part of the gain as a radial vignetting ln V = a1 r^2 + a2 r^4 about the principal point (one field
  /// for the whole image, learned from the ground's motion: VignettingLearner; shrunk as a whole) before the
  /// per-pixel model looks at what is left.
  bool radial_vignetting = true;
  double report_fraction = 0.05;                ///< image share of strong pattern reported in the status (0..1)
  /// Allow for the bias of the updates made before the pattern was learned: its share s of the image's contrast
  /// (FixedPattern::contrastShare) voted for "no motion", so s^2 alpha^2 and s^2 |vartheta|^2 are added to their
  /// variances when s grows (docs/noise_model.md section 11).
  bool discount_biased_updates = true;
  /// The learned pattern's share of the image's gradient energy (0..1) from which it dominates the image: named in
  /// the status and diagnostics (the status degraded once when it gets there); 0: never.
  double dominant_contrast_share = 0.25;
  /// When the learned pattern reaches dominant_contrast_share and the raw images are not opened yet
  /// (PreprocessParams::dot_removal_px = 0), switch the bright-dot opening on with this side (raw px, odd; 0 =
  /// never) and learn the pattern anew: a pattern that dominates the contrast is an IR projector's dots
  /// (docs/noise_model.md section 11).
  int auto_dot_removal_px = 5;
  /// The projector-dot detector on the raw images (docs/noise_model.md section 11): once the ground has moved by
  /// three auto_dot_removal_px along both image axes, bright specks that stayed on the same pixels in every image
  /// sampled are counted; if they hold at least this share of the image (0..1) they are taken for an IR
  /// projector's dots and the raw images are opened from then on (the side measured on them, max_dot_removal_px
  /// below), as above, without waiting for the pattern's statistics. Once per estimator; 0 = off.
  double dot_detect_share = 0.01;
  /// A speck for that detector: a top-hat (image minus its opening) above this fraction of the opening, unitless.
  double dot_detect_contrast = 0.5;
  /// Contrast levels of that detector (1-3): level l looks for specks above dot_detect_contrast / 2^l, and decides
  /// once every brighter level found no dots (fainter dots: a projector far away, a ground dark in infrared).
  int dot_detect_levels = 3;
  /// When the detector finds dots, the opening's side is measured on its last sample instead of taking
  /// auto_dot_removal_px: the least odd side from auto_dot_removal_px up to this one (raw px) at which a larger
  /// side no longer takes more from the dots than from the ground (their tails and clusters are gone;
  /// DotDetector::removalElement). Equal to auto_dot_removal_px: that side, not measured.
  int max_dot_removal_px = 21;
  /// Fill the pixels the dots light (the detector's fixed specks grown over their tails, DotDetector::fillMask) from
  /// the ground around them, instead of opening the whole raw image at the detector's verdict
  /// (ImagePreprocessor::setDotFill; docs/noise_model.md section 11, "Filling the dots"): from its fourth sample
  /// once the fixed specks have stopped falling (interim), and with the final mask at a verdict of dots. The opening leaves the
  /// dots a few grey levels of remains fixed in the image (an opening only rises where a dot lit the minimum of a
  /// window) and takes fine bright texture from the ground; the fill touches only the dots' pixels.
  bool dot_fill = true;
  /// With dot_fill: after the verdict, learn the dots' gain per raw pixel from the ground's motion (the current
  /// image's pixels against the reference's where the warp puts them, away from the dots) and, once learned, divide
  /// the raw images by it, filling only the dots' saturating cores (docs/noise_model.md section 11, "Dots divided
  /// out"). The fill's interpolation is fixed in the image and biases the distance; the division keeps the ground.
  bool dot_gain = true;
  /// Optional offline flat field: a cv::FileStorage file (YAML/XML) with a matrix `gain` (relative response per
  /// raw pixel at the calibration resolution, any scale); empty: none. Divided out before the online model.
  std::string vignetting_file;
};

struct FeatureParams {
  int max_corners = 50;                         ///< corners detected in the reference image
  double quality_level = 0.01;                  ///< goodFeaturesToTrack quality level
  double min_distance_px = 5.0;                 ///< minimum corner spacing at working resolution, px
  int window_px = 11;                           ///< LK window size, px
  int pyramid_levels = 3;                       ///< LK pyramid levels
  double pixel_noise_sigma_px = 0.5;            ///< 1-sigma of a tracked corner position, px
  double huber_threshold_px = 1.0;              ///< Huber threshold on innovation, px
  int working_width_px = 376;                   ///< resolution the baseline tracks at, px
  bool predict_flow = false;                    ///< start LK at the prior's predicted position (false: at the corner, as the paper)
};

struct DivergenceParams {
  double min_distance_m = 0.05;                 ///< reset when d falls below, m
  double max_distance_m = 50.0;                 ///< reset when d exceeds, m
  double max_sigma_distance_m = 10.0;           ///< reset when 1-sigma of d exceeds, m
  double max_photometric_rms = 0.8;             ///< larger residual RMS: update rejected (normalised units)
  int bad_frames_before_reset = 30;             ///< consecutive bad frames before a reset
  double max_speed_mps = 20.0;                  ///< reset when the speed |v| exceeds, m/s
  double max_sigma_velocity_mps = 5.0;          ///< reset when the 1-sigma of any velocity axis exceeds, m/s
  double max_step_sigma = 5.0;                  ///< reject an update moving alpha by more prior sigmas than this
  double degraded_hold_s = 1.0;                 ///< status stays degraded this long after a failed check, s
  double max_nis_ratio = 3.0;                   ///< degraded while the smoothed NIS exceeds this x its mean (8)
};

/// Input checks of the facade (docs/robustness.md): what is rejected, bridged or restarts the filter.
struct InputParams {
  double max_imu_bridge_s = 0.5;                ///< IMU gaps up to this are propagated through; longer reset, s
  double time_jump_reset_s = 1.0;               ///< a stamp this far backwards resets (closer: rejected), s
  double max_frame_interval_s = 0.25;           ///< longer reference-to-image intervals skip the update, s
  double max_image_gap_s = 1.0;                 ///< no usable image for longer: restart at the next one, s
  /// Grey-level std of the 8-bit working image below which it has no texture: about twice a uniform scene's under
  /// the MYNT EYE's sensor noise at 180 px (0.54); docs/algorithm.md section 3.1.
  double min_image_contrast_grey = 1.0;
  double min_unclipped_ratio = 0.1;             ///< fraction of working pixels neither 0 nor 255 required
  double max_accel_mps2 = 200.0;                ///< IMU samples with a larger |specific force| are rejected, m/s^2
  double max_gyro_radps = 35.0;                 ///< IMU samples with a larger |rate| are rejected, rad/s
  double gap_accel_sigma_mps2 = 3.0;            ///< unknown acceleration during a bridged IMU gap, 1-sigma, m/s^2
  double gap_gyro_sigma_radps = 0.5;            ///< unknown rate change during a bridged IMU gap, 1-sigma, rad/s
  /// Image stamps taken on arrival at a host jitter by a few ms: each frame's time from the camera's frame clock
  /// fitted to the stamps (docs/algorithm.md section 3.6, "Jittered image stamps"); exact stamps pass unchanged.
  bool stamp_smoothing = true;
  int stamp_smoothing_frames = 128;             ///< frames the frame clock is fitted over (8-128)
};

/// What an image's stamp marks (EstimatorParams::image_stamp).
enum class ImageStamp { kMiddle, kStart, kEnd };

struct EstimatorParams {
  UpdateMode mode = UpdateMode::kIterated;
  InitParams init;
  ImuParams imu;
  ProcessNoiseParams process;
  PreprocessParams preprocess;
  PhotometricParams photometric;
  FixedPatternParams fixed_pattern;
  FeatureParams feature;
  DivergenceParams divergence;
  InputParams input;
  double max_imu_gap_s = 0.05;                  ///< larger IMU gaps are warned about and re-prime the low-pass, s
  int max_queued_images = 8;                    ///< images waiting for IMU coverage before the oldest is dropped
  bool update_at_interval_midpoint = true;      ///< apply the image update at the middle of the image interval
  bool estimate_time_offset = true;             ///< the camera-IMU time offset as a filter state (else fixed at 0)
  double max_time_offset_s = 0.05;              ///< bound of the estimated offset around the calibration's, s
  double time_offset_start_s = 2.0;             ///< converged this long before the offset is estimated, s
  bool time_offset_consider = true;             ///< until then, the offset a consider state (its column, held)
  bool estimate_readout = true;                 ///< the rolling-shutter readout time as a filter state
  double max_readout_s = 0.05;                  ///< bound of the estimated readout (either sign), s
  bool readout_consider = true;  ///< until then, from convergence, the readout a consider state (its column, held)
  /// With estimate_readout and no line delay configured (line_delay_s here or in the camchain): the readout
  /// estimated from the first image on (the rows' alpha with the readout's uncertainty), its variance given back its
  /// prior and its correlations dropped when the time offset's estimate starts (time_offset_start_s after
  /// convergence); false, or a line delay configured: estimated from the offset's start (docs/algorithm.md section
  /// 3.7, "From the first image")
  bool readout_from_first_image = true;
  /// With readout_from_first_image: from convergence to the offset's start the readout is estimated with the
  /// offset's column considered (the offset held, not the readout), and its variance is given back its prior at
  /// convergence instead of at the offset's start; false: held with the offset until its start (before session 57;
  /// docs/algorithm.md section 3.7, "From the first image")
  bool readout_with_considered_offset = true;
  /// With the time offset estimated: the readout is estimated once the offset's 1-sigma is below this, s; 0 (the
  /// default): from the offset's start, with it (docs/algorithm.md section 3.7)
  double readout_start_sigma_time_offset_s = 0.0;
  /// The readout's and the offset's columns take the gyro rate's change between the images at its expected value
  /// given its noise and its readings' mean square over this window (exponential weights), s; 0: each reading's own
  /// square (before session 56; docs/algorithm.md section 3.7, "The rates' expected values")
  double rates_window_s = 0.3;
  /// With estimate_focal_scale and the time offset estimated: the focal-length scale is estimated once the offset's
  /// 1-sigma is below this, s (docs/algorithm.md section 3.8)
  double focal_start_sigma_time_offset_s = 0.001;
  /// The focal length's relative error as a filter state, the raw images resampled for its estimate (section 3.8).
  /// Off: with a correct calibration it settles 0.3-1 % off on natural textures (docs/results.md "Consistency over
  /// the calibration's prior").
  bool estimate_focal_scale = false;
  /// With estimate_focal_scale: the focal-length scale as a consider parameter (Schmidt-Kalman) instead: its
  /// uncertainty (init.sigma_focal_scale) enters the covariance of the other states through the update, but the
  /// images never move it (its mean and variance are kept). docs/noise_model.md section 9.
  bool focal_scale_consider = false;
  double max_focal_scale = 0.1;                 ///< bound of the estimated focal-length scale (either sign), unitless
  /// Rolling shutter: readout time per raw image row, s; 0 = the camchain's line_delay_s (0 there: global shutter).
  double line_delay_s = 0.0;
  /// What the image stamp marks: the middle of the exposure of the middle row (the estimator's image time),
  /// the start of the first row's exposure, or the end of the last row's.
  ImageStamp image_stamp = ImageStamp::kMiddle;
  double exposure_time_s = 0.0;                 ///< exposure time for image_stamp start/end, s
};

/// "middle" | "start" | "end" -> ImageStamp; throws std::invalid_argument naming the value otherwise.
ImageStamp parseImageStamp(const std::string& name);
const char* toString(ImageStamp stamp);
/// Seconds to add to an image stamp for the capture time of the middle of the middle row's exposure, given the
/// convention, the exposure time and the whole frame's readout time (rows times line delay).
double imageStampShift(ImageStamp stamp, double exposure_time_s, double readout_s);

class CameraModel;
/// The rolling shutter's configured line delay, s per raw row: the parameter line_delay_s, or the camchain's when the
/// parameter is 0 (0 in both: a global shutter, or a readout the calibration does not give; docs/algorithm.md 3.7).
double configuredLineDelay_s(const EstimatorParams& p, const CameraModel& cam);

/// "iekf" | "ekf" | "lk" -> mode; throws std::invalid_argument naming the value otherwise.
UpdateMode parseUpdateMode(const std::string& name);
const char* toString(UpdateMode mode);

}  // namespace diekf
