// Prediction: Jacobians against central finite differences with the state's own [+]/[-], mean propagation in
// simple motions, and covariance behaviour.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <Eigen/Cholesky>

#include "diekf/prediction.h"

namespace diekf {
namespace {

constexpr double kG0 = 9.81;  // m/s^2

struct Case {
  State x;
  Vec3 accel_C;  // m/s^2
  Vec3 gyro_C;   // rad/s
  double dt_s;
};

Case randomCase(std::mt19937& rng, double dt_s, double rate_scale) {
  std::normal_distribution<double> n(0.0, 1.0);
  Case c;
  c.x.alpha = 0.3 + std::abs(n(rng));
  c.x.vartheta = Vec3(n(rng), n(rng), n(rng));
  c.x.mu = UnitVector(Vec3(0.3 * n(rng), 0.3 * n(rng), 1.0));
  c.x.g = UnitVector(Vec3(0.3 * n(rng), 0.3 * n(rng), 1.0));
  c.x.b_a = 0.2 * Vec3(n(rng), n(rng), n(rng));
  c.x.b_w = 0.05 * Vec3(n(rng), n(rng), n(rng));
  c.accel_C = -kG0 * c.x.g.vector() + Vec3(n(rng), n(rng), n(rng));
  c.gyro_C = rate_scale * Vec3(n(rng), n(rng), n(rng));
  c.dt_s = dt_s;
  return c;
}

/// A random symmetric positive-definite error covariance.
ErrorCov randomCovariance(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Matrix<double, kErrorDim, kErrorDim> A;
  for (int i = 0; i < kErrorDim; ++i)
    for (int j = 0; j < kErrorDim; ++j) A(i, j) = n(rng);
  return A * A.transpose() * 0.01 + ErrorCov::Identity() * 1e-3;
}

/// f(x, n) exactly as documented in prediction.h (NoiseIdx).
State predictWithNoise(const Case& c, const NoiseVec& n) {
  State y = predictState(c.x, c.accel_C + n.segment<3>(NoiseIdx::kAccel), c.gyro_C + n.segment<3>(NoiseIdx::kGyro),
                         c.dt_s, kG0);
  ErrorVec inc = ErrorVec::Zero();
  inc(ErrIdx::kAlpha) = n(NoiseIdx::kAlpha);
  inc.segment<3>(ErrIdx::kVartheta) = n.segment<3>(NoiseIdx::kVartheta);
  inc.segment<2>(ErrIdx::kMu) = n.segment<2>(NoiseIdx::kMu);
  inc.segment<2>(ErrIdx::kG) = n.segment<2>(NoiseIdx::kG);
  inc.segment<3>(ErrIdx::kBa) = n.segment<3>(NoiseIdx::kBaWalk);
  inc.segment<3>(ErrIdx::kBw) = n.segment<3>(NoiseIdx::kBwWalk);
  return y.boxplus(inc);
}

ErrorCov numericF(const Case& c, double h) {
  const State f0 = predictState(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0);
  ErrorCov F;
  for (int i = 0; i < kErrorDim; ++i) {
    ErrorVec e = ErrorVec::Zero();
    e(i) = h;
    const State fp = predictState(c.x.boxplus(e), c.accel_C, c.gyro_C, c.dt_s, kG0);
    const State fm = predictState(c.x.boxplus(-e), c.accel_C, c.gyro_C, c.dt_s, kG0);
    F.col(i) = (fp.boxminus(f0) - fm.boxminus(f0)) / (2.0 * h);
  }
  return F;
}

NoiseJacobian numericG(const Case& c, double h) {
  const State f0 = predictWithNoise(c, NoiseVec::Zero());
  NoiseJacobian G;
  for (int i = 0; i < kNoiseDim; ++i) {
    NoiseVec e = NoiseVec::Zero();
    e(i) = h;
    G.col(i) = (predictWithNoise(c, e).boxminus(f0) - predictWithNoise(c, -e).boxminus(f0)) / (2.0 * h);
  }
  return G;
}

template <typename A, typename B>
double relativeMaxError(const A& analytic, const B& numeric) {
  return (analytic - numeric).cwiseAbs().maxCoeff() / std::max(1.0, analytic.cwiseAbs().maxCoeff());
}

TEST(Prediction, JacobiansMatchFiniteDifferences) {
  std::mt19937 rng(11);
  struct Setting {
    double dt_s, rate_scale;
  };
  const Setting settings[] = {{0.01, 1.0}, {0.01, 0.01}, {0.05, 3.0}, {0.002, 0.5}};
  for (const Setting& s : settings) {
    for (int trial = 0; trial < 8; ++trial) {
      const Case c = randomCase(rng, s.dt_s, s.rate_scale);
      ErrorCov F;
      NoiseJacobian G;
      predictionJacobians(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0, &F, &G);
      const ErrorCov Fn = numericF(c, 1e-6);
      const NoiseJacobian Gn = numericG(c, 1e-6);
      EXPECT_LT(relativeMaxError(F, Fn), 1e-6) << "dt " << s.dt_s << " trial " << trial << "\nF\n"
                                               << F << "\nFn\n" << Fn;
      EXPECT_LT(relativeMaxError(G, Gn), 1e-6) << "dt " << s.dt_s << " trial " << trial << "\nG\n"
                                               << G << "\nGn\n" << Gn;
      // The S^2 blocks are the error-prone ones: check them on their own scale as well.
      EXPECT_LT((F.block<4, 4>(ErrIdx::kMu, ErrIdx::kMu) - Fn.block<4, 4>(ErrIdx::kMu, ErrIdx::kMu)).norm(), 1e-7);
      EXPECT_LT((F.block<4, 3>(ErrIdx::kMu, ErrIdx::kBw) - Fn.block<4, 3>(ErrIdx::kMu, ErrIdx::kBw)).norm(), 1e-8);
    }
  }
}

TEST(Prediction, JacobiansAtMuEqualGAndUntiltedCamera) {
  // Degenerate-looking but common configuration: mu = g = e_z (hover over level ground).
  Case c;
  c.x.mu = UnitVector(Vec3(0, 0, 1));
  c.x.g = UnitVector(Vec3(0, 0, 1));
  c.x.vartheta = Vec3(0.1, -0.2, 0.05);
  c.x.b_w = Vec3(0.01, 0.0, -0.02);
  c.accel_C = Vec3(0.1, 0.2, -9.7);
  c.gyro_C = Vec3(0.3, -0.1, 0.2);
  c.dt_s = 0.01;
  ErrorCov F;
  NoiseJacobian G;
  predictionJacobians(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0, &F, &G);
  EXPECT_LT(relativeMaxError(F, numericF(c, 1e-6)), 1e-6);
  EXPECT_LT(relativeMaxError(G, numericG(c, 1e-6)), 1e-6);
  // The gyro-noise columns are minus the gyro-bias columns (outside the bias rows, where F has its identity).
  EXPECT_LT((G.block<ErrIdx::kBa, 3>(0, NoiseIdx::kGyro) + F.block<ErrIdx::kBa, 3>(0, ErrIdx::kBw)).norm(), 1e-15);
  EXPECT_TRUE((G.block<6, 3>(ErrIdx::kBa, NoiseIdx::kGyro).isZero()));
}

// predict()'s column_accel_C (docs/algorithm.md section 2.1, "The distance's column"): the acceleration the
// distance's column of F uses. Given the step's own (a - b_a + g0 g, no rotation over the step so that both forms
// agree exactly) it is predict() without it; given another, only the covariance of the distance and vartheta
// rows changes (the rows F's distance column reaches), and the mean not at all.
// A direction of the error state carried by the dynamics (the focal length's sensitivity, FrameResult::
// focal_sensitivity): predict's optional vector becomes F s, F the step's Jacobian (tested against finite
// differences above), and the mean and the covariance are those of the step without it.
TEST(Prediction, ASensitivityIsCarriedByTheStepsJacobian) {
  std::mt19937 rng(23);
  std::normal_distribution<double> n(0.0, 1.0);
  ImuParams imu;
  imu.gravity_mps2 = kG0;
  ProcessNoiseParams proc;
  for (int trial = 0; trial < 5; ++trial) {
    const Case c = randomCase(rng, 0.01, 0.0);
    const ErrorCov P0 = randomCovariance(rng);
    ErrorVec s0;
    for (int i = 0; i < kErrorDim; ++i) s0(i) = n(rng);
    ErrorCov F;
    NoiseJacobian G;
    predictionJacobians(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0, &F, &G);
    State x_with = c.x, x_without = c.x;
    ErrorCov P_with = P0, P_without = P0;
    ErrorVec s = s0;
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x_with, &P_with, nullptr, &s);
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x_without, &P_without);
    EXPECT_LT((s - F * s0).cwiseAbs().maxCoeff(), 1e-12 * (1.0 + s0.cwiseAbs().maxCoeff()));
    EXPECT_EQ(P_with, P_without);
    EXPECT_LT(x_with.boxminus(x_without).norm(), 1e-14);
  }
}

