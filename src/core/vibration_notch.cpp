#include "diekf/vibration_notch.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace diekf {

namespace {
// Bins from min_hz up to one short of Nyquist (each tested against both neighbours): [first, last].
int firstBin(double rate_hz, const VibrationNotch::Options& o) {
  return std::max(2, static_cast<int>(std::ceil(o.min_hz * o.window / rate_hz)));
}
int lastBin(const VibrationNotch::Options& o) { return o.window / 2 - 2; }
}  // namespace

bool VibrationNotch::bandFits(double rate_hz, const Options& o) {
  return rate_hz > 0.0 && std::isfinite(rate_hz) && o.min_hz > 0.0 && o.min_hz < 0.5 * rate_hz && o.window >= 32 &&
         (o.window & (o.window - 1)) == 0 && lastBin(o) >= firstBin(rate_hz, o) + 4;
}

VibrationNotch::VibrationNotch(double rate_hz, const Options& options) : rate_hz_(rate_hz), opt_(options) {
  if (!bandFits(rate_hz, opt_))
    throw std::invalid_argument("VibrationNotch: rate " + std::to_string(rate_hz) + " Hz, min_hz " +
                                std::to_string(opt_.min_hz) + " and window " + std::to_string(opt_.window) +
                                ": need a rate > 0, min_hz in (0, rate / 2) and a power-of-two window >= 32 holding "
                                "five bins from min_hz to Nyquist");
  const int N = opt_.window;
  if (opt_.hop < 1 || opt_.max_notches < 1 || opt_.max_notches > kMaxNotches || !(opt_.q > 0.0) ||
      !(opt_.peak_ratio > 1.0))
    throw std::invalid_argument("VibrationNotch: hop >= 1, max_notches 1..4, q > 0 and peak_ratio > 1 required");
  ring_.assign(static_cast<size_t>(N), Eigen::Vector3d::Zero());
  hann_.resize(static_cast<size_t>(N));
  cos_.resize(static_cast<size_t>(N));
  sin_.resize(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i) {
    hann_[static_cast<size_t>(i)] = 0.5 - 0.5 * std::cos(2.0 * M_PI * i / N);
    cos_[static_cast<size_t>(i)] = std::cos(2.0 * M_PI * i / N);
    sin_[static_cast<size_t>(i)] = std::sin(2.0 * M_PI * i / N);
  }
  k_lo_ = firstBin(rate_hz, opt_);
  k_hi_ = lastBin(opt_);
  power_.assign(static_cast<size_t>(N / 2 + 1), 0.0);
  re_.assign(static_cast<size_t>(N), 0.0);
  im_.assign(static_cast<size_t>(N), 0.0);
  bitrev_.assign(static_cast<size_t>(N), 0);
  int bits = 0;
  while ((1 << bits) < N) ++bits;
  for (int i = 0; i < N; ++i) {
    int r = 0;
    for (int b = 0; b < bits; ++b) r |= ((i >> b) & 1) << (bits - 1 - b);
    bitrev_[static_cast<size_t>(i)] = r;
  }
  sorted_.reserve(static_cast<size_t>(k_hi_ - k_lo_ + 1));
}

void VibrationNotch::reset() {
  count_ = 0;
  since_analysis_ = 0;
  for (Notch& n : notches_) n = Notch();
}

int VibrationNotch::activeNotches() const {
  int n = 0;
  for (const Notch& x : notches_) n += x.active;
  return n;
}

double VibrationNotch::frequencyHz(int i) const {
  for (const Notch& x : notches_) {
    if (!x.active) continue;
    if (i-- == 0) return x.f_hz;
  }
  return 0.0;
}

double VibrationNotch::delaySamples() const {
  // Group delay at 0 Hz, summed over the active notches.
  double d = 0.0;
  for (const Notch& n : notches_) {
    if (n.active) d += n.section.dcDelaySamples();
  }
  return d;
}

void VibrationNotch::place(Notch* n, double f_hz, const Vec6& x) {
  // Second-order notch (zeros on the unit circle at f0, poles inside at the same angle): unit gain at 0 Hz and
  // Nyquist, -3 dB width f0 / q.
  const double w0 = 2.0 * M_PI * f_hz / rate_hz_;
  const double alpha = std::sin(w0) / (2.0 * opt_.q);
  const double c = std::cos(w0);
  const double a0 = 1.0 + alpha;
  Biquad6& b = n->section;
  b.b0 = 1.0 / a0;
  b.b1 = -2.0 * c / a0;
  b.b2 = 1.0 / a0;
  b.a1 = -2.0 * c / a0;
  b.a2 = (1.0 - alpha) / a0;
  n->f_hz = f_hz;
  if (!n->active) {
    // Start in the steady state of the current input (gain 1 at 0 Hz): no transient from a constant part.
    b.settleAt(x, x);
    n->active = true;
  }
}

