// The IMU's sample rate measured from its stamps, and the IMU preprocessing (low-pass and decimation) designed for
// it. A MYNT EYE S samples its IMU at a device setting (100, 200, 250, 333 or 500 Hz); the nodelet measures the rate
// at start-up instead of trusting imu/input_rate_hz (docs/ros.md, "IMU rate").
#pragma once

#include <string>
#include <vector>

#include "diekf/params.h"

namespace diekf {

/// Sample rate from stamps: 1 / the median interval between consecutive stamps over a start-up window. The median
/// ignores gaps (dropped samples), duplicates and jitter. Non-increasing stamps are skipped.
class RateMeter {
 public:
  /// window_s: stamps spanning this long (s) are needed; min_intervals: and at least this many intervals.
  explicit RateMeter(double window_s = 1.0, int min_intervals = 20);
  /// Adds a stamp (s). Returns true once the rate is known (and keeps returning true).
  bool add(double t_s);
  bool ready() const { return ready_; }
  /// Measured rate, Hz (0 before ready()).
  double rateHz() const { return rate_hz_; }
  /// Intervals the measurement used.
  int intervals() const { return static_cast<int>(intervals_.size()); }
  void reset();

 private:
  double window_s_;
  int min_intervals_;
  double first_t_s_ = -1.0, last_t_s_ = -1.0;
  std::vector<double> intervals_;
  bool ready_ = false;
  double rate_hz_ = 0.0;
};

/// The IMU preprocessing for a measured raw rate. The configured parameters describe the intent: a prediction
/// rate of imu/input_rate_hz / imu/decimation_factor (100 Hz by default) and the low-pass cut-off and order. The
/// result has input_rate_hz = the measured rate, decimation_factor = the integer that brings it closest to that
/// prediction rate (at least 1), the cut-off and order unchanged.
/// Throws std::invalid_argument, naming the keys and the measured rate, when the configured cut-off cannot work:
/// at or above half the measured rate (the Butterworth cannot be designed), or at or above half the resulting
/// prediction rate (what passes the filter would alias when decimated); also for a measured rate <= 0.
/// `summary`, when given, receives one line describing the design (and a note when the low-pass is off although
/// samples are decimated).
ImuParams designImuPreprocessing(const ImuParams& configured, double measured_rate_hz, std::string* summary = nullptr);

/// The IMU preprocessing for a recording whose rate is measured before it is processed (diekf_bag_runner,
/// diekf_replay): the configured parameters as they are when the measured rate is within `tolerance` (relative) of
/// imu/input_rate_hz, so that a recording at the configured rate is processed exactly as configured; otherwise
/// designImuPreprocessing for the measured rate (a 100 or 200 Hz IMU is not low-passed and decimated as if it ran at
/// 500 Hz). A measured rate of 0 (too few samples to measure) keeps the configuration. `summary`: one line.
/// Throws std::invalid_argument as designImuPreprocessing does.
ImuParams imuPreprocessingForRecording(const ImuParams& configured, double measured_rate_hz, double tolerance,
                                       std::string* summary = nullptr);

}  // namespace diekf