TEST(Prediction, ColumnAccelerationOnlyChangesTheDistanceColumn) {
  std::mt19937 rng(17);
  std::normal_distribution<double> n(0.0, 1.0);
  ImuParams imu;
  imu.gravity_mps2 = kG0;
  ProcessNoiseParams proc;
  for (int trial = 0; trial < 5; ++trial) {
    Case c = randomCase(rng, 0.01, 0.0);
    c.x.b_w.setZero();  // no rotation
    const ErrorCov P0 = randomCovariance(rng);
    State x_plain = c.x, x_own = c.x, x_other = c.x;
    ErrorCov P_plain = P0, P_own = P0, P_other = P0;
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x_plain, &P_plain);
    const Vec3 own = c.accel_C - c.x.b_a + kG0 * c.x.g.vector();
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x_own, &P_own, &own);
    EXPECT_LT((P_own - P_plain).cwiseAbs().maxCoeff(), 1e-13 * P_plain.cwiseAbs().maxCoeff());
    const Vec3 other = own + Vec3(n(rng), n(rng), n(rng));
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x_other, &P_other, &other);
    // (Equal up to rounding: the compiler may fuse the mean's multiply-adds differently in the two calls, as GCC does
    // for 32-bit ARM.)
    EXPECT_LT(x_other.boxminus(x_plain).norm(), 1e-14) << "the mean is the readings'";
    // Only F's distance column differs, and it is nonzero in the distance and vartheta rows only: the other
    // entries of P' are those of the own column.
    const ErrorCov D = P_other - P_own;
    for (int i = ErrIdx::kVartheta + 3; i < kErrorDim; ++i) {
      for (int j = ErrIdx::kVartheta + 3; j < kErrorDim; ++j) {
        EXPECT_EQ(D(i, j), 0.0) << i << "," << j;
      }
    }
    EXPECT_GT((D.block<4, 4>(0, 0).cwiseAbs().maxCoeff()), 1e-9) << "the distance and vartheta rows did change";
  }
}

