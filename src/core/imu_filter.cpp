#include "diekf/imu_filter.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <stdexcept>
#include <string>

namespace diekf {

int effectiveLowpassOrder(const ImuParams& p) {
  if (p.lowpass_order <= 0) return p.lowpass_order;
  const bool aliased = p.input_rate_hz < 2.0 * p.max_vibration_hz;
  return aliased ? std::max(p.lowpass_order, p.aliased_lowpass_order) : p.lowpass_order;
}

namespace {
// The notches' spectrum: about one second of samples (the power of two at or above the rate), renewed every eighth
// of it to follow the rotors' speed, searched from the cutoff up (below it lies the motion's band).
VibrationNotch::Options notchOptions(const ImuParams& p) {
  VibrationNotch::Options o;
  o.min_hz = p.lowpass_cutoff_hz;
  o.window = 64;
  while (o.window < p.input_rate_hz) o.window *= 2;
  o.hop = o.window / 8;
  return o;
}
}  // namespace

bool vibrationNotchesOn(const ImuParams& p) {
  return p.aliased_notch && p.lowpass_order > 0 && p.input_rate_hz < 2.0 * p.max_vibration_hz &&
         VibrationNotch::bandFits(p.input_rate_hz, notchOptions(p));
}

ImuPreprocessor::ImuPreprocessor(const Eigen::Isometry3d& T_cam_imu, const ImuParams& params)
    : params_(params) {
  if (!(params.input_rate_hz > 0.0)) {
    throw std::invalid_argument("ImuPreprocessor: input_rate_hz must be > 0, got " +
                                std::to_string(params.input_rate_hz));
  }
  if (params.decimation_factor < 1) {
    throw std::invalid_argument("ImuPreprocessor: decimation_factor must be >= 1, got " +
                                std::to_string(params.decimation_factor));
  }
  if (params.lowpass_order < 0 || params.aliased_lowpass_order < 0) {
    throw std::invalid_argument("ImuPreprocessor: lowpass_order and aliased_lowpass_order must be >= 0, got " +
                                std::to_string(params.lowpass_order) + " and " +
                                std::to_string(params.aliased_lowpass_order));
  }
  // Vibration the IMU's rate folds into the low band gets the steeper filter (docs/algorithm.md section 4).
  params_.lowpass_order = effectiveLowpassOrder(params);
  const double fs = params.input_rate_hz;  // Hz
  if (params.lowpass_order > 0 && !(params.lowpass_cutoff_hz > 0.0 && params.lowpass_cutoff_hz < 0.5 * fs)) {
    throw std::invalid_argument("ImuPreprocessor: lowpass_cutoff_hz must be in (0, input_rate_hz/2), got " +
                                std::to_string(params.lowpass_cutoff_hz));
  }

  // Extrinsics: p_C = R_CI p_I + t_CI. The camera centre (p_C = 0) sits at p_I = -R_CI^T t_CI, i.e. at
  // r = R_CI p_I = -t_CI from the IMU origin, expressed in C.
  R_CI_ = T_cam_imu.linear();
  r_imu_to_cam_C_ = -T_cam_imu.translation();

  // Butterworth low-pass: analog prototype sections s'^2 + 2 sin(theta_k) s' + 1 (theta_k = (2k+1) pi / (2N)),
  // plus s' + 1 for odd N, with s' = s / Omega_c. Bilinear transform with the cutoff prewarped:
  // s' = (1/K) (1 - z^-1) / (1 + z^-1), K = tan(pi fc / fs), so the digital -3 dB point is exactly fc.
  const int order = params_.lowpass_order;
  if (order > 0) {
    const double K = std::tan(M_PI * params.lowpass_cutoff_hz / fs);
    const double K2 = K * K;
    for (int k = 0; k < order / 2; ++k) {
      const double c = 2.0 * std::sin((2.0 * k + 1.0) * M_PI / (2.0 * order));
      const double a0 = 1.0 + c * K + K2;
      Biquad6 bq;
      bq.b0 = K2 / a0;
      bq.b1 = 2.0 * K2 / a0;
      bq.b2 = K2 / a0;
      bq.a1 = 2.0 * (K2 - 1.0) / a0;
      bq.a2 = (1.0 - c * K + K2) / a0;
      sections_.push_back(bq);
    }
    if (order % 2 == 1) {
      Biquad6 fo;  // first-order section K (1 + z^-1) / ((1 + K) + (K - 1) z^-1)
      fo.b0 = K / (1.0 + K);
      fo.b1 = K / (1.0 + K);
      fo.b2 = 0.0;
      fo.a1 = (K - 1.0) / (K + 1.0);
      fo.a2 = 0.0;
      sections_.push_back(fo);
    }
  }

  // Group delay at 0 Hz of B(z)/A(z): sum n b_n / sum b_n - sum n a_n / sum a_n, in samples (exact for the
  // designed coefficients; approaches sum_k 2 sin(theta_k) / Omega_c for fc << fs).
  double delay_samples = 0.0;
  for (const Biquad6& s : sections_) delay_samples += s.dcDelaySamples();
  // The decimation's boxcar (imu/decimation_mean): the mean of D samples is centred (D - 1) / 2 periods back.
  const int boxcar = params.decimation_mean ? params.decimation_factor : 1;
  boxcar_.assign(static_cast<size_t>(boxcar), Vec6::Zero());
  delay_samples += 0.5 * (boxcar - 1);
  delay_s_ = delay_samples / fs;
  // Folded vibration tones notched before the low-pass (docs/algorithm.md section 4, "Notches").
  if (vibrationNotchesOn(params)) notch_.emplace(fs, notchOptions(params));
  prime_samples_ = order > 0 && params.prime_from_mean
                       ? std::max(1, static_cast<int>(std::lround(fs / params.lowpass_cutoff_hz)))
                       : 1;
  if (order > 0 && params.prime_from_mean) {
    // Settling: the shortest n with the impulse response's tail sum_(k >= n) |h_k| <= kSettleTail sum |h_k|.
    const std::vector<double> h = impulseResponse(0);
    double total = 0.0;
    for (double v : h) total += std::abs(v);
    double tail = total;
    int n = 0;
    while (n < static_cast<int>(h.size()) && tail > kSettleTail * total) tail -= std::abs(h[static_cast<size_t>(n++)]);
    settle_samples_ = n;
  }
}

double ImuPreprocessor::magnitudeResponse(double f_hz) const {
  const double omega = 2.0 * M_PI * f_hz / params_.input_rate_hz;  // rad/sample
  const std::complex<double> z1 = std::polar(1.0, -omega);          // z^-1
  std::complex<double> h(1.0, 0.0);
  for (const Biquad6& s : sections_) {
    h *= (s.b0 + s.b1 * z1 + s.b2 * z1 * z1) / (1.0 + s.a1 * z1 + s.a2 * z1 * z1);
  }
  return std::abs(h);
}

std::vector<double> ImuPreprocessor::impulseResponse(int extra) const {
  // The impulse response through the cascaded sections (transposed direct form II, as filter()), until it has
  // decayed: long enough for any cutoff the constructor accepts (the slowest pole's time constant is below
  // fs / (2 pi fc) samples).
  const int n = 64 + extra + static_cast<int>(std::ceil(40.0 * params_.input_rate_hz /
                                                        (2.0 * M_PI * std::max(1e-9, params_.lowpass_cutoff_hz))));
  std::vector<double> h(static_cast<size_t>(sections_.empty() ? 1 : n), 0.0);
  h[0] = 1.0;
  for (const Biquad6& s : sections_) {
    double z1 = 0.0, z2 = 0.0;
    for (double& v : h) {
      const double in = v;
      v = s.b0 * in + z1;
      z1 = s.b1 * in - s.a1 * v + z2;
      z2 = s.b2 * in - s.a2 * v;
    }
  }
  return h;
}

std::vector<double> ImuPreprocessor::outputImpulseResponse(int extra) const {
  const std::vector<double> h = impulseResponse(extra);
  const int D = boxcarLength();
  if (D == 1) return h;
  std::vector<double> g(h.size() + static_cast<size_t>(D - 1), 0.0);  // h convolved with the boxcar
  for (size_t i = 0; i < h.size(); ++i)
    for (size_t j = 0; j < static_cast<size_t>(D); ++j) g[i + j] += h[i] / D;
  return g;
}

namespace {
double autocovarianceOf(const std::vector<double>& h, size_t lag) {
  double sum = 0.0;
  for (size_t i = 0; i + lag < h.size(); ++i) sum += h[i] * h[i + lag];
  return sum;
}
}  // namespace

double ImuPreprocessor::noiseAutocovariance(int lag) const {
  if (lag < 0) lag = -lag;
  return autocovarianceOf(outputImpulseResponse(lag), static_cast<size_t>(lag));
}

std::vector<double> ImuPreprocessor::noiseAutocovariances(int step) const {
  step = std::max(1, step);
  const std::vector<double> h = outputImpulseResponse(0);
  std::vector<double> r;
  for (size_t lag = 0; lag < h.size() || r.size() < 3; lag += static_cast<size_t>(step))
    r.push_back(autocovarianceOf(h, lag));
  return r;
}

void ImuPreprocessor::reset() {
  primed_ = false;
  prime_sum_.setZero();
  prime_count_ = 0;
  counter_ = 0;
  for (Biquad6& s : sections_) s.clear();
  last_gyro_C_.setZero();
  std::fill(boxcar_.begin(), boxcar_.end(), Vec6::Zero());
  boxcar_next_ = 0;
  if (notch_) notch_->reset();
}

void ImuPreprocessor::prime(const Vec6& in) {
  // Steady state of every section for the constant input `in`: y = gain x at each.
  Vec6 x = in;
  for (Biquad6& s : sections_) {
    const Vec6 y = s.dcGain() * x;
    s.settleAt(x, y);
    x = y;
  }
}

ImuPreprocessor::Vec6 ImuPreprocessor::atCamera(const Vec6& y, const Vec3& w_dot) const {
  Vec6 z = y;
  if (params_.lever_arm_compensation) {
    const Vec3& r = r_imu_to_cam_C_;
    const Vec3 w = y.tail<3>();
    z.head<3>() += w_dot.cross(r) + w.cross(w.cross(r));
  }
  return z;
}

ImuPreprocessor::Vec6 ImuPreprocessor::filter(const Vec6& in) {
  Vec6 x = in;
  for (Biquad6& s : sections_) x = s.step(x);
  return x;
}

bool ImuPreprocessor::push(const ImuSample& raw_imu, ImuSample* out) {
  Vec6 in;
  in.head<3>() = R_CI_ * raw_imu.accel_mps2;  // specific force at the IMU, in C, m/s^2
  in.tail<3>() = R_CI_ * raw_imu.gyro_radps;  // body rate in C, rad/s
  if (notch_) in = notch_->apply(in);
  if (!primed_) {
    // imu.prime_from_mean: start from the mean of the first samples over one period of the cutoff, not from one
    // raw sample, which carries the vibration's instantaneous value (m/s^2 on a flying drone): a filter primed
    // on it emits a decaying burst of acceleration the images never show (docs/results.md "Start-up").
    prime_sum_ += in;
    if (++prime_count_ < prime_samples_) return false;
    const Vec6 mean = prime_sum_ / static_cast<double>(prime_count_);
    prime(mean);
    primed_ = true;
    counter_ = 0;
    settle_left_ = settle_samples_;
    last_gyro_C_ = mean.tail<3>();
    // The boxcar starts full of the primed (steady) sample, so its first mean is centred as every later one.
    std::fill(boxcar_.begin(), boxcar_.end(), atCamera(mean, Vec3::Zero()));
    boxcar_next_ = 0;
  }
  const Vec6 y = filter(in);
  const Vec3 w = y.tail<3>();
  // Backward difference at the nominal input period (robust to stamp jitter; the filter is designed for it).
  const Vec3 w_dot = (w - last_gyro_C_) * params_.input_rate_hz;  // rad/s^2
  last_gyro_C_ = w;
  const int D = boxcarLength();
  if (D > 1) {  // every sample into the boxcar, the settling ones included
    boxcar_[static_cast<size_t>(boxcar_next_)] = atCamera(y, w_dot);
    boxcar_next_ = (boxcar_next_ + 1) % D;
  }
  if (settle_left_ > 0) {  // the start-up transient (settleSamples): nothing emitted yet
    --settle_left_;
    return false;
  }

  const bool emit = (counter_ == 0);
  counter_ = (counter_ + 1) % params_.decimation_factor;
  if (!emit) return false;

  Vec6 z;
  if (D > 1) {
    z.setZero();
    for (const Vec6& b : boxcar_) z += b;
    z /= D;
  } else {
    z = atCamera(y, w_dot);
  }
  out->accel_mps2 = z.head<3>();
  out->gyro_radps = z.tail<3>();
  const double delay_s = delay_s_ + (notch_ ? notch_->delaySamples() / params_.input_rate_hz : 0.0);
  out->t_s = params_.compensate_filter_delay ? raw_imu.t_s - delay_s : raw_imu.t_s;
  return true;
}

}  // namespace diekf
