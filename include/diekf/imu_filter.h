// IMU preprocessing: rotate raw readings into the camera frame (with the lever-arm term), low-pass filter
// (Butterworth, cascaded biquads) and decimate (500 Hz -> 100 Hz by default), with the filter's delay
// compensated in the output stamps.
//
// Pipeline per raw sample (IMU frame I):
//   1. rotate: f_C = R_CI f_I, w_C = R_CI w_I (R_CI from T_cam_imu, p_C = R_CI p_I + t_CI);
//   1b. at rates that fold the propellers' vibration into the low band (vibrationNotchesOn), notch out the folded
//      tones found in the stream's spectrum (VibrationNotch);
//   2. low-pass both 3-vectors with a Butterworth of effectiveLowpassOrder() (bilinear transform, prewarped
//      cutoff, designed for `input_rate_hz`), primed from the mean of the first samples; with `prime_from_mean`
//      nothing is emitted until the filter has settled (settleSamples()): the vibration, applied to a filter at
//      rest, rings at the filter's own frequencies (a folded tone at 100 Hz: 1 m/s^2);
//   3. add the lever-arm term to the specific force: f_cam = f_imu + dw/dt x r + w x (w x r), r = -t_CI the
//      vector from the IMU origin to the camera centre in C, w and dw/dt from the filtered gyro (dw/dt by a
//      backward difference at the input rate). The linear dw/dt term commutes with the filter; the centripetal
//      term is evaluated on the filtered rate so that gyro noise is not rectified into an offset;
//   4. on every `decimation_factor`-th sample (the first one included), emit: with `decimation_mean` the mean of
//      the last decimation_factor samples of step 3 (a boxcar: the prediction step then integrates what the
//      input-rate steps would, and what the low-pass leaves of the vibration near multiples of the prediction
//      rate is not folded to near 0 Hz), otherwise that sample alone;
//   5. stamp = raw stamp - delay_s() when `compensate_filter_delay`: the filter's group delay at 0 Hz, the
//      boxcar's (decimation_factor - 1) / 2 input periods, and the active notches' delay at 0 Hz.
#pragma once

#include <optional>
#include <vector>

#include "diekf/biquad.h"
#include "diekf/camera_model.h"
#include "diekf/params.h"
#include "diekf/vibration_notch.h"

namespace diekf {

/// The low-pass order the preprocessing uses for `p`: `aliased_lowpass_order` (if higher) when the IMU rate is
/// below twice `max_vibration_hz`, where vibration aliases into the low band; else `lowpass_order` (0: off).
int effectiveLowpassOrder(const ImuParams& p);
/// Whether the preprocessing for `p` notches the folded vibration tones: `aliased_notch`, a low-pass, and a rate
/// below twice `max_vibration_hz`.
bool vibrationNotchesOn(const ImuParams& p);

class ImuPreprocessor {
 public:
  /// Throws std::invalid_argument on an unusable configuration (rate <= 0, cutoff outside (0, rate/2),
  /// order < 0, decimation < 1).
  ImuPreprocessor(const Eigen::Isometry3d& T_cam_imu, const ImuParams& params);

  /// Feeds one raw sample (IMU frame, IMU clock). Returns true and fills `out` (camera frame, stamp on the IMU
  /// clock minus the filter delay) when a decimated sample is ready.
  bool push(const ImuSample& raw_imu, ImuSample* out);
  /// Clears the filter memory (next sample re-primes it).
  void reset();
  /// Low-frequency group delay of the filter and the decimation's boxcar, s (subtracted from output stamps when
  /// compensation is on).
  double delay_s() const { return delay_s_; }
  /// The vibration notches (imu/aliased_notch at a folding rate), or null.
  const VibrationNotch* notch() const { return notch_ ? &*notch_ : nullptr; }
  /// Filtered samples held back after the filter is primed (imu.prime_from_mean; 0 otherwise): the first n
  /// whose impulse-response tail sum_(k >= n) |h_k| is at most kSettleTail of sum_k |h_k|. A signal x applied
  /// to the primed filter at rest leaves at most that share of max |x - mean| as start-up transient.
  int settleSamples() const { return settle_samples_; }
  static constexpr double kSettleTail = 0.01;
  /// Number of second-order (or, for odd orders, one first-order) sections of the designed filter.
  int numSections() const { return static_cast<int>(sections_.size()); }
  /// Magnitude of the designed low-pass's frequency response at f_hz (input-rate design, without the
  /// decimation's boxcar), for diagnostics.
  double magnitudeResponse(double f_hz) const;
  /// Autocovariance of the emitted samples `lag` input samples apart for white input of unit variance per input
  /// sample: sum_n h[n] h[n + lag] over the low-pass's impulse response followed by the decimation's boxcar
  /// (outputImpulseResponse; 1 at lag 0 with neither, 1 / decimation_factor with the boxcar alone).
  double noiseAutocovariance(int lag) const;
  /// The same at the lags 0, step, 2 step, ... up to where the impulse response has decayed (at least lags 0-2).
  std::vector<double> noiseAutocovariances(int step) const;

 private:
  /// The designed low-pass's impulse response, long enough to have decayed (plus `extra` samples).
  std::vector<double> impulseResponse(int extra) const;
  /// The same followed by the decimation's boxcar: the emitted samples' response to one input sample.
  std::vector<double> outputImpulseResponse(int extra) const;
  using Vec6 = Biquad6::Vec6;
  Vec6 filter(const Vec6& in);
  void prime(const Vec6& in);
  /// A filtered sample (f, w) with the lever-arm term added to f (step 3).
  Vec6 atCamera(const Vec6& y, const Vec3& w_dot) const;
  /// Samples the decimation averages: decimation_factor with decimation_mean, else 1.
  int boxcarLength() const { return static_cast<int>(boxcar_.size()); }

  ImuParams params_;
  Mat3 R_CI_;
  Vec3 r_imu_to_cam_C_;      // lever arm from the IMU origin to the camera centre, in C, m
  std::vector<Biquad6> sections_;  // the Butterworth's sections, with their memory
  double delay_s_ = 0.0;
  std::optional<VibrationNotch> notch_;  // before the low-pass, at rates that fold the vibration
  bool primed_ = false;
  Vec6 prime_sum_ = Vec6::Zero();  // sum of the first samples (rotated into C), before the filter starts
  int prime_count_ = 0;
  int prime_samples_ = 1;  // samples averaged for the start: one period of the cutoff
  int settle_samples_ = 0;  // filtered samples held back after priming (settleSamples)
  int settle_left_ = 0;     // of them still to come
  int counter_ = 0;
  Vec3 last_gyro_C_ = Vec3::Zero();  // filtered gyro of the previous raw sample, rad/s
  std::vector<Vec6> boxcar_;  // the last boxcarLength() samples of step 3 (a ring; allocated once)
  int boxcar_next_ = 0;       // where the next one goes
};

}  // namespace diekf