TEST(Prediction, HoverKeepsVarthetaZero) {
  // At rest the accelerometer reads -g0 g (1 g "up"); vartheta and alpha must stay constant, for a level and
  // a tilted camera.
  const Vec3 gravity_dirs[] = {Vec3(0, 0, 1), Vec3(0.3, -0.2, 0.93)};
  for (const Vec3& gdir : gravity_dirs) {
    State x;
    x.alpha = 2.0;
    x.mu = UnitVector(gdir);
    x.g = UnitVector(gdir);
    const Vec3 accel = -kG0 * x.g.vector();
    for (int k = 0; k < 1000; ++k) x = predictState(x, accel, Vec3::Zero(), 0.01, kG0);
    EXPECT_LT(x.vartheta.norm(), 1e-12);
    EXPECT_NEAR(x.alpha, 2.0, 1e-12);
    EXPECT_LT((x.g.vector() - gdir.normalized()).norm(), 1e-12);
  }
}

TEST(Prediction, ConstantVelocityMovesDistanceConsistently) {
  // d' = d - (v . mu) dt with v constant (no acceleration, no rotation).
  State x;
  const double d0_m = 2.0;
  const Vec3 v_mps(0.3, -0.2, 0.5);
  x.alpha = 1.0 / d0_m;
  x.vartheta = v_mps * x.alpha;
  x.mu = UnitVector(Vec3(0.2, 0.1, 1.0));
  x.g = x.mu;
  const Vec3 mu = x.mu.vector();
  const Vec3 accel = -kG0 * x.g.vector();  // specific force of unaccelerated motion
  const double dt_s = 1e-3;
  const int steps = 1000;
  for (int k = 0; k < steps; ++k) x = predictState(x, accel, Vec3::Zero(), dt_s, kG0);
  const double d_expected_m = d0_m - v_mps.dot(mu) * dt_s * steps;
  EXPECT_NEAR(x.distance_m(), d_expected_m, 1e-6);  // trapezoid rule on the log-distance rate, O(dt^2)
  EXPECT_LT((x.velocity_mps() - v_mps).norm(), 1e-12);
  EXPECT_LT((x.mu.vector() - mu).norm(), 1e-14);
}

