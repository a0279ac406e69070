// One second-order IIR section on six channels (specific force and body rate), transposed direct form II:
//   y = b0 x + z1,  z1' = b1 x - a1 y + z2,  z2' = b2 x - a2 y   (a0 = 1).
// Shared by the IMU low-pass (ImuPreprocessor: Butterworth sections) and the vibration notches (VibrationNotch).
// Fixed size, no allocation.
#pragma once

#include <Eigen/Core>

namespace diekf {

struct Biquad6 {
  using Vec6 = Eigen::Matrix<double, 6, 1>;

  double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0;  // normalised (a0 = 1)
  Vec6 z1 = Vec6::Zero(), z2 = Vec6::Zero();      // memory

  /// One sample through the section.
  Vec6 step(const Vec6& x) {
    const Vec6 y = b0 * x + z1;
    z1 = b1 * x - a1 * y + z2;
    z2 = b2 * x - a2 * y;
    return y;
  }
  /// The memory of the steady state in which the constant input x gives the output y (y = dcGain() x for the
  /// section's own steady state; a notch passes 0 Hz at exactly 1, y = x): no start-up transient from it.
  void settleAt(const Vec6& x, const Vec6& y) {
    z1 = y - b0 * x;
    z2 = b2 * x - a2 * y;
  }
  /// Forgets the memory.
  void clear() {
    z1.setZero();
    z2.setZero();
  }
  /// Gain at 0 Hz, B(1) / A(1).
  double dcGain() const { return (b0 + b1 + b2) / (1.0 + a1 + a2); }
  /// Group delay at 0 Hz, samples: sum n b_n / sum b_n - sum n a_n / sum a_n.
  double dcDelaySamples() const { return (b1 + 2.0 * b2) / (b0 + b1 + b2) - (a1 + 2.0 * a2) / (1.0 + a1 + a2); }
};

}  // namespace diekf
