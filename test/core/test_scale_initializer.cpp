// ScaleInitializer (src/core/scale_initializer.h, docs/algorithm.md section 7.1): the batch start-up of the
// distance, on an analytic motion over a tilted plane with a turning camera.
#include <gtest/gtest.h>

#include <cmath>

#include "../../src/core/scale_initializer.h"
#include "diekf/state.h"

namespace diekf {
namespace {

constexpr double kG0 = 9.81;

/// World W: plane z = 0 tilted (normal n_W), camera above it. The camera turns about its z axis at a constant rate
/// and moves with p(t) = p0 + A sin(2 pi f t) (per axis) once `t_move_s` has passed; still before.
struct Flight {
  Vec3 n_W = Vec3(0.05, -0.03, 1.0).normalized();  // plane normal, pointing up (toward the camera)
  Vec3 p0 = Vec3(0.0, 0.0, 0.8);
  Vec3 amp = Vec3(0.15, 0.10, 0.12);                 // m
  Vec3 freq = Vec3(0.7, 0.9, 0.5);                   // Hz
  double yaw_rate = 0.3;                             // rad/s about the camera's z
  double t_move_s = 1.0;

  // R_WC: camera looking down (C z = -W z), turned by the yaw.
  Mat3 R_WC(double t) const {
    Mat3 down;
    down << 1, 0, 0, 0, -1, 0, 0, 0, -1;
    return down * expSO3(Vec3(0, 0, yaw_rate * t));
  }
  double tau(double t) const { return std::max(0.0, t - t_move_s); }
  Vec3 p(double t) const {
    Vec3 r;
    for (int i = 0; i < 3; ++i) r(i) = p0(i) + amp(i) * std::sin(2 * M_PI * freq(i) * tau(t));
    return r;
  }
  Vec3 v_W(double t) const {
    Vec3 r = Vec3::Zero();
    if (t < t_move_s) return r;
    for (int i = 0; i < 3; ++i) r(i) = amp(i) * 2 * M_PI * freq(i) * std::cos(2 * M_PI * freq(i) * tau(t));
    return r;
  }
  Vec3 a_W(double t) const {
    Vec3 r = Vec3::Zero();
    if (t < t_move_s) return r;
    for (int i = 0; i < 3; ++i) {
      const double w = 2 * M_PI * freq(i);
      r(i) = -amp(i) * w * w * std::sin(w * tau(t));
    }
    return r;
  }
  double d(double t) const { return n_W.dot(p(t)); }  // distance to the plane through the origin
  /// The filter's state as the images and a converged filter would give it (alpha held at `alpha_f`).
  State state(double t, double alpha_f, const Vec3& g_error_rad) const {
    const Mat3 RT = R_WC(t).transpose();
    State x;
    x.alpha = alpha_f;
    x.vartheta = RT * v_W(t) / d(t);
    x.mu = UnitVector(RT * (-n_W));
    x.g = UnitVector(expSO3(g_error_rad) * (RT * Vec3(0, 0, -1)));
    return x;
  }
  /// The filtered IMU at t (specific force and rate in C).
  ImuSample imu(double t) const {
    ImuSample s;
    s.t_s = t;
    const Mat3 RT = R_WC(t).transpose();
    s.accel_mps2 = RT * (a_W(t) - kG0 * Vec3(0, 0, -1));
    s.gyro_radps = Vec3(0, 0, yaw_rate);
    return s;
  }
};

ErrorCov filterCovariance(double sigma_vartheta) {
  ErrorCov P = ErrorCov::Identity() * 1e-4;
  P(ErrIdx::kAlpha, ErrIdx::kAlpha) = 9.0;
  P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) = Mat3::Identity() * sigma_vartheta * sigma_vartheta;
  P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = Eigen::Matrix2d::Identity() * 0.02 * 0.02;
  P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa) = Mat3::Identity() * 0.05 * 0.05;
  return P;
}

/// Runs the initializer over the flight at 30 Hz until it accepts (or `until_s`); returns the time of acceptance
/// (< 0 if none) with the accepted distance and the true one.
double run(const Flight& f, internal::ScaleInitializer* init, const Vec3& g_error_rad, double until_s, double* d_est,
           double* sigma, double* d_true) {
  init->reset();
  const ErrorCov P = filterCovariance(0.01);
  double t_prev = 0.0;
  for (int k = 1; k * (1.0 / 30.0) <= until_s; ++k) {
    const double t = k / 30.0;
    const State x = f.state(t, 3.0, g_error_rad);
    init->integrate(t_prev, t, x, [&f](double tt) { return f.imu(tt); });
    t_prev = t;
    if (init->addFrame(t, x, P)) {
      *d_est = init->distance();
      *sigma = init->sigmaDistance();
      *d_true = f.d(t);
      return t;
    }
  }
  return -1.0;
}

internal::ScaleInitializer::Config config() {
  internal::ScaleInitializer::Config cfg;
  cfg.gravity_mps2 = kG0;
  return cfg;
}