TEST(Prediction, PureRotationTurnsWorldDirectionsBackwards) {
  // Camera yawing at +1 rad/s about its optical axis: a world-fixed direction along x_C ends on -y_C after
  // pi/2 s.
  State x;
  x.mu = UnitVector(Vec3(1, 0, 0));
  x.g = UnitVector(Vec3(0, 1, 0));
  const double dt_s = M_PI / 2.0 / 1000.0;
  for (int k = 0; k < 1000; ++k) x = predictState(x, Vec3::Zero(), Vec3(0, 0, 1), dt_s, kG0);
  EXPECT_LT((x.mu.vector() - Vec3(0, -1, 0)).norm(), 1e-9);
  EXPECT_LT((x.g.vector() - Vec3(1, 0, 0)).norm(), 1e-9);
}

TEST(Prediction, DiscreteNoiseSigmas) {
  ImuParams imu;
  ProcessNoiseParams proc;
  const double dt_s = 0.01;
  const NoiseVec s = discreteNoiseSigmas(imu, proc, dt_s);
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kAccel), imu.accel_noise_density / std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kGyro + 2), imu.gyro_noise_density / std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kBaWalk + 1), imu.accel_random_walk * std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kBwWalk), imu.gyro_random_walk * std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kAlpha), proc.alpha_inv_m_per_sqrt_s * std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kMu + 1), proc.mu_rad_per_sqrt_s * std::sqrt(dt_s));
  EXPECT_DOUBLE_EQ(s(NoiseIdx::kG), proc.g_rad_per_sqrt_s * std::sqrt(dt_s));
  EXPECT_TRUE(discreteNoiseSigmas(imu, proc, 0.0).isZero());
}

TEST(Prediction, NoiseGrowthIndependentOfStepSize) {
  // Starting from P = 0 at hover, 1 s of prediction with dt = 10 ms and dt = 2.5 ms must give nearly the same P.
  ImuParams imu;
  ProcessNoiseParams proc;
  auto run = [&](double dt_s) {
    State x;
    x.alpha = 1.0;
    x.mu = UnitVector(Vec3(0.1, 0, 1));
    x.g = UnitVector(Vec3(0, 0.1, 1));
    x.vartheta = Vec3(0.2, 0.1, -0.1);
    ErrorCov P = ErrorCov::Zero();
    const int steps = static_cast<int>(std::lround(1.0 / dt_s));
    for (int k = 0; k < steps; ++k) predict(-kG0 * x.g.vector(), Vec3(0.1, 0, 0), dt_s, imu, proc, &x, &P);
    return P;
  };
  const ErrorCov P1 = run(0.01);
  const ErrorCov P2 = run(0.0025);
  EXPECT_GT(P1.diagonal().minCoeff(), 0.0);
  EXPECT_LT((P1 - P2).norm(), 0.05 * P1.norm());
  // A zero-length step is a no-op.
  State x;
  ErrorCov P = ErrorCov::Identity();
  predict(Vec3(1, 2, 3), Vec3(1, 0, 0), 0.0, imu, proc, &x, &P);
  EXPECT_TRUE(P.isIdentity());
  EXPECT_DOUBLE_EQ(x.alpha, State().alpha);
}

