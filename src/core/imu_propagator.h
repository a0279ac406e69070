// Internal part of the estimator (docs/algorithm.md section 9): the filtered IMU samples, the state's time, and
// the prediction between images. Also integrates the gyro over the current image interval, which the image
// update's warp needs (its rotation), and answers "what did the IMU read at time t".
#pragma once

#include "diekf/params.h"
#include "diekf/state.h"
#include "diekf/types.h"
#include "diekf/unit_vector.h"
#include "ring.h"

namespace diekf {
namespace internal {

class ImuPropagator {
 public:
  /// `params` must outlive the propagator (the estimator's own copy).
  explicit ImuPropagator(const EstimatorParams& params);

  // --- The buffer of filtered samples (C frame, delay-compensated stamps, increasing) ---
  /// Appends a filtered sample; false (and ignored) unless it is newer than the newest one.
  bool push(const ImuSample& filtered);
  void clear() { buffer_.clear(); }
  bool empty() const { return buffer_.empty(); }
  const ImuSample& oldest() const { return buffer_[0]; }
  const ImuSample& newest() const { return buffer_.back(); }

  // --- The state's time and the prediction ---
  double stateTime() const { return t_state_s_; }
  /// The state is at t_s from now on (a start: no propagation before it); samples no longer needed dropped.
  void startAt(double t_s);
  /// Propagates (x, P) from the state's time to t_target_s (prediction.h's predict over the samples, split at
  /// their stamps; a bridged gap held and its noise inflated) and accumulates the gyro over the interval.
  void propagateTo(double t_target_s, State* x, ErrorCov* P);

  /// Holds the acceleration that the distance's column of the prediction Jacobian uses until the next call: the
  /// propagated acceleration (specific force plus gravity, biases removed) of the steps so far, smoothed over
  /// imu/jacobian_accel_smoothing_s without lag (level and trend), shrunk to its expected value given the
  /// samples' noise, then extrapolated along the trend and turned with the camera. The estimator calls it after
  /// each image update (propagateTo renews it when older than kMaxColumnAccelAgeS): the column then carries none
  /// of the reading noise that the next innovation measures, nor noise taken for acceleration (docs/algorithm.md
  /// section 2.1, "The distance's column"). No-op before anything was propagated, or with the smoothing negative
  /// (each step's own reading, the textbook EKF).
  void holdColumnAccel();
  /// The smoothed acceleration's level (2 s1 - s2, C frame, m/s^2) before it is shrunk and held, and its variance
  /// per unit variance of one filtered sample's noise (4 v11 - 4 v12 + v22, white samples): what holdColumnAccel
  /// shrinks by. For tests.
  Vec3 smoothedAccelLevel() const { return 2.0 * smooth1_C_ - smooth2_C_; }
  double levelVarianceFactor() const;
  /// The level's variance with the filtered samples' correlation over every lag, per its variance for white
  /// samples of the same variance (steady-state smoothing coefficients c_k: 1 + 2 sum_m rho_m sum_k c_k c_(k+m) /
  /// sum_k c_k^2). holdColumnAccel multiplies levelVarianceFactor by it.
  double sampleCorrelationFactor() const { return correlation_factor_; }

  // --- The image interval (reference image -> current image) ---
  /// A new reference image at t_s: the interval's gyro integral restarts, the rate at t_s is remembered.
  void setReference(double t_s);
  /// The reference image's time moved from from_s to to_s (the camera-IMU time offset estimate changed since
  /// it was placed): the interval's gyro integral and the rate at the reference follow.
  void moveReference(double from_s, double to_s);
  /// Forgets the gyro integrated so far (a filter restart).
  void clearInterval();
  /// Mean filtered gyro (C) over the interval from the reference image to t_img_s: what was integrated so far
  /// plus the samples from the state's time up to t_img_s, rad/s.
  Vec3 meanGyroOverInterval(double t_img_s) const;
  /// Filtered gyro at t_s minus the one at the reference image, rad/s.
  Vec3 rateChangeSinceReference(double t_s) const { return imuAt(t_s).gyro_radps - ref_rate_C_; }

  /// The filtered sample at t_s: linear interpolation between the buffered samples around it (the nearest one
  /// outside the buffer's span).
  ImuSample imuAt(double t_s) const;
  // --- The gyro's noise (docs/noise_model.md section 6) ---
  /// The low-pass's response to white noise: autocov[m] = ImuPreprocessor::noiseAutocovariance(m D), the filtered
  /// samples' autocovariance m filtered periods apart (D the decimation; in input samples), for m = 0 up to where it
  /// has decayed. It relates the filtered samples' spread to a noise density (lags 0-2) and the smoothed
  /// acceleration's variance to one sample's (every lag: sampleCorrelationFactor).
  void setFilterNoise(const std::vector<double>& autocov);
  /// The gyro's white-noise density, (rad/s)^2/Hz: its angle over an interval dt is uncertain by this times dt.
  /// The calibration's gyro_noise_density^2, or less where the filtered samples show less (the second
  /// differences of three consecutive samples, smoothed over 2 s, their noisiest axis; from 1 s of samples on):
  /// Kalibr densities are often inflated several times on purpose. Not more: what the samples show above the
  /// calibration at rest is propeller vibration, a narrow band far above the frame rate that the interval's
  /// angle averages out.
  double gyroNoiseDensitySq() const;
  /// Variance of the noise of one filtered sample per axis of C, from the same second differences (the gyro's in
  /// (rad/s)^2, the specific force's in (m/s^2)^2; until 1 s of samples, the calibration's densities through the
  /// low-pass): what a rate read from one or two samples is uncertain by, vibration included.
  Vec3 gyroSampleVariance() const;
  Vec3 accelSampleVariance() const;
  /// One filtered sample's variance as the distance's column counts it (holdColumnAccel): accelSampleVariance, but
  /// not more than the calibration's density through the low-pass, for the reason gyroNoiseDensitySq gives. The
  /// column's level averages over imu/jacobian_accel_smoothing_s; what the second differences show above the
  /// calibration is what the low-pass leaves of the propellers' tones (at IMU rates below twice the vibration
  /// folded to 30-70 Hz), which that average removes. Taken for white noise it shrank real accelerations out of
  /// the column and the distance was found 4-5 % high for seconds (a 100 Hz IMU; docs/algorithm.md 2.1).
  Vec3 accelLevelSampleVariance() const;
  /// The acceleration the distance's column holds (C, m/s^2; holdColumnAccel). For tests.
  const Vec3& heldColumnAccel() const { return column_accel_C_; }
  /// The state's error per unit focal-length error (reported covariance), carried by each prediction step.
  ErrorVec& focalSensitivity() { return focal_sensitivity_; }

