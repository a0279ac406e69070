#include "imu_propagator.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "diekf/prediction.h"
#include "expected_value.h"
#include "imu_propagation.h"

namespace diekf {
namespace internal {

namespace {
constexpr size_t kImuBufferCapacity = 1024;  // filtered samples (about 10 s at 100 Hz)
}  // namespace

ImuPropagator::ImuPropagator(const EstimatorParams& params) : params_(params), buffer_(kImuBufferCapacity) {
  setFilterNoise({1.0});  // no low-pass until told
}

void ImuPropagator::setFilterNoise(const std::vector<double>& autocov) {
  if (autocov.empty() || !(autocov[0] > 0.0)) return;
  // White input of density s has the variance s^2 f_in per input sample; through the filter one output sample
  // has s^2 f_in autocov0, and (w_(k-L) + w_(k+L)) / 2 - w_k, with the samples' correlations rho_L, rho_2L L and 2 L
  // filtered periods apart, (3/2 - 2 rho_L + rho_2L / 2) of that. L: the samples about 10 ms apart (1 at 100 Hz,
  // 5 at 500 Hz): the low-pass correlates neighbouring samples at 500 Hz so closely (rho_1 = 0.975 for 20 Hz) that
  // their second difference keeps 0.3 % of the noise, and the motion's own curvature would dominate it.
  const double autocov0 = autocov[0];
  auto rho = [&](size_t m) { return m < autocov.size() ? autocov[m] / autocov0 : 0.0; };
  diff_lag_ = std::max(1, static_cast<int>(std::lround(kNoiseDiffSpacingS / filteredPeriod())));
  const size_t L = static_cast<size_t>(diff_lag_);
  sample_var_per_density_sq_ = std::max(1e-12, params_.imu.input_rate_hz * autocov0);
  second_diff_var_per_density_sq_ =
      std::max(1e-12, sample_var_per_density_sq_ * (1.5 - 2.0 * rho(L) + 0.5 * rho(2 * L)));
  // The smoothed acceleration's level (holdColumnAccel) weighs the samples k periods back by c_k = w b^k (2 - w (k +
  // 1)), b = 1 - w, in the steady state: its variance is sum_k sum_l c_k c_l R((k - l) D), i.e. the white samples'
  // sum_k c_k^2 R(0) times 1 + 2 sum_m rho_m S_m / S_0 with S_m = sum_k c_k c_(k+m). The correlation reaches over
  // about the low-pass's time constant: one or two periods at 100 Hz, ten and more at 500 Hz (20 Hz low-pass).
  const double tau_s = params_.imu.jacobian_accel_smoothing_s;
  const double w = tau_s > 0.0 ? -std::expm1(-filteredPeriod() / tau_s) : 1.0;
  correlation_factor_ = 1.0;
  if (w < 1.0 && autocov.size() > 1) {
    const double b = 1.0 - w;
    const int n = static_cast<int>(std::min(1e6, std::ceil(50.0 / w)));  // b^n below 1e-21
    std::vector<double> c(static_cast<size_t>(n));  // once, at set-up
    double bk = 1.0;
    for (int k = 0; k < n; ++k, bk *= b) c[static_cast<size_t>(k)] = w * bk * (2.0 - w * (k + 1));
    auto S = [&](size_t m) {
      double sum = 0.0;
      for (size_t k = 0; k + m < c.size(); ++k) sum += c[k] * c[k + m];
      return sum;
    };
    const double S0 = S(0);
    double sum = 0.0;
    for (size_t m = 1; m < autocov.size(); ++m) sum += rho(m) * S(m);
    correlation_factor_ = std::max(1e-3, 1.0 + 2.0 * sum / S0);
  }
}

bool ImuPropagator::push(const ImuSample& filtered) {
  if (!buffer_.empty() && filtered.t_s <= buffer_.back().t_s) return false;
  // The second difference of three samples L nominal periods apart (setFilterNoise): over 2 L periods (20 ms) the
  // motion's own curvature is small against the noise.
  const size_t L = static_cast<size_t>(diff_lag_);
  if (buffer_.size() >= 2 * L) {
    const ImuSample& a = buffer_[buffer_.size() - 2 * L];
    const ImuSample& b = buffer_[buffer_.size() - L];
    const double period = L * filteredPeriod();
    const Vec3 e = 0.5 * (a.gyro_radps + filtered.gyro_radps) - b.gyro_radps;
    const Vec3 ea = 0.5 * (a.accel_mps2 + filtered.accel_mps2) - b.accel_mps2;
    if (std::abs(b.t_s - a.t_s - period) < 0.1 * period && std::abs(filtered.t_s - b.t_s - period) < 0.1 * period &&
        e.allFinite() && ea.allFinite()) {
      // Smoothed over 2 s (one difference per sample); the plain mean of the first ones (no start from zero).
      constexpr double kTimeConstantS = 2.0;
      second_diffs_ = std::min(second_diffs_ + 1, 1 << 20);
      const double beta = std::max(1.0 - std::exp(-filteredPeriod() / kTimeConstantS), 1.0 / second_diffs_);
      gyro_second_diff_var_ += beta * (e.cwiseAbs2() - gyro_second_diff_var_);
      accel_second_diff_var_ += beta * (ea.cwiseAbs2() - accel_second_diff_var_);
    }
  }
  buffer_.push(filtered);
  return true;
}

bool ImuPropagator::noiseMeasured() const { return second_diffs_ >= 1.0 / filteredPeriod(); }  // 1 s of them

Vec3 ImuPropagator::calibratedSampleVariance(double density) const {
  return Vec3::Constant(density * density * sample_var_per_density_sq_);
}

Vec3 ImuPropagator::sampleVariance(const Vec3& second_diff_var, double calibrated_density) const {
  if (!noiseMeasured()) return calibratedSampleVariance(calibrated_density);
  return second_diff_var * (sample_var_per_density_sq_ / second_diff_var_per_density_sq_);
}

Vec3 ImuPropagator::gyroSampleVariance() const {
  return sampleVariance(gyro_second_diff_var_, params_.imu.gyro_noise_density);
}

Vec3 ImuPropagator::accelSampleVariance() const {
  return sampleVariance(accel_second_diff_var_, params_.imu.accel_noise_density);
}

Vec3 ImuPropagator::accelLevelSampleVariance() const {
  return accelSampleVariance().cwiseMin(calibratedSampleVariance(params_.imu.accel_noise_density));
}

double ImuPropagator::gyroNoiseDensitySq() const {
  const double calibrated = params_.imu.gyro_noise_density * params_.imu.gyro_noise_density;
  if (!noiseMeasured()) return calibrated;
  return std::min(calibrated, gyro_second_diff_var_.maxCoeff() / second_diff_var_per_density_sq_);
}

void ImuPropagator::startAt(double t_s) {
  t_state_s_ = t_s;
  accel_smooth_valid_ = column_valid_ = false;  // a new run: nothing propagated yet
  dropUsed();
}

void ImuPropagator::dropUsed() {
  // Keep the last sample at or before the state's time (the next piece interpolates from it), and those of
  // the history before it that moveReference may reach back into (a reference moved earlier by a changed
  // camera-IMU time offset: at most twice its bound).
  const double keep_from_s = t_state_s_ - 2.0 * std::max(0.0, params_.max_time_offset_s);
  while (buffer_.size() > 1 && buffer_[1].t_s <= keep_from_s) buffer_.pop();
}

void ImuPropagator::moveReference(double from_s, double to_s) {
  if (!(to_s != from_s) || !std::isfinite(to_s)) return;
  // The interval's gyro integral starts at to_s instead of from_s: the part in between added (earlier) or
  // taken off (later; it may lie beyond the state's time, which meanGyroOverInterval's sum allows for).
  if (to_s < from_s) {
    gyro_integral_ += gyroIntegral(to_s, from_s);
    gyro_time_s_ += from_s - to_s;
  } else {
    gyro_integral_ -= gyroIntegral(from_s, to_s);
    gyro_time_s_ -= to_s - from_s;
  }
  ref_rate_C_ = imuAt(to_s).gyro_radps;
}

double ImuPropagator::filteredPeriod() const {
  return std::max(1, params_.imu.decimation_factor) / std::max(1e-9, params_.imu.input_rate_hz);
}

Vec3 ImuPropagator::gyroIntegral(double t0_s, double t1_s) const {
  Vec3 sum = Vec3::Zero();
  forEachImuPiece(buffer_, t0_s, t1_s, 2.0 * filteredPeriod(),
                  [&](double a_s, double b_s, const ImuSample& in) { sum += in.gyro_radps * (b_s - a_s); });
  return sum;
}

// Each step is fed the mean of the linear interpolation between the samples around it (forEachImuPiece); across
// a bridged IMU gap the sample after it is held (zero-order hold) and the gap is integrated in steps of at most
// one nominal period, its noise inflated (predictImuPiece).
void ImuPropagator::propagateTo(double t_target_s, State* x, ErrorCov* P) {
  const double nominal_dt_s = filteredPeriod();
  const double tau_s = params_.imu.jacobian_accel_smoothing_s;
  const bool held = tau_s >= 0.0;
  const double g0 = params_.imu.gravity_mps2;
  // Without an image update for a while the held value would be extrapolated ever further: renewed then
  // (holdColumnAccel is a no-op while nothing was propagated or without the smoothing).
  if (!column_valid_ || t_state_s_ - column_t_s_ > kMaxColumnAccelAgeS) holdColumnAccel();
  forEachImuPiece(buffer_, t_state_s_, t_target_s, 2.0 * nominal_dt_s,
                  [&](double t0_s, double t1_s, const ImuSample& s, double u, bool starts_interval) {
    const double dt = t1_s - t0_s;
    if (!held) {
      predictImuPiece(s, dt, nominal_dt_s, params_, x, P, nullptr, &focal_sensitivity_);
    } else {
      // The held acceleration extrapolated to the step and turned with the camera since it was held; then the
      // smoothed ones turned with the camera and updated with this step's acceleration.
      // (Before the first hold: no acceleration measured apart from this step's reading yet, none in the column.)
      const Vec3 held_accel = column_accel_C_ + (t0_s - column_t_s_) * column_trend_C_;  // m/s^2
      const Vec3 column = column_valid_ ? Vec3(column_turn_ * held_accel) : Vec3::Zero();
      const Mat3 turn = expSO3(-dt * (s.gyro_radps - x->b_w));
      predictImuPiece(s, dt, nominal_dt_s, params_, x, P, &column, &focal_sensitivity_);
      column_turn_ = turn * column_turn_;
      const Vec3 accel = s.accel_mps2 - x->b_a + g0 * x->g.vector();  // m/s^2
      // The two averages' variances and covariance per unit sample variance (white samples), exactly from the
      // first one: a piece's input is (1 - u) n_prev + u n_next of the two samples around it (the interpolation at
      // its middle), so the pieces of one interval share their noise; each sample's coefficients in s1, s2 add up
      // until it leaves the interpolation (s1' = k s1 + w a, s2' = k s2 + w s1').
      if (!accel_smooth_valid_) {
        smooth1_C_ = smooth2_C_ = accel;
        prev_c1_ = prev_c2_ = 1.0 - u;
        next_c1_ = next_c2_ = u;
        closed11_ = closed12_ = closed22_ = 0.0;
        accel_smooth_valid_ = true;
      } else {
        const double w = tau_s > 0.0 ? -std::expm1(-dt / tau_s) : 1.0, k = 1.0 - w;
        smooth1_C_ = turn * smooth1_C_;
        smooth1_C_ += w * (accel - smooth1_C_);
        smooth2_C_ = turn * smooth2_C_;
        smooth2_C_ += w * (smooth1_C_ - smooth2_C_);
        if (starts_interval) {  // the earlier sample leaves; the later one becomes the earlier
          closed11_ += prev_c1_ * prev_c1_;
          closed12_ += prev_c1_ * prev_c2_;
          closed22_ += prev_c2_ * prev_c2_;
          prev_c1_ = next_c1_;
          prev_c2_ = next_c2_;
          next_c1_ = next_c2_ = 0.0;
        }
        closed22_ = k * k * (closed22_ + 2.0 * w * closed12_ + w * w * closed11_);
        closed12_ = k * k * (closed12_ + w * closed11_);
        closed11_ = k * k * closed11_;
        prev_c1_ = k * prev_c1_ + w * (1.0 - u);
        prev_c2_ = k * prev_c2_ + w * prev_c1_;
        next_c1_ = k * next_c1_ + w * u;
        next_c2_ = k * next_c2_ + w * next_c1_;
      }
    }
    gyro_integral_ += s.gyro_radps * dt;
    gyro_time_s_ += dt;
  });
  t_state_s_ = t_target_s;
  dropUsed();
}

double ImuPropagator::levelVarianceFactor() const {
  const double v11 = closed11_ + prev_c1_ * prev_c1_ + next_c1_ * next_c1_;
  const double v12 = closed12_ + prev_c1_ * prev_c2_ + next_c1_ * next_c2_;
  const double v22 = closed22_ + prev_c2_ * prev_c2_ + next_c2_ * next_c2_;
  return 4.0 * v11 - 4.0 * v12 + v22;
}

void ImuPropagator::holdColumnAccel() {
  const double tau_s = params_.imu.jacobian_accel_smoothing_s;
  if (!accel_smooth_valid_ || tau_s < 0.0) return;
  // Brown's double exponential smoothing: with w the weight per nominal period h, the level 2 s1 - s2 is the
  // acceleration now and w / (1 - w) (s1 - s2) / h its rate of change, both without the lag of s1 for a linear
  // trend (w = 1, no smoothing: the last step's acceleration, no trend).
  const double h = filteredPeriod();
  const double w = tau_s > 0.0 ? -std::expm1(-h / tau_s) : 1.0;
  const Vec3 level = 2.0 * smooth1_C_ - smooth2_C_;
  const Vec3 trend = w < 1.0 ? Vec3((w / ((1.0 - w) * h)) * (smooth1_C_ - smooth2_C_)) : Vec3::Zero();
  // Held as its expected value given the samples' noise through the smoothing: one sample's variance
  // (accelLevelSampleVariance: the calibration's at most) times the level's variance factor 4 v11 - 4 v12 + v22
  // (tracked from the first sample: 1 then, w (1 + 4b + 5b^2) / (1 + b)^3 with b = 1 - w in the steady state),
  // times the factor of the filtered samples' correlation over every lag (sampleCorrelationFactor). Where the noise
  // explains the level (at rest), the column shows no acceleration, and the images' "vartheta did not change" is no
  // information about the distance. (The gravity direction's and the
  // bias's uncertainty are not counted: they are states whose first-order effect F models, and counted here they
  // hold the distance back until the tilt is known: docs/algorithm.md 2.1.)
  const double noise_factor = std::max(0.0, levelVarianceFactor()) * correlation_factor_;
  const Vec3 var = noise_factor * accelLevelSampleVariance();
  column_accel_C_ = expectedGivenReading(level, var);
  for (int i = 0; i < 3; ++i)  // the trend shrunk alike
    column_trend_C_(i) = level(i) != 0.0 ? trend(i) * (column_accel_C_(i) / level(i)) : 0.0;
  column_turn_.setIdentity();
  column_t_s_ = t_state_s_;
  column_valid_ = true;
}

void ImuPropagator::setReference(double t_s) {
  ref_rate_C_ = imuAt(t_s).gyro_radps;
  clearInterval();
}

void ImuPropagator::clearInterval() {
  gyro_integral_.setZero();
  gyro_time_s_ = 0.0;
}

Vec3 ImuPropagator::meanGyroOverInterval(double t_img_s) const {
  const double rest_s = t_img_s - t_state_s_;
  const double total_s = gyro_time_s_ + rest_s;
  return total_s > 0.0 ? Vec3((gyro_integral_ + gyroIntegral(t_state_s_, t_img_s)) / total_s) : Vec3::Zero();
}

ImuSample ImuPropagator::imuAt(double t_s) const {
  ImuSample out;
  out.t_s = t_s;
  if (buffer_.empty()) return out;
  size_t i = 0;
  while (i < buffer_.size() && buffer_[i].t_s < t_s) ++i;
  if (i == 0 || i == buffer_.size()) {
    const ImuSample& s = buffer_[i == 0 ? 0 : buffer_.size() - 1];
    out.accel_mps2 = s.accel_mps2;
    out.gyro_radps = s.gyro_radps;
    return out;
  }
  const ImuSample& a = buffer_[i - 1];
  const ImuSample& b = buffer_[i];
  const double u = b.t_s > a.t_s ? (t_s - a.t_s) / (b.t_s - a.t_s) : 1.0;
  out.accel_mps2 = a.accel_mps2 + u * (b.accel_mps2 - a.accel_mps2);
  out.gyro_radps = a.gyro_radps + u * (b.gyro_radps - a.gyro_radps);
  return out;
}

bool ImuPropagator::gravityFromAccel(double up_to_t_s, UnitVector* g, double* spread_var_rad2) const {
  Vec3 sum = Vec3::Zero();
  Mat3 sum_sq = Mat3::Zero();
  int n = 0;
  // The rotation of the frame from each sample to the window's end (small angles: the gyro summed backwards).
  Vec3 turned = Vec3::Zero();
  double turned_sq = 0.0, last_t = up_to_t_s;
  for (size_t i = buffer_.size(); i-- > 0;) {
    const ImuSample& s = buffer_[i];
    if (s.t_s > up_to_t_s) continue;
    if (up_to_t_s - s.t_s > 0.5) break;
    turned += s.gyro_radps * (last_t - s.t_s);
    last_t = s.t_s;
    turned_sq += turned.squaredNorm();
    sum += s.accel_mps2;
    sum_sq.noalias() += s.accel_mps2 * s.accel_mps2.transpose();
    ++n;
  }
  if (n == 0) return false;
  const Vec3 f = sum / n;
  const double g0 = params_.imu.gravity_mps2;
  if (!f.allFinite() || std::abs(f.norm() - g0) > 0.1 * g0) return false;
  // Specific force at rest points up, gravity down.
  *g = UnitVector(-f);
  if (spread_var_rad2 != nullptr) {
    const Mat3 cov = sum_sq / n - f * f.transpose();
    const Vec3 u = f.normalized();
    *spread_var_rad2 = std::max(0.0, 0.5 * (cov.trace() - u.dot(cov * u))) / f.squaredNorm() + 0.5 * turned_sq / n;
  }
  return true;
}

}  // namespace internal
}  // namespace diekf