/// The second-order term of d vartheta/dt = alpha a (ProcessNoiseParams::bilinear_accel_time_s), written out:
/// T dt var(alpha) Cov(a), a = f - b_a + g0 g over the errors of b_a and g (dense, for the tests).
Mat3 bilinearTerm(const State& x, const ErrorCov& P, const ProcessNoiseParams& proc, double dt_s) {
  Eigen::Matrix<double, 3, kErrorDim> J = Eigen::Matrix<double, 3, kErrorDim>::Zero();
  J.block<3, 3>(0, ErrIdx::kBa) = -Mat3::Identity();
  J.block<3, 2>(0, ErrIdx::kG) = kG0 * x.g.M();
  return proc.bilinear_accel_time_s * dt_s * P(ErrIdx::kAlpha, ErrIdx::kAlpha) * (J * P * J.transpose());
}

TEST(Prediction, CovarianceStepEqualsDenseFormula) {
  // predict() exploits the structure of F and G; it must equal F P F^T + G Q G^T computed densely.
  std::mt19937 rng(13);
  ImuParams imu;
  imu.gravity_mps2 = kG0;
  ProcessNoiseParams proc;
  proc.bilinear_accel_time_s = 0.01;  // the optional second-order term too
  for (int trial = 0; trial < 5; ++trial) {
    const Case c = randomCase(rng, 0.01, 1.0);
    const ErrorCov P0 = randomCovariance(rng);
    ErrorCov F;
    NoiseJacobian G;
    predictionJacobians(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0, &F, &G);
    NoiseVec sigma = discreteNoiseSigmas(imu, proc, c.dt_s);
    // Plus the state-dependent model error of the distance dynamics (alpha_rate_noise_sqrt_s).
    sigma(NoiseIdx::kAlpha) = std::hypot(sigma(NoiseIdx::kAlpha),
                                         proc.alpha_rate_noise_sqrt_s * c.x.alpha *
                                             std::abs(c.x.mu.vector().dot(c.x.vartheta)) * std::sqrt(c.dt_s));
    // The distance's increment moves vartheta with alpha (alpha_noise_keeps_velocity).
    G.block<3, 1>(ErrIdx::kVartheta, NoiseIdx::kAlpha) = c.x.vartheta / c.x.alpha;
    ErrorCov expected = F * P0 * F.transpose() + G * sigma.cwiseAbs2().asDiagonal() * G.transpose();
    // The time offset's, readout's and focal scale's random walks (not IMU noises, so not in G).
    expected(ErrIdx::kTd, ErrIdx::kTd) += proc.time_offset_s_per_sqrt_s * proc.time_offset_s_per_sqrt_s * c.dt_s;
    expected(ErrIdx::kRo, ErrIdx::kRo) += proc.readout_s_per_sqrt_s * proc.readout_s_per_sqrt_s * c.dt_s;
    expected(ErrIdx::kFs, ErrIdx::kFs) += proc.focal_scale_per_sqrt_s * proc.focal_scale_per_sqrt_s * c.dt_s;
    expected.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) += bilinearTerm(c.x, P0, proc, c.dt_s);
    State x = c.x;
    ErrorCov P = P0;
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, proc, &x, &P);
    EXPECT_LT((P - expected).cwiseAbs().maxCoeff(), 1e-12 * expected.cwiseAbs().maxCoeff());
    EXPECT_LT(x.boxminus(predictState(c.x, c.accel_C, c.gyro_C, c.dt_s, kG0)).norm(), 1e-15);
  }
}