  /// Gravity direction from the mean specific force of the filtered samples of the 0.5 s up to up_to_t_s, if
  /// the vehicle is near rest (|mean| within 10 % of g): g = -f/|f|. False otherwise. `spread_var_rad2` (optional):
  /// per tangent axis, rad^2, how far the mean may be from gravity: the samples' variance across f over |f|^2 plus
  /// the mean square angle the frame turned from each sample to the window's end (the gyro summed). A multirotor's
  /// specific force points along its thrust: tilting into a manoeuvre turns the frame, not the samples.
  bool gravityFromAccel(double up_to_t_s, UnitVector* g, double* spread_var_rad2 = nullptr) const;

 private:
  /// Nominal period of the filtered samples, s.
  double filteredPeriod() const;
  /// Integral of the filtered gyro over (t0, t1] with the interpolation of propagateTo, rad.
  Vec3 gyroIntegral(double t0_s, double t1_s) const;
  /// Whether 1 s of second differences has been seen (until then the calibration's densities are used).
  bool noiseMeasured() const;
  /// One filtered sample's variance for white noise of the calibration's density through the low-pass.
  Vec3 calibratedSampleVariance(double density) const;
  /// One filtered sample's variance from the smoothed second differences, or from the calibration's density.
  Vec3 sampleVariance(const Vec3& second_diff_var, double calibrated_density) const;
  /// Drops the samples before the last one at or before the state's time.
  void dropUsed();

  const EstimatorParams& params_;
  Ring<ImuSample> buffer_;
  double t_state_s_ = 0.0;
  Vec3 gyro_integral_ = Vec3::Zero();  // integral of the filtered gyro (C) since the reference image, rad
  double gyro_time_s_ = 0.0;           // time covered by gyro_integral_, s
  Vec3 ref_rate_C_ = Vec3::Zero();     // filtered rate at the reference image, rad/s
  double second_diff_var_per_density_sq_ = 1.0;  // variance of (w_(k-1) + w_(k+1)) / 2 - w_k per unit density^2
  double sample_var_per_density_sq_ = 1.0;       // one filtered sample's variance per unit density^2
  Vec3 gyro_second_diff_var_ = Vec3::Zero();     // its smoothed square per axis, (rad/s)^2
  Vec3 accel_second_diff_var_ = Vec3::Zero();    // the same of the specific force, (m/s^2)^2
  int second_diffs_ = 0;                         // second differences seen (capped)
  static constexpr double kMaxColumnAccelAgeS = 0.1;  // s, the held value is renewed when older
  double correlation_factor_ = 1.0;  // sampleCorrelationFactor()
  static constexpr double kNoiseDiffSpacingS = 0.01;  // s, the noise's second differences take samples this far apart
  int diff_lag_ = 1;                                  // ... i.e. this many filtered periods
  Vec3 smooth1_C_ = Vec3::Zero();         // propagated acceleration (a - b_a + g0 g), smoothed once, in C now
  Vec3 smooth2_C_ = Vec3::Zero();         // ... and twice (Brown), m/s^2
  // Their variances and covariance per unit sample variance, v11 = closed11_ + prev_c1_^2 + next_c1_^2 etc.
  // (levelVarianceFactor): the coefficients of the two samples the pieces interpolate between (the earlier, the
  // later) in s1 and s2, and the part of the samples before them.
  double prev_c1_ = 0.0, prev_c2_ = 0.0, next_c1_ = 0.0, next_c2_ = 0.0;
  double closed11_ = 0.0, closed12_ = 0.0, closed22_ = 0.0;
  bool accel_smooth_valid_ = false;
  ErrorVec focal_sensitivity_ = ErrorVec::Zero();  // the state's error per unit focal error (the estimator's)
  Vec3 column_accel_C_ = Vec3::Zero();   // the held acceleration of the distance's column, in C then, m/s^2
  Vec3 column_trend_C_ = Vec3::Zero();   // its rate of change, m/s^3
  Mat3 column_turn_ = Mat3::Identity();  // how directions fixed in the world turned from then to now
  bool column_valid_ = false;
  double column_t_s_ = 0.0;              // state time when it was held, s
};

}  // namespace internal
}  // namespace diekf
