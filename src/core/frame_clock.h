// Internal part of the estimator (docs/algorithm.md section 3.6, "Jittered image stamps"): the camera's frame
// clock fitted to the image stamps. A camera captures frames at a steady period; a stamp taken when the image
// arrives at a host (USB cameras, many drivers) adds a varying delay of a few ms. Over the gyro's interval
// between two images such a delay is a rotation error of rate x delay that the update takes for translation
// (a 3 ms jitter made the webcam-like render's distance RMSE 0.68 -> 4.79 cm). The clock fits the line
// t = a + T k to the last frames' stamps (k: the frame count, dropped frames counted from the period), robustly
// (the largest delays left out), and gives each frame the line's time; the mean delay stays in the stamps, a
// constant the time offset's state takes.
#pragma once

#include <cstddef>

#include "ring.h"

namespace diekf {
namespace internal {

class FrameClock {
 public:
  /// `window_frames` (8-128): frames the line is fitted over; the fitted times are used from the 4th frame on.
  /// The line's time at the newest frame scatters by about 2 / sqrt(window) of the stamps' own scatter.
  explicit FrameClock(int window_frames = 128);

  /// The time for the frame stamped `t_s` (stamps in increasing order; an earlier or equal stamp starts the
  /// clock again): the fitted line's time once enough frames agree with a steady period, else `t_s` itself.
  /// A stamp within 1 us of the line is returned as it is (hardware-synchronised cameras pass unchanged).
  double frameTime(double t_s);
  /// Forgets every frame (after a restart or a jump of the stamps).
  void reset();

  /// The last frame's stamp less its fitted time, s (0 while not fitted).
  double lastDelay_s() const { return last_delay_s_; }
  /// Robust 1-sigma of the stamps about the line over the window, s (0 while not fitted).
  double jitter_s() const { return jitter_s_; }
  /// Whether the last frame's time came from the line.
  bool fitted() const { return fitted_; }

 private:
  struct Frame {
    double k = 0.0;  // frame count (from the oldest frame until a line is accepted, then from the line)
    double t = 0.0;  // stamp less the first stamp, s
  };
  /// Starts the clock again at the frame stamped t_s (the times given out stay in order); returns t_s.
  double restartAt(double t_s);
  /// Least-squares line over the frames with weight (|residual| <= limit, all when limit < 0): t = a + b k.
  bool fitLine(double limit, double* a, double* b) const;
  /// Robust 1-sigma of the frames about the line t = a + b k: 1.4826 times the median absolute residual.
  double robustSigma(double a, double b);

  static constexpr int kMaxWindow = 128;

  Ring<Frame> frames_;
  double t0_ = 0.0;        // first stamp of the clock, s (times are kept relative to it)
  double period_s_ = 0.0;  // the frame period of the last accepted line, s (0: none yet)
  double line_a_ = 0.0;    // that line's time at count 0, s (relative to t0_)
  double last_out_s_ = -1e300;  // the last time given out, s (absolute)
  int outliers_in_row_ = 0;
  double last_delay_s_ = 0.0;
  double jitter_s_ = 0.0;
  bool fitted_ = false;
  double residuals_[kMaxWindow];  // scratch of the medians
};

}  // namespace internal
}  // namespace diekf