void VibrationNotch::fft() {
  // In-place iterative radix-2 FFT of re_/im_ (length N, a power of two): bit-reversed order, then butterflies with
  // the twiddles exp(-2 pi i k / N) of the tables.
  const size_t N = re_.size();
  for (size_t i = 0; i < N; ++i) {
    const size_t j = static_cast<size_t>(bitrev_[i]);
    if (j > i) {
      std::swap(re_[i], re_[j]);
      std::swap(im_[i], im_[j]);
    }
  }
  for (size_t len = 2; len <= N; len <<= 1) {
    const size_t half = len / 2, step = N / len;
    for (size_t start = 0; start < N; start += len) {
      for (size_t k = 0; k < half; ++k) {
        const double wr = cos_[k * step], wi = -sin_[k * step];
        const size_t a = start + k, b = a + half;
        const double tr = wr * re_[b] - wi * im_[b], ti = wr * im_[b] + wi * re_[b];
        re_[b] = re_[a] - tr;
        im_[b] = im_[a] - ti;
        re_[a] += tr;
        im_[a] += ti;
      }
    }
  }
}

void VibrationNotch::analyse() {
  const int N = opt_.window;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& s : ring_) mean += s;
  mean /= N;
  const size_t first = static_cast<size_t>(count_ % N);  // the oldest sample's slot
  std::fill(power_.begin(), power_.end(), 0.0);
  for (int axis = 0; axis < 3; ++axis) {
    for (size_t i = 0; i < static_cast<size_t>(N); ++i) {
      re_[i] = hann_[i] * (ring_[(first + i) & static_cast<size_t>(N - 1)](axis) - mean(axis));
      im_[i] = 0.0;
    }
    fft();
    for (int k = k_lo_ - 1; k <= k_hi_ + 1; ++k) {
      const size_t u = static_cast<size_t>(k);
      power_[u] += re_[u] * re_[u] + im_[u] * im_[u];
    }
  }
  sorted_.assign(power_.begin() + k_lo_, power_.begin() + k_hi_ + 1);
  const auto mid = sorted_.begin() + static_cast<long>(sorted_.size() / 2);
  std::nth_element(sorted_.begin(), mid, sorted_.end());
  const double floor = *mid;

  // The strongest local maxima above the floor, at least three bins apart (the Hann window's main lobe).
  std::array<double, kMaxNotches> tone_hz{};
  std::array<int, kMaxNotches> tone_bin{};
  int tones = 0;
  for (int m = 0; m < opt_.max_notches; ++m) {
    int best = -1;
    for (int k = k_lo_; k <= k_hi_; ++k) {
      const double p = power_[static_cast<size_t>(k)];
      if (!(p > opt_.peak_ratio * floor) || p < power_[static_cast<size_t>(k - 1)] ||
          p < power_[static_cast<size_t>(k + 1)])
        continue;
      bool taken = false;
      for (int j = 0; j < tones; ++j) taken |= std::abs(k - tone_bin[static_cast<size_t>(j)]) < 3;
      if (!taken && (best < 0 || p > power_[static_cast<size_t>(best)])) best = k;
    }
    if (best < 0) break;
    // Parabolic interpolation of the log power over the peak's bins.
    const double l0 = std::log(std::max(power_[static_cast<size_t>(best - 1)], 1e-300));
    const double l1 = std::log(power_[static_cast<size_t>(best)]);
    const double l2 = std::log(std::max(power_[static_cast<size_t>(best + 1)], 1e-300));
    const double den = l0 - 2.0 * l1 + l2;
    const double delta = den < 0.0 ? std::clamp(0.5 * (l0 - l2) / den, -0.5, 0.5) : 0.0;
    tone_bin[static_cast<size_t>(tones)] = best;
    tone_hz[static_cast<size_t>(tones)] = (best + delta) * rate_hz_ / N;
    ++tones;
  }

  // Each tone moves the notch already near it, or takes a free one; unmatched notches go.
  const double bin_hz = rate_hz_ / N;
  std::array<bool, kMaxNotches> kept{};
  std::array<bool, kMaxNotches> placed{};
  for (int j = 0; j < tones; ++j) {
    for (int i = 0; i < kMaxNotches; ++i) {
      Notch& n = notches_[static_cast<size_t>(i)];
      // Within the notch's half width (or two bins): the same tone, moved with the rotors' speed.
      const double reach_hz = std::max(2.0 * bin_hz, 0.5 * n.f_hz / opt_.q);
      if (n.active && !kept[static_cast<size_t>(i)] && std::abs(n.f_hz - tone_hz[static_cast<size_t>(j)]) < reach_hz) {
        place(&n, tone_hz[static_cast<size_t>(j)], last_in_);
        kept[static_cast<size_t>(i)] = placed[static_cast<size_t>(j)] = true;
        break;
      }
    }
  }
  for (int i = 0; i < kMaxNotches; ++i)
    if (!kept[static_cast<size_t>(i)]) notches_[static_cast<size_t>(i)].active = false;
  for (int j = 0; j < tones; ++j) {
    if (placed[static_cast<size_t>(j)]) continue;
    for (int i = 0; i < kMaxNotches; ++i) {
      Notch& n = notches_[static_cast<size_t>(i)];
      if (!n.active) {
        place(&n, tone_hz[static_cast<size_t>(j)], last_in_);
        break;
      }
    }
  }
}

VibrationNotch::Vec6 VibrationNotch::apply(const Vec6& in) {
  const int N = opt_.window;
  ring_[static_cast<size_t>(count_ & (N - 1))] = in.head<3>();
  ++count_;
  if (count_ >= N && ++since_analysis_ >= opt_.hop) {
    since_analysis_ = 0;
    analyse();
  }
  last_in_ = in;
  Vec6 x = in;
  for (Notch& n : notches_) {
    if (n.active) x = n.section.step(x);
  }
  return x;
}

}  // namespace diekf