TEST(ScaleInitializer, WaitsForMotionThenSolvesTheDistance) {
  Flight f;
  const internal::ScaleInitializer::Config cfg = config();
  internal::ScaleInitializer init;
  init.configure(cfg);
  init.reset();
  // Still: alpha held, nothing collected.
  const ErrorCov P = filterCovariance(0.01);
  for (int k = 1; k < 25; ++k) {
    EXPECT_FALSE(init.addFrame(k / 30.0, f.state(k / 30.0, 3.0, Vec3::Zero()), P));
    EXPECT_TRUE(init.holdsAlpha());
    EXPECT_EQ(init.phase(), internal::ScaleInitializer::Phase::kWaiting);
  }
  double d = 0, sigma = 0, truth = 0;
  const double t = run(f, &init, Vec3::Zero(), 5.0, &d, &sigma, &truth);
  ASSERT_GT(t, f.t_move_s + cfg.window_s - 1e-9) << "accepted before a window of motion";
  EXPECT_LT(t, f.t_move_s + cfg.window_s + 0.5);
  EXPECT_EQ(init.phase(), internal::ScaleInitializer::Phase::kDone);
  EXPECT_FALSE(init.holdsAlpha());
  EXPECT_LT(sigma, cfg.max_relative_sigma * d);
  EXPECT_NEAR(d, truth, 0.01 * truth) << "sigma " << sigma;  // exact data: the distance itself
}

TEST(ScaleInitializer, GravityTiltIsAbsorbedWithinItsSigma) {
  // The filter's gravity 1 deg off: the constant acceleration error c takes it.
  Flight f;
  const internal::ScaleInitializer::Config cfg = config();
  internal::ScaleInitializer init;
  init.configure(cfg);
  double d = 0, sigma = 0, truth = 0;
  const double t = run(f, &init, Vec3(0.0175, 0.0, 0.0), 5.0, &d, &sigma, &truth);
  ASSERT_GT(t, 0.0);
  EXPECT_LT(std::abs(d - truth), 3.0 * sigma) << d << " vs " << truth << " sigma " << sigma;
  EXPECT_LT(std::abs(d - truth), 0.05 * truth);
}

TEST(ScaleInitializer, TheImagesOwnVarthetaAtTheIntervalMidpointGivesTheDistance) {
  // The rows from the image's own measurement of vartheta, taken at the midpoint of the frame interval (half a
  // frame before the frame's time, as the update measures it), while the filter's state at the frame's time is
  // wrong (its vartheta smoothed toward zero): the rows are placed at the measurement's time.
  Flight f;
  const internal::ScaleInitializer::Config cfg = config();
  internal::ScaleInitializer init;
  init.configure(cfg);
  init.reset();
  const ErrorCov P = filterCovariance(0.01);
  const double dt = 1.0 / 30.0;
  double t_prev = 0.0, d = -1.0, sigma = 0.0, truth = 0.0;
  for (int k = 1; k * dt <= 5.0 && d < 0.0; ++k) {
    const double t = k * dt, t_mid = t - 0.5 * dt;
    State x = f.state(t, 3.0, Vec3::Zero());
    // The motion test (waiting) reads the filter's vartheta; once collecting, the filter's is 30 % short.
    if (init.phase() != internal::ScaleInitializer::Phase::kWaiting) x.vartheta *= 0.7;
    init.integrate(t_prev, t, x, [&f](double tt) { return f.imu(tt); });
    t_prev = t;
    internal::ScaleInitializer::ImageVartheta image;
    image.vartheta = f.state(t_mid, 3.0, Vec3::Zero()).vartheta;
    image.cov = Mat3::Identity() * 1e-4;
    image.lag_s = t - t_mid;  // (taken as 0 the batch is accepted later and 15 % off)
    if (init.addFrame(t, x, P, &image)) {
      d = init.distance();
      sigma = init.sigmaDistance();
      truth = f.d(t);
    }
  }
  ASSERT_GT(d, 0.0);
  EXPECT_NEAR(d, truth, 0.01 * truth) << "sigma " << sigma;
}

TEST(ScaleInitializer, GivesUpWithoutAcceleration) {
  // Constant velocity (no acceleration to scale the images' velocity by): no solve is accepted; after the longest
  // window alpha is freed.
  Flight f;
  f.freq = Vec3(0.01, 0.01, 0.01);  // over a few seconds: a straight, constant-speed line
  f.amp = Vec3(3.0, 2.0, 0.5);
  const internal::ScaleInitializer::Config cfg = config();
  internal::ScaleInitializer init;
  init.configure(cfg);
  double d = 0, sigma = 0, truth = 0;
  EXPECT_LT(run(f, &init, Vec3::Zero(), f.t_move_s + cfg.max_window_s + 0.5, &d, &sigma, &truth), 0.0);
  EXPECT_EQ(init.phase(), internal::ScaleInitializer::Phase::kDone);
  EXPECT_FALSE(init.holdsAlpha());
  // finish() frees alpha at once (a warm restart).
  init.reset();
  EXPECT_TRUE(init.holdsAlpha());
  init.finish();
  EXPECT_FALSE(init.holdsAlpha());
}

}  // namespace
}  // namespace diekf
