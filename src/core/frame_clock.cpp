#include "frame_clock.h"

#include <algorithm>
#include <cmath>

namespace diekf {
namespace internal {

namespace {
constexpr double kExactS = 1e-6;        // stamps this close to the line are taken as they are, s
constexpr double kMinJitterS = 2e-4;    // floor of the robust scale when telling a real change from a delay, s
constexpr double kMaxJitterS = 0.02;    // a fit scattered more than this is not a steady clock, s
constexpr double kGapPeriods = 30.0;    // a gap of more periods than this starts the clock again
constexpr int kMinFitFrames = 4;        // frames before the line is used (its end then scatters by 0.84 of the stamps)
}  // namespace

FrameClock::FrameClock(int window_frames)
    : frames_(static_cast<size_t>(std::clamp(window_frames, 8, kMaxWindow))) {}

void FrameClock::reset() {
  frames_.clear();
  period_s_ = 0.0;
  outliers_in_row_ = 0;
  last_delay_s_ = 0.0;
  jitter_s_ = 0.0;
  fitted_ = false;
  last_out_s_ = -HUGE_VAL;
}

double FrameClock::restartAt(double t_s) {
  const double keep = last_out_s_;  // the order of the times given out holds across the restart
  reset();
  last_out_s_ = keep;
  t0_ = t_s;
  frames_.push({0.0, 0.0});
  return t_s;
}

bool FrameClock::fitLine(double limit, double* a, double* b) const {
  double n = 0.0, sk = 0.0, st = 0.0;
  for (size_t i = 0; i < frames_.size(); ++i) {
    const Frame& f = frames_[i];
    if (limit >= 0.0 && std::abs(f.t - (*a + *b * f.k)) > limit) continue;
    n += 1.0;
    sk += f.k;
    st += f.t;
  }
  if (n < 3.0) return false;
  const double km = sk / n, tm = st / n;
  double skk = 0.0, skt = 0.0;
  for (size_t i = 0; i < frames_.size(); ++i) {
    const Frame& f = frames_[i];
    if (limit >= 0.0 && std::abs(f.t - (*a + *b * f.k)) > limit) continue;
    skk += (f.k - km) * (f.k - km);
    skt += (f.k - km) * (f.t - tm);
  }
  if (!(skk > 0.0)) return false;
  *b = skt / skk;
  *a = tm - *b * km;
  return std::isfinite(*a) && std::isfinite(*b) && *b > 0.0;
}

double FrameClock::robustSigma(double a, double b) {
  const size_t n = frames_.size();
  for (size_t i = 0; i < n; ++i) residuals_[i] = std::abs(frames_[i].t - (a + b * frames_[i].k));
  std::nth_element(residuals_, residuals_ + n / 2, residuals_ + n);
  return 1.4826 * residuals_[n / 2];
}

double FrameClock::frameTime(double t_s) {
  fitted_ = false;
  last_delay_s_ = 0.0;
  if (!std::isfinite(t_s)) return t_s;
  if (!frames_.empty() && !(t_s - t0_ > frames_.back().t)) reset();  // not after the last stamp: start again
  if (frames_.empty()) t0_ = t_s;
  const double t = t_s - t0_;
  const auto out = [&](double time_s) {
    const double v = std::max(time_s, last_out_s_ + kExactS);  // the frames' order is kept
    last_out_s_ = v;
    return v;
  };
  // A long gap: the count across it is not to be trusted.
  if (!frames_.empty() && period_s_ > 0.0 && t - frames_.back().t > kGapPeriods * period_s_) return out(restartAt(t_s));
  // The frame's count: from the last accepted line, else one more than the last (counts are redone from the median
  // interval until a line is accepted). The line runs through the stamps' mean delay and delays are one-sided, so
  // a stamp up to 3/4 of a period above the line or 1/4 below it counts as that frame.
  double k = frames_.empty() ? 0.0 : frames_.back().k + 1.0;
  if (period_s_ > 0.0 && !frames_.empty()) k = std::max(k, std::round((t - line_a_) / period_s_ - 0.25));
  frames_.push({k, t});
  const size_t n = frames_.size();
  if (n < 4) return out(t_s);

  // Another frame rate (a camera switching modes, a restarted driver): the median of the last 16 intervals is no
  // longer near a whole number of periods. Start the clock again from this frame. (A rate halved is counted as
  // every other frame dropped: the line's times stay right. A small change is caught by the residuals below.)
  if (period_s_ > 0.0 && n >= 17) {
    for (size_t i = 0; i < 16; ++i) residuals_[i] = frames_[n - 16 + i].t - frames_[n - 17 + i].t;
    std::nth_element(residuals_, residuals_ + 8, residuals_ + 16);
    const double ratio = residuals_[8] / period_s_;
    if (std::abs(ratio - std::round(ratio)) > 0.3 || ratio < 0.7) {
      return out(restartAt(t_s));
    }
  }
  // The period: the last accepted fit's slope, else the median interval (robust to delays and dropped frames).
  double T = period_s_;
  if (!(T > 0.0)) {
    for (size_t i = 1; i < n; ++i) residuals_[i - 1] = frames_[i].t - frames_[i - 1].t;
    std::nth_element(residuals_, residuals_ + (n - 1) / 2, residuals_ + (n - 1));
    T = residuals_[(n - 1) / 2];
    if (!(T > 0.0)) return out(t_s);
  }
  // Until a line is accepted, the counts from the median interval: a dropped frame is a whole period more.
  if (!(period_s_ > 0.0)) {
    frames_[0].k = 0.0;
    for (size_t i = 1; i < n; ++i)
      frames_[i].k = frames_[i - 1].k + std::max(1.0, std::round((frames_[i].t - frames_[i - 1].t) / T));
  }

  // Fit, then again without the frames beyond 3 robust sigmas (the largest delays).
  double a = 0.0, b = T;
  if (!fitLine(-1.0, &a, &b)) return out(t_s);
  const double sigma = std::max(kMinJitterS, robustSigma(a, b));
  if (!fitLine(3.0 * sigma, &a, &b)) return out(t_s);
  const double jitter = robustSigma(a, b);

  // A real change of the camera's timing (another frame rate, a restarted driver) leaves a run of frames off the
  // line on one side: start the clock again from this frame. A single far stamp is a long delay: the line's time.
  const double line_t = a + b * frames_.back().k;
  const double delay = t - line_t;
  const bool off_line = std::abs(delay) > std::max(6.0 * std::max(kMinJitterS, jitter), 0.25 * b);
  outliers_in_row_ = off_line ? outliers_in_row_ + 1 : 0;
  if (outliers_in_row_ >= 3) {
    return out(restartAt(t_s));
  }
  if (static_cast<int>(n) < kMinFitFrames || jitter > kMaxJitterS || std::abs(b - T) > 0.1 * T) {
    period_s_ = 0.0;
    return out(t_s);
  }
  period_s_ = b;
  line_a_ = a;
  jitter_s_ = jitter;
  last_delay_s_ = delay;
  fitted_ = true;
  if (std::abs(delay) < kExactS) return out(t_s);
  return out(t0_ + line_t);
}

}  // namespace internal
}  // namespace diekf