// The product of the distance's and the acceleration's errors (dropped by the linearisation of alpha a;
// process/bilinear_accel_time_s, off by default) widens vartheta only while both are uncertain: at a start, the
// distance unknown and the tilt (gravity) and the accelerometer bias not yet learned. Without it the images'
// precise "no change of vartheta" at rest meets the column's small acceleration (noise, the tilt's error) and takes
// information on alpha that is not there (docs/algorithm.md section 2.1).
TEST(Prediction, BilinearTermNeedsBothTheDistanceAndTheAccelerationUncertain) {
  std::mt19937 rng(5);
  ImuParams imu;
  imu.gravity_mps2 = kG0;
  ProcessNoiseParams proc;
  proc.bilinear_accel_time_s = 0.01;  // (off by default)
  const Case c = randomCase(rng, 0.01, 1.0);
  auto varthetaBlock = [&](const ErrorCov& P0, const ProcessNoiseParams& pr) {
    State x = c.x;
    ErrorCov P = P0;
    predict(c.accel_C, c.gyro_C, c.dt_s, imu, pr, &x, &P);
    return Mat3(P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta));
  };
  ProcessNoiseParams off = proc;
  off.bilinear_accel_time_s = 0.0;
  // A start: alpha 3 +- 3 1/m, gravity +- 0.1 rad, accelerometer bias +- 0.1 m/s^2.
  ErrorCov P0 = ErrorCov::Identity() * 1e-6;
  P0(ErrIdx::kAlpha, ErrIdx::kAlpha) = 9.0;
  P0.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = Eigen::Matrix2d::Identity() * 0.01;
  P0.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa) = Mat3::Identity() * 0.01;
  const Mat3 added = varthetaBlock(P0, proc) - varthetaBlock(P0, off);
  EXPECT_LT((added - bilinearTerm(c.x, P0, proc, c.dt_s)).cwiseAbs().maxCoeff(), 1e-12);
  // T 0.01 s x dt 0.01 s x 9 (1/m)^2 x (2 x (9.81 x 0.1)^2 + 3 x 0.1^2) (m/s^2)^2: 0.0018 (1/s)^2 in the trace.
  ASSERT_NEAR(c.dt_s, 0.01, 1e-12);
  EXPECT_NEAR(added.trace(), 0.0018 * proc.bilinear_accel_time_s / 0.01, 0.0001);
  // The distance known: nothing.
  ErrorCov P1 = P0;
  P1(ErrIdx::kAlpha, ErrIdx::kAlpha) = 0.0;
  EXPECT_LT((varthetaBlock(P1, proc) - varthetaBlock(P1, off)).cwiseAbs().maxCoeff(), 1e-15);
  // The acceleration known (gravity and bias): nothing.
  ErrorCov P2 = P0;
  P2.block<2, 2>(ErrIdx::kG, ErrIdx::kG).setZero();
  P2.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa).setZero();
  EXPECT_LT((varthetaBlock(P2, proc) - varthetaBlock(P2, off)).cwiseAbs().maxCoeff(), 1e-15);
}

/// One 10 ms prediction step from P = 0 of a camera looking straight down at alpha = 2 /m, gravity along the optical
/// axis and the specific force cancelling it, with the given vartheta: the state after it, P into *P.
State stepAboveLevelGround(const Vec3& vartheta_inv_s, const ImuParams& imu, const ProcessNoiseParams& proc,
                           ErrorCov* P) {
  State x;
  x.alpha = 2.0;
  x.mu = UnitVector(Vec3(0, 0, 1));
  x.g = UnitVector(Vec3(0, 0, 1));
  x.vartheta = vartheta_inv_s;
  P->setZero();
  predict(-kG0 * x.g.vector(), Vec3::Zero(), 0.01, imu, proc, &x, P);
  return x;
}

TEST(Prediction, DistanceRateNoiseGrowsWithVerticalMotionOnly) {
  // The alpha random walk k alpha |mu . vartheta| adds variance in a climb (vartheta along mu), none in level
  // flight (vartheta orthogonal to mu), and none with k = 0.
  ImuParams imu;
  auto alphaVariance = [&](const Vec3& vartheta_inv_s, double k) {
    ProcessNoiseParams proc;
    proc.alpha_rate_noise_sqrt_s = k;
    ErrorCov P;
    stepAboveLevelGround(vartheta_inv_s, imu, proc, &P);
    return P(ErrIdx::kAlpha, ErrIdx::kAlpha);
  };
  const Vec3 climb(0.0, 0.0, 1.5), level(1.5, 0.0, 0.0);
  EXPECT_NEAR(alphaVariance(level, 0.1), alphaVariance(level, 0.0), 1e-15);
  // One 10 ms step of a 1.5 /s climb at alpha = 2: (0.1 * 2 * 1.5)^2 * 0.01 = 9e-4 more.
  EXPECT_NEAR(alphaVariance(climb, 0.1) - alphaVariance(climb, 0.0), 9e-4, 1e-9);
}

