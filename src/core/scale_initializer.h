// Internal part of the estimator (docs/algorithm.md section 7.1; `init/scale_batch`): the start-up of the
// distance for a camera that sits still before it moves. While the camera does not translate nothing observes
// the distance, and an update that may move `alpha` pulls it toward zero (regression dilution: the regressor
// `alpha x residual acceleration` is noise). So `alpha` is held (not updated) until the images see translation;
// then the distance is solved in one batch from the first second of motion (linear least squares, as
// visual-inertial initialisers do) and fused into the filter as a measurement of `alpha`. Eigen only.
//
// The images give vartheta = v / d and mu, scale-free; d(t) = d_0 rho(t) with ln rho = -integral mu . vartheta
// (d ln alpha / dt = mu . vartheta). With R_j the rotation from the camera frame at the first frame (C_0) to that
// at frame j and Delta_j the specific force (bias removed) integrated in C_0 since the first frame,
//
//   d_0 rho_j R_j^T vartheta_j - v_0 - t_j c = Delta_j + g0 t_j g_0          (3 rows per frame j)
//
// with unknowns d_0, the velocity v_0 at the first frame and c, a constant acceleration error in C_0 (gravity
// direction and accelerometer bias over the short window; prior from the filter's covariance).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "diekf/state.h"
#include "diekf/types.h"

namespace diekf {
namespace internal {

class ScaleInitializer {
 public:
  struct Config {
    double window_s = 1.0;            ///< motion used by the first solve, s
    double max_window_s = 3.0;        ///< longest wait for an accepted solve; then the filter goes on without, s
    double motion_chi2 = 16.27;       ///< vartheta^T P^-1 vartheta above this: translation seen (chi2(3) 99.9 %)
    double max_relative_sigma = 0.1;  ///< a solve is accepted when its 1-sigma of d / d is below this
    double row_spacing_s = 0.1;       ///< frames used as rows at least this far apart (the filtered velocities
                                      ///< of neighbouring frames are not independent), s
    double accel_noise_density = 2e-2;  ///< m/s^2/sqrt(Hz)
    double gravity_mps2 = 9.81;
  };
  enum class Phase { kWaiting, kCollecting, kDone };
  /// The image pair's own measurement of vartheta (UpdateStats::vartheta_image) at lag_s before the frame's
  /// time (the update's state time: the interval's midpoint).
  struct ImageVartheta {
    Vec3 vartheta = Vec3::Zero();  ///< 1/s
    Mat3 cov = Mat3::Zero();
    double lag_s = 0.0;
  };

  void configure(const Config& c) { cfg_ = c; }
  /// A new run: hold alpha and wait for motion.
  void reset();
  /// No start-up wanted (a warm restart from a known distance, or disabled): alpha is free from now on.
  void finish() { phase_ = Phase::kDone; }
  Phase phase() const { return phase_; }
  bool holdsAlpha() const { return phase_ == Phase::kWaiting; }

  /// The filtered IMU over (t0, t1], in C: the rotation and the specific force are integrated while collecting
  /// (biases of `x` removed). `sample(t)` returns the filtered sample at t.
  template <class SampleAt>
  void integrate(double t0_s, double t1_s, const State& x, const SampleAt& sample) {
    if (phase_ != Phase::kCollecting || !(t1_s > t0_s)) return;
    const int n = std::max(1, static_cast<int>(std::ceil((t1_s - t0_s) / 0.002)));
    const double dt = (t1_s - t0_s) / n;
    for (int i = 0; i < n; ++i) {
      const ImuSample s = sample(t0_s + (i + 0.5) * dt);
      step(dt, s.accel_mps2 - x.b_a, s.gyro_radps - x.b_w);
    }
  }

  /// After the image update at t_s (the IMU integrated up to t_s). Waiting: starts collecting once vartheta is
  /// significant. Collecting: records the frame and, once the window is long enough, solves. Returns true when
  /// a solve was just accepted (distance(), sigmaDistance()); the phase is then kDone. With `image` the rows
  /// take the image's own vartheta (at its time) instead of the filter's, whose prediction smooths it.
  bool addFrame(double t_s, const State& x, const ErrorCov& P, const ImageVartheta* image = nullptr);

  /// The solved distance at the last frame and its 1-sigma, m (valid after addFrame returned true).
  double distance() const { return distance_m_; }
  double sigmaDistance() const { return sigma_distance_m_; }

 private:
  struct Row {
    double t_s = 0.0;        // since the first frame
    Vec3 a = Vec3::Zero();   // rho_j R_j^T vartheta_j, the column of d_0
    double var_a = 0.0;      // variance of each axis of it (the filter's vartheta)
    Vec3 delta = Vec3::Zero();   // Delta_j
  };
  void step(double dt, const Vec3& accel, const Vec3& gyro);
  bool solve();

  Config cfg_;
  Phase phase_ = Phase::kWaiting;
  double t_first_s_ = 0.0;
  Mat3 R_ = Mat3::Identity();  // C_0 -> C(t)
  Vec3 delta_ = Vec3::Zero();   // integral of R^T a
  Vec3 last_accel_C0_ = Vec3::Zero();  // the last step's specific force in C_0, m/s^2
  Vec3 last_gyro_ = Vec3::Zero();      // the last step's rate, rad/s
  Vec3 g_first_ = Vec3::Zero(); // gravity direction in C_0 at the first frame
  double var_c_ = 0.0;         // prior variance of each axis of c
  std::vector<Row> rows_;
  double log_rho_ = 0.0;       // ln d(t) / d_0 = -integral of mu . vartheta, at t_last_s_
  double s_last_ = 0.0;        // mu . vartheta at the last frame, 1/s
  double t_last_s_ = 0.0;      // time of the last measurement of vartheta
  double d0_m_ = 0.0, sigma_d0_m_ = 0.0;  // d_0 and its 1-sigma
  double distance_m_ = 0.0, sigma_distance_m_ = 0.0;
};

}  // namespace internal
}  // namespace diekf
