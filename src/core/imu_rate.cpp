#include "diekf/imu_rate.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "diekf/imu_filter.h"

namespace diekf {

RateMeter::RateMeter(double window_s, int min_intervals) : window_s_(window_s), min_intervals_(min_intervals) {
  if (!(window_s >= 0.0) || min_intervals < 1) {
    throw std::invalid_argument("RateMeter: window_s must be >= 0 and min_intervals >= 1");
  }
}

void RateMeter::reset() {
  first_t_s_ = last_t_s_ = -1.0;
  intervals_.clear();
  ready_ = false;
  rate_hz_ = 0.0;
}

bool RateMeter::add(double t_s) {
  if (ready_) return true;
  if (!std::isfinite(t_s)) return false;
  if (first_t_s_ < 0.0) {
    first_t_s_ = last_t_s_ = t_s;
    return false;
  }
  if (!(t_s > last_t_s_)) return false;  // duplicate or out of order
  intervals_.push_back(t_s - last_t_s_);
  last_t_s_ = t_s;
  if (static_cast<int>(intervals_.size()) < min_intervals_ || last_t_s_ - first_t_s_ < window_s_) return false;
  std::vector<double> sorted = intervals_;
  const size_t mid = sorted.size() / 2;
  std::nth_element(sorted.begin(), sorted.begin() + mid, sorted.end());
  double median = sorted[mid];
  if (sorted.size() % 2 == 0) {
    median = 0.5 * (median + *std::max_element(sorted.begin(), sorted.begin() + mid));
  }
  rate_hz_ = 1.0 / median;
  ready_ = true;
  return true;
}

ImuParams designImuPreprocessing(const ImuParams& configured, double measured_rate_hz, std::string* summary) {
  if (!(measured_rate_hz > 0.0) || !std::isfinite(measured_rate_hz)) {
    std::ostringstream os;
    os << "measured IMU rate " << measured_rate_hz << " Hz is not usable";
    throw std::invalid_argument(os.str());
  }
  const double target_hz = configured.input_rate_hz / std::max(1, configured.decimation_factor);
  ImuParams p = configured;
  p.input_rate_hz = measured_rate_hz;
  p.decimation_factor = std::max(1, static_cast<int>(std::lround(measured_rate_hz / target_hz)));
  const double prediction_hz = measured_rate_hz / p.decimation_factor;
  const double fc = configured.lowpass_cutoff_hz;
  std::ostringstream os;
  os.precision(4);
  if (configured.lowpass_order > 0) {
    if (!(fc < 0.5 * measured_rate_hz)) {
      os << "imu/lowpass_cutoff_hz " << fc << " Hz cannot work with the measured IMU rate of " << measured_rate_hz
         << " Hz: the low-pass must cut off below half the rate (" << 0.5 * measured_rate_hz
         << " Hz); lower imu/lowpass_cutoff_hz or raise the IMU rate (MYNT EYE: standard/imu_frequency)";
      throw std::invalid_argument(os.str());
    }
    if (!(fc < 0.5 * prediction_hz)) {
      os << "imu/lowpass_cutoff_hz " << fc << " Hz cannot work with the measured IMU rate of " << measured_rate_hz
         << " Hz decimated by " << p.decimation_factor << " to " << prediction_hz
         << " Hz (imu/input_rate_hz / imu/decimation_factor = " << target_hz
         << " Hz asked for): what passes the low-pass above " << 0.5 * prediction_hz
         << " Hz would alias into the prediction; lower imu/lowpass_cutoff_hz or raise the prediction rate "
            "(imu/decimation_factor)";
      throw std::invalid_argument(os.str());
    }
  }
  os << "IMU at " << measured_rate_hz << " Hz (measured; imu/input_rate_hz " << configured.input_rate_hz
     << " Hz): " << (vibrationNotchesOn(p) ? "vibration notches, " : "") << "order-" << effectiveLowpassOrder(p)
     << " low-pass at " << fc << " Hz, decimation " << p.decimation_factor << " -> prediction at " << prediction_hz
     << " Hz";
  if (configured.lowpass_order == 0 && p.decimation_factor > 1) {
    os << " (low-pass off: vibration above " << 0.5 * prediction_hz << " Hz aliases)";
  }
  if (summary) *summary = os.str();
  return p;
}

ImuParams imuPreprocessingForRecording(const ImuParams& configured, double measured_rate_hz, double tolerance,
                                       std::string* summary) {
  std::ostringstream os;
  os.precision(4);
  if (!(measured_rate_hz > 0.0) || !std::isfinite(measured_rate_hz)) {
    os << "IMU rate not measured (too few samples): imu/input_rate_hz " << configured.input_rate_hz
       << " Hz as configured";
    if (summary) *summary = os.str();
    return configured;
  }
  if (std::abs(measured_rate_hz / configured.input_rate_hz - 1.0) <= tolerance) {
    os << "IMU at " << measured_rate_hz << " Hz (measured), as configured (imu/input_rate_hz "
       << configured.input_rate_hz << " Hz, " << (vibrationNotchesOn(configured) ? "vibration notches, " : "")
       << "order-" << effectiveLowpassOrder(configured) << " low-pass at "
       << configured.lowpass_cutoff_hz << " Hz, decimation " << configured.decimation_factor << ")";
    if (summary) *summary = os.str();
    return configured;
  }
  return designImuPreprocessing(configured, measured_rate_hz, summary);
}

}  // namespace diekf