TEST(Prediction, DistanceNoiseLeavesTheVelocityUnchanged) {
  // Only the distance's process noise (its random walk and, in a climb, its rate term): the distance's variance
  // grows, the velocity v = vartheta / alpha keeps its (zero) variance; with the noise on alpha alone
  // (alpha_noise_keeps_velocity = false) the velocity's variance grows as (|v| sigma_alpha / alpha)^2.
  ImuParams imu;
  imu.accel_noise_density = imu.gyro_noise_density = imu.accel_random_walk = imu.gyro_random_walk = 0.0;
  auto varianceAfterOneStep = [&](const Vec3& vartheta_inv_s, bool keeps_velocity, double* var_d_m2) {
    ProcessNoiseParams proc;
    proc.vartheta_inv_s_per_sqrt_s = proc.mu_rad_per_sqrt_s = proc.g_rad_per_sqrt_s = 0.0;
    proc.alpha_noise_keeps_velocity = keeps_velocity;
    ErrorCov P;
    const State x = stepAboveLevelGround(vartheta_inv_s, imu, proc, &P);
    *var_d_m2 = std::pow(sigmaDistance_m(x, P), 2);
    return velocityCovariance(x, P).trace();  // (m/s)^2
  };
  const Vec3 level(0.8, -0.3, 0.0), climb(0.8, -0.3, 0.6);
  double var_d = 0.0, var_d_alone = 0.0;
  // Level flight: alpha does not move over the step, so v's variance stays zero to rounding.
  const double var_v = varianceAfterOneStep(level, true, &var_d);
  const double var_v_alone = varianceAfterOneStep(level, false, &var_d_alone);
  EXPECT_GT(var_d, 0.0);
  EXPECT_NEAR(var_d, var_d_alone, 1e-12 * var_d);  // the distance's growth is the same either way
  // alpha off by e: v = vartheta / alpha off by -vartheta e / alpha^2 and d = 1 / alpha by -e / alpha^2, so
  // var(v) = |vartheta|^2 var(d).
  EXPECT_NEAR(var_v_alone, level.squaredNorm() * var_d, 1e-9 * var_v_alone);
  EXPECT_LT(var_v, 1e-12 * var_v_alone);
  // A climb: alpha moves by 1.2 % over the step, the velocity's variance stays below 1e-3 of alpha alone's.
  const double var_v_climb = varianceAfterOneStep(climb, true, &var_d);
  const double var_v_climb_alone = varianceAfterOneStep(climb, false, &var_d_alone);
  EXPECT_GT(var_v_climb_alone, var_v_alone);  // the rate term adds to it
  EXPECT_LT(var_v_climb, 1e-3 * var_v_climb_alone);
}

TEST(Prediction, CovarianceStaysSymmetricPositiveDefinite) {
  std::mt19937 rng(12);
  std::normal_distribution<double> n(0.0, 1.0);
  ImuParams imu;
  ProcessNoiseParams proc;
  State x;
  x.alpha = 1.0;
  x.mu = UnitVector(Vec3(0.2, -0.1, 0.97));
  ErrorCov P = ErrorCov::Identity() * 0.01;
  int not_pd = 0;
  for (int k = 0; k < 1000; ++k) {
    const Vec3 accel = -kG0 * x.g.vector() + 0.5 * Vec3(n(rng), n(rng), n(rng));
    const Vec3 gyro = 0.3 * Vec3(n(rng), n(rng), n(rng));
    predict(accel, gyro, 0.01, imu, proc, &x, &P);
    ASSERT_TRUE(P.allFinite()) << "step " << k;
    ASSERT_TRUE(x.allFinite()) << "step " << k;
    ASSERT_EQ((P - P.transpose()).cwiseAbs().maxCoeff(), 0.0) << "step " << k;
    Eigen::LLT<ErrorCov> llt(P);
    if (llt.info() != Eigen::Success) ++not_pd;
  }
  EXPECT_EQ(not_pd, 0);
  const Eigen::LDLT<ErrorCov> ldlt(P);
  EXPECT_GT(ldlt.vectorD().minCoeff(), 0.0);
}

}  // namespace
}  // namespace diekf
