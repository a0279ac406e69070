// The camera's frame clock fitted to jittered image stamps (src/core/frame_clock.h; docs/algorithm.md section
// 3.6, "Jittered image stamps"): exact stamps pass unchanged, host-arrival delays are removed but for their mean,
// dropped frames, a single long delay, a change of frame rate and a jump back are handled.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "../../src/core/frame_clock.h"

namespace diekf {
namespace {

using internal::FrameClock;

constexpr double kStart = 1600000000.0;  // s, a bag's stamps

struct Frames {
  std::vector<double> capture;  // true capture times, s
  std::vector<double> stamp;    // their stamps, s
};

/// Frames at `rate_hz` for `n` periods (a share `drop` of them dropped), stamped on arrival: delayed by
/// |N(0, jitter)|.
Frames arrivals(double rate_hz, int n, double jitter_s, double drop, unsigned seed, double t0 = kStart) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  Frames f;
  for (int k = 0; k < n; ++k) {
    const double delay = jitter_s * std::abs(normal(rng));
    if (uni(rng) < drop) continue;
    const double t = t0 + k / rate_hz;
    f.capture.push_back(t);
    f.stamp.push_back(std::max(t + delay, f.stamp.empty() ? 0.0 : f.stamp.back() + 5e-4));
  }
  return f;
}

TEST(FrameClock, ExactStampsPassUnchanged) {
  FrameClock clock(64);
  for (int k = 0; k < 300; ++k) {
    const double t = kStart + k / 30.0;
    EXPECT_EQ(clock.frameTime(t), t) << k;
  }
  EXPECT_TRUE(clock.fitted());
  EXPECT_LT(clock.jitter_s(), 1e-6);
}

TEST(FrameClock, ArrivalDelaysRemovedButForTheirMean) {
  const double jitter = 0.003;                      // s
  const double mean_delay = jitter * std::sqrt(2.0 / M_PI);  // of |N(0, jitter)|
  const Frames f = arrivals(60.0, 1200, jitter, 0.05, 3);
  FrameClock clock(64);
  double raw2 = 0.0, out2 = 0.0, last = -1.0;
  int n = 0;
  for (size_t i = 0; i < f.stamp.size(); ++i) {
    const double out = clock.frameTime(f.stamp[i]);
    EXPECT_GT(out, last) << i;  // in order
    last = out;
    if (i < 64) continue;       // the first window
    EXPECT_TRUE(clock.fitted()) << i;
    raw2 += std::pow(f.stamp[i] - f.capture[i] - mean_delay, 2);
    out2 += std::pow(out - f.capture[i] - mean_delay, 2);
    ++n;
  }
  ASSERT_GT(n, 1000);
  const double raw_rms = std::sqrt(raw2 / n), out_rms = std::sqrt(out2 / n);
  EXPECT_GT(raw_rms, 0.0015);            // the delays' spread about their mean: 0.6 jitter
  EXPECT_LT(out_rms, 0.3 * raw_rms);     // a line's end over 64 frames: 2 / sqrt(64) of it
  EXPECT_NEAR(clock.jitter_s(), 0.6 * jitter, 0.4 * jitter);
}

TEST(FrameClock, OneLongDelayTakesTheLinesTime) {
  Frames f = arrivals(30.0, 200, 0.001, 0.0, 5);
  f.stamp[150] += 0.02;  // one image 20 ms late (0.6 of a period; still before the next one's stamp)
  FrameClock clock(64);
  for (size_t i = 0; i < f.stamp.size(); ++i) {
    const double out = clock.frameTime(f.stamp[i]);
    if (i >= 100) {
      EXPECT_NEAR(out - f.capture[i], 0.0008, 0.0015) << i;
    }
  }
}

TEST(FrameClock, AChangeOfFrameRateStartsTheClockAgain) {
  const Frames a = arrivals(60.0, 300, 0.002, 0.0, 7);
  const Frames b = arrivals(25.0, 300, 0.002, 0.0, 8, a.capture.back() + 0.04);
  FrameClock clock(64);
  for (double t : a.stamp) clock.frameTime(t);
  for (size_t i = 0; i < b.stamp.size(); ++i) {
    const double out = clock.frameTime(b.stamp[i]);
    // Until the change is found (the median of 16 intervals, so within about 10 frames) the frames are read on the
    // old clock's line, within 3/4 of its period and the jitter; then the stamps themselves, fitted again within a window.
    EXPECT_NEAR(out - b.capture[i], 0.0016, i < 12 ? 0.75 / 60.0 + 0.004 : 0.008) << i;
    if (i >= 70) {
      EXPECT_TRUE(clock.fitted()) << i;
      EXPECT_NEAR(out - b.capture[i], 0.0016, 0.0015) << i;
    }
  }
}

TEST(FrameClock, AStampBackInTimeStartsAgain) {
  FrameClock clock(32);
  for (int k = 0; k < 100; ++k) clock.frameTime(kStart + k / 30.0 + 0.002 * (k % 3));
  EXPECT_TRUE(clock.fitted());
  const double back = kStart + 1.0;
  EXPECT_EQ(clock.frameTime(back), back);  // a looping bag: the raw stamp, the clock from here
  EXPECT_FALSE(clock.fitted());
}

}  // namespace
}  // namespace diekf
