// The parts of the estimator one at a time (docs/algorithm.md section 9): the stamp rule shared with the ROS
// layer, the uncertainty of the derived quantities, the health monitor's status state machine and divergence
// checks, the restart policy's priors, the IMU propagator's interval bookkeeping and the image check.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

#include <opencv2/imgproc.hpp>

#include "../../src/core/health_monitor.h"
#include "../../src/core/image_update.h"
#include "../../src/core/imu_propagator.h"
#include "../../src/core/restart_policy.h"
#include "diekf/image_preprocessor.h"
#include "diekf/imu_filter.h"
#include "diekf/stamp_check.h"
#include "diekf/state.h"
#include "mynt_camera.h"
#include "synthetic_flight.h"

namespace diekf {
namespace {

using internal::FrameFacts;
using internal::HealthMonitor;
using internal::ImuPropagator;
using internal::RestartPolicy;

// The photometric RMS limit keeps the noise-free limit's share of unrelated images' residual for the ground's part
// and adds the sensor noise's (docs/noise_model.md section 4).
TEST(PhotometricRmsLimit, WidensWithTheSensorNoisesShareOnly) {
  using internal::maxPhotometricRms;
  EXPECT_DOUBLE_EQ(maxPhotometricRms(0.8, 0.0), 0.8);              // noise-free images: the configured limit
  EXPECT_NEAR(maxPhotometricRms(0.8, 0.1), 0.8, 0.005);            // textured ground: hardly wider
  EXPECT_DOUBLE_EQ(maxPhotometricRms(0.8, std::sqrt(2.0)), std::sqrt(2.0));  // pure noise: unrelated images' RMS
  EXPECT_DOUBLE_EQ(maxPhotometricRms(0.8, 5.0), std::sqrt(2.0));   // floor clamped at unrelated images'
  // With the floor's variance f, the ground's part (limit^2 - f) is 0.32 of unrelated images' ground part (2 - f).
  for (double f : {0.1, 0.5, 1.0, 1.5}) {
    const double limit = maxPhotometricRms(0.8, std::sqrt(f));
    EXPECT_NEAR((limit * limit - f) / (2.0 - f), 0.32, 1e-12) << f;
    EXPECT_LT(limit, std::sqrt(2.0));
  }
}

TEST(StampCheck, ClassifiesAgainstTheJumpThreshold) {
  EXPECT_EQ(classifyStampStep(10.0, 10.01, 1.0), StampStep::kForward);
  EXPECT_EQ(classifyStampStep(10.0, 10.0, 1.0), StampStep::kDuplicate);
  EXPECT_EQ(classifyStampStep(10.0, 9.5, 1.0), StampStep::kOutOfOrder);
  EXPECT_EQ(classifyStampStep(10.0, 9.0, 1.0), StampStep::kOutOfOrder);  // exactly the threshold: not a jump
  EXPECT_EQ(classifyStampStep(10.0, 8.9, 1.0), StampStep::kJumpBack);
  EXPECT_EQ(classifyStampStep(-HUGE_VAL, 0.0, 1.0), StampStep::kForward);  // no previous stamp yet
}

State sampleState() {
  State x;
  x.alpha = 0.8;
  x.vartheta = Vec3(0.3, -0.2, 0.1);
  return x;
}

// A camera at rest 1 m above level ground, looking down (the distance column's tests).
State restingStateAt1m() {
  State x;
  x.alpha = 1.0;
  x.mu = UnitVector(Vec3(0.0, 0.0, 1.0));
  x.g = UnitVector(Vec3(0.0, 0.0, 1.0));
  return x;
}

ErrorCov sampleCovariance() {
  ErrorCov P = ErrorCov::Identity() * 1e-4;
  P(ErrIdx::kAlpha, ErrIdx::kAlpha) = 4e-3;
  P(ErrIdx::kAlpha, ErrIdx::kVartheta) = P(ErrIdx::kVartheta, ErrIdx::kAlpha) = 1e-4;  // positive definite
  P(ErrIdx::kVartheta + 1, ErrIdx::kVartheta + 1) = 2e-3;
  return P;
}

// The first-order uncertainties against finite differences of d = 1/alpha and v = vartheta/alpha.
TEST(DerivedUncertainty, MatchesFiniteDifferences) {
  const State x = sampleState();
  const ErrorCov P = sampleCovariance();
  const double h = 1e-6;
  const double dd_dalpha = (1.0 / (x.alpha + h) - 1.0 / (x.alpha - h)) / (2.0 * h);
  EXPECT_NEAR(sigmaDistance_m(x, P), std::abs(dd_dalpha) * std::sqrt(P(0, 0)), 1e-8);
  EXPECT_NEAR(relativeSigmaDistance(x, P), sigmaDistance_m(x, P) / x.distance_m(), 1e-12);
  Eigen::Matrix<double, 3, 4> J;
  for (int k = 0; k < 4; ++k) {
    State a = x, b = x;
    if (k == 0) {
      a.alpha += h;
      b.alpha -= h;
    } else {
      a.vartheta[k - 1] += h;
      b.vartheta[k - 1] -= h;
    }
    J.col(k) = (a.velocity_mps() - b.velocity_mps()) / (2.0 * h);
  }
  const Mat3 C_fd = J * P.topLeftCorner<4, 4>() * J.transpose();
  ASSERT_GT(C_fd.diagonal().minCoeff(), 0.0);
  EXPECT_LT((velocityCovariance(x, P) - C_fd).cwiseAbs().maxCoeff(), 1e-8);
  EXPECT_LT((sigmaVelocity_mps(x, P) - C_fd.diagonal().cwiseSqrt()).cwiseAbs().maxCoeff(), 1e-8);
}

// The plane's ambiguity over a scene that is not one plane: the distance's relative variance grows by the given
// amount, the velocity's covariance and the other states' are unchanged.
TEST(DerivedUncertainty, ScaleAmbiguityWidensTheDistanceNotTheVelocity) {
  const State x = sampleState();
  const ErrorCov P = sampleCovariance();
  ErrorCov Q = P;
  const double relative_var = 0.05 * 0.05;
  addScaleAmbiguity(x, relative_var, &Q);
  EXPECT_NEAR(relativeSigmaDistance(x, Q) * relativeSigmaDistance(x, Q),
              relativeSigmaDistance(x, P) * relativeSigmaDistance(x, P) + relative_var, 1e-12);
  EXPECT_LT((velocityCovariance(x, Q) - velocityCovariance(x, P)).cwiseAbs().maxCoeff(), 1e-15);
  const ErrorCov D = Q - P;
  constexpr int kRest = kErrorDim - 4;  // the states after alpha and vartheta
  const double changed = D.topLeftCorner<4, 4>().cwiseAbs().maxCoeff();
  const double rest = D.bottomRightCorner<kRest, kRest>().cwiseAbs().maxCoeff();
  EXPECT_GT(changed, 1e-6);
  EXPECT_EQ(rest, 0.0);
  ErrorCov R = P;
  addScaleAmbiguity(x, 0.0, &R);
  EXPECT_EQ((R - P).cwiseAbs().maxCoeff(), 0.0);
}

// The image's motion defined only to a relative accuracy (movers): the velocity's covariance grows by
// relative_var v v^T (found by finite differences of v = vartheta / alpha over vartheta scaled by 1 + e), the
// distance's and the other states' not.
TEST(DerivedUncertainty, MotionAmbiguityWidensTheVelocityNotTheDistance) {
  const State x = sampleState();
  const ErrorCov P = sampleCovariance();
  ErrorCov Q = P;
  const double relative_var = 0.2 * 0.2;
  addMotionAmbiguity(x, relative_var, &Q);
  const double h = 1e-6;
  State a = x, b = x;
  a.vartheta *= 1.0 + h;
  b.vartheta *= 1.0 - h;
  const Vec3 dv_de = (a.velocity_mps() - b.velocity_mps()) / (2.0 * h);  // v per unit relative error
  const Mat3 added_fd = relative_var * dv_de * dv_de.transpose();
  ASSERT_GT(added_fd.diagonal().maxCoeff(), 1e-6);
  EXPECT_LT((velocityCovariance(x, Q) - velocityCovariance(x, P) - added_fd).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_NEAR(relativeSigmaDistance(x, Q), relativeSigmaDistance(x, P), 1e-15);
  ErrorCov D = Q - P;
  D.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta).setZero();
  EXPECT_EQ(D.cwiseAbs().maxCoeff(), 0.0);  // nothing but vartheta's own block
  ErrorCov R = P;
  addMotionAmbiguity(x, 0.0, &R);
  EXPECT_EQ((R - P).cwiseAbs().maxCoeff(), 0.0);
}

// The calibration's pointing (camera-IMU rotation, principal point) as an uncertain small rotation of the frame:
// the covariance added equals the spread of the state turned by a rotation of that variance, found by finite
// differences (vartheta, mu and g turned together); the velocity's covariance grows by var [v]x [v]x^T, the
// distance's and the other states' not.
TEST(DerivedUncertainty, FrameRotationTurnsVelocityNormalAndGravityTogether) {
  const State x = sampleState();
  const ErrorCov P = sampleCovariance();
  ErrorCov Q = P;
  const double var = 0.01 * 0.01;
  addFrameRotationUncertainty(x, var, &Q);
  ErrorCov Q_fd = P;
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    const Eigen::Matrix3d R = Eigen::AngleAxisd(h, Vec3::Unit(k)).toRotationMatrix();
    State turned = x;
    turned.vartheta = R * x.vartheta;
    turned.mu = UnitVector(R * x.mu.vector());
    turned.g = UnitVector(R * x.g.vector());
    const ErrorVec column = turned.boxminus(x) / h;
    Q_fd.noalias() += var * column * column.transpose();
  }
  EXPECT_LT((Q - Q_fd).cwiseAbs().maxCoeff(), 1e-9);
  const Vec3 v = x.velocity_mps();
  EXPECT_LT((velocityCovariance(x, Q) - velocityCovariance(x, P) - var * skew(v) * skew(v).transpose())
                .cwiseAbs()
                .maxCoeff(),
            1e-12);
  EXPECT_EQ(Q(ErrIdx::kAlpha, ErrIdx::kAlpha), P(ErrIdx::kAlpha, ErrIdx::kAlpha));
  const ErrorCov D = Q - P;
  const double mu_grown = D.block<2, 2>(ErrIdx::kMu, ErrIdx::kMu).trace();
  const double g_grown = D.block<2, 2>(ErrIdx::kG, ErrIdx::kG).trace();
  const double bias_grown = D.block<6, 6>(ErrIdx::kBa, ErrIdx::kBa).cwiseAbs().maxCoeff();
  EXPECT_NEAR(mu_grown, 2.0 * var, 1e-12);  // both tangent axes turn, by var each
  EXPECT_NEAR(g_grown, 2.0 * var, 1e-12);
  EXPECT_EQ(bias_grown, 0.0);
  ErrorCov R = P;
  addFrameRotationUncertainty(x, 0.0, &R);
  EXPECT_EQ((R - P).cwiseAbs().maxCoeff(), 0.0);
}

FilterStatus frame(HealthMonitor* m, double t_s, const State& x, const ErrorCov& P, std::string* msg,
                   const std::string& reset_here = "", double accel_mps2 = 0.0) {
  static const std::string empty;
  FrameFacts f;
  f.t_s = t_s;
  f.accel_mps2 = accel_mps2;
  f.reset_here = &reset_here;
  f.usable = true;
  f.usable_why = &empty;
  f.had_reference = true;
  f.skip_reason = &empty;
  f.last_reset_reason = &empty;
  char buf[internal::kMessageCapacity] = "";
  const FilterStatus s = m->frameStatus(f, x, P, buf, sizeof(buf));
  *msg = buf;
  return s;
}

// Every transition of the state machine listed in health_monitor.h (and docs/algorithm.md section 9).
TEST(HealthMonitor, StatusTransitions) {
  EstimatorParams params;
  HealthMonitor m(params);
  m.startRun();
  State x = sampleState();
  ErrorCov P_wide = ErrorCov::Identity();  // sigma_d / d = 1 / 0.8 / ... far above the tracking threshold
  ErrorCov P_tight = ErrorCov::Identity() * 1e-6;
  std::string msg;
  // any -> reset: a restart at this image.
  EXPECT_EQ(frame(&m, 0.0, x, P_wide, &msg, "distance 99 m outside"), FilterStatus::kReset);
  EXPECT_EQ(msg, "distance 99 m outside");
  // An input restart announced: the next frame reports reset with its reason, once.
  m.announceReset("IMU time jumped back by 5 s");
  EXPECT_EQ(frame(&m, 0.1, x, P_wide, &msg), FilterStatus::kReset);
  EXPECT_EQ(msg, "IMU time jumped back by 5 s");
  // reset -> initializing: no update applied yet.
  EXPECT_EQ(frame(&m, 0.2, x, P_tight, &msg), FilterStatus::kInitializing);
  EXPECT_EQ(msg, "waiting for a valid image update");
  // Still initializing with an update but a wide distance.
  m.countUpdate(true);
  EXPECT_EQ(frame(&m, 0.3, x, P_wide, &msg), FilterStatus::kInitializing);
  EXPECT_NE(msg.find("converging"), std::string::npos) << msg;
  EXPECT_FALSE(m.converged());
  // initializing -> tracking: sigma_d / d below the threshold.
  EXPECT_EQ(frame(&m, 0.4, x, P_tight, &msg), FilterStatus::kTracking);
  EXPECT_TRUE(m.converged());
  EXPECT_EQ(m.convergedSince(), 0.4);
  // Converged stays converged even if sigma grows again (until the next run).
  EXPECT_EQ(frame(&m, 0.5, x, P_wide, &msg), FilterStatus::kTracking);
  // tracking -> degraded for degraded_hold_s after a failed consistency check, then back to tracking.
  m.noteDegraded(1.0, "update gated: test");
  EXPECT_EQ(frame(&m, 1.0, x, P_tight, &msg), FilterStatus::kDegraded);
  EXPECT_EQ(msg, "update gated: test");
  // A later frame in the hold names the check with its age: not this frame's.
  ASSERT_GT(params.divergence.degraded_hold_s, 0.5);
  EXPECT_EQ(frame(&m, 1.5, x, P_tight, &msg), FilterStatus::kDegraded);
  EXPECT_EQ(msg, "update gated: test (0.5 s ago)");
  EXPECT_EQ(frame(&m, 1.0 + params.divergence.degraded_hold_s, x, P_tight, &msg), FilterStatus::kDegraded);
  EXPECT_EQ(frame(&m, 1.01 + params.divergence.degraded_hold_s, x, P_tight, &msg), FilterStatus::kTracking);
  EXPECT_EQ(m.status(), FilterStatus::kTracking);
  // A new run: initializing again.
  m.startRun();
  EXPECT_FALSE(m.converged());
  EXPECT_EQ(frame(&m, 3.0, x, P_tight, &msg), FilterStatus::kInitializing);
  // A note held while converging is said too, with its age once it is an earlier frame's.
  m.noteDegraded(3.0, "pattern found");
  EXPECT_EQ(frame(&m, 3.0, x, P_wide, &msg), FilterStatus::kInitializing);
  EXPECT_EQ(msg, "waiting for a valid image update; pattern found") << msg;
  EXPECT_EQ(frame(&m, 3.3, x, P_wide, &msg), FilterStatus::kInitializing);
  EXPECT_EQ(msg, "waiting for a valid image update; pattern found (0.3 s ago)") << msg;
}

TEST(HealthMonitor, SaysWhenTheDistanceIsNotObserved) {
  // While converging, a sigma_d / d that does not fall over kStallWindowS (a hover, constant velocity) is named.
  EstimatorParams params;
  HealthMonitor m(params);
  m.startRun();
  m.countUpdate(true);
  const State x = sampleState();
  const ErrorCov P_wide = ErrorCov::Identity();
  std::string msg;
  const char* kStall = "no acceleration to scale the images";
  for (int i = 0; i <= 90; ++i) {  // 3 s at 30 Hz, sigma_d / d constant
    EXPECT_EQ(frame(&m, i / 30.0, x, P_wide, &msg), FilterStatus::kInitializing);
    if (i / 30.0 < internal::kStallWindowS) {
      EXPECT_EQ(msg.find(kStall), std::string::npos) << i << ": " << msg;
    }
  }
  EXPECT_NE(msg.find(kStall), std::string::npos) << msg;
  EXPECT_NE(msg.find("converging"), std::string::npos) << msg;
  // The variance falling by 40 % per second: the distance is being observed, the note goes at the next window.
  ErrorCov P = P_wide;
  for (int i = 91; i <= 240; ++i) {
    P *= std::pow(0.6, 1.0 / 30.0);
    EXPECT_EQ(frame(&m, i / 30.0, x, P, &msg), FilterStatus::kInitializing);
  }
  EXPECT_EQ(msg.find(kStall), std::string::npos) << msg;
  // sigma_d / d constant again, but the camera accelerates (the updates are held back for another reason: gated,
  // outliers): not said.
  for (int i = 241; i <= 420; ++i) {
    const double accel_mps2 = 2.0 * internal::kStallMaxAccelMps2 * (i % 30 == 0);  // a short push each second
    EXPECT_EQ(frame(&m, i / 30.0, x, P, &msg, "", accel_mps2), FilterStatus::kInitializing);
    EXPECT_EQ(msg.find(kStall), std::string::npos) << i << ": " << msg;
  }
  // A new run forgets the window.
  m.startRun();
  m.countUpdate(true);
  EXPECT_EQ(frame(&m, 10.0, x, P_wide, &msg), FilterStatus::kInitializing);
  EXPECT_EQ(msg.find(kStall), std::string::npos) << msg;
}

TEST(HealthMonitor, SmoothedNisDegrades) {
  EstimatorParams params;
  HealthMonitor m(params);
  m.startRun();
  m.countUpdate(true);
  std::string msg;
  const State x = sampleState();
  const ErrorCov P = ErrorCov::Identity() * 1e-6;
  EXPECT_EQ(frame(&m, 0.0, x, P, &msg), FilterStatus::kTracking);
  m.noteInnovation(0.1, 0.033, 8.0);  // its mean: consistent
  EXPECT_EQ(frame(&m, 0.1, x, P, &msg), FilterStatus::kTracking);
  for (int i = 0; i < 100; ++i) m.noteInnovation(0.2 + 0.033 * i, 0.033, 40.0);  // 5x the mean, above 3x
  EXPECT_EQ(frame(&m, 3.5, x, P, &msg), FilterStatus::kDegraded);
  EXPECT_NE(msg.find("smoothed NIS"), std::string::npos) << msg;
}

TEST(HealthMonitor, DivergenceChecks) {
  EstimatorParams params;
  params.divergence.bad_frames_before_reset = 3;
  HealthMonitor m(params);
  m.startRun();
  const State good = sampleState();
  const ErrorCov P = sampleCovariance();
  std::string reason;
  m.checkDivergence(good, P, true, true, "", &reason);
  EXPECT_TRUE(reason.empty()) << reason;
  State far = good;
  far.alpha = 1.0 / 80.0;
  m.checkDivergence(far, P, true, true, "", &reason);
  EXPECT_NE(reason.find("distance 80 m outside"), std::string::npos) << reason;
  EXPECT_FALSE(m.scaleLost());
  reason.clear();
  // The distance's 1-sigma running away: before convergence a loss of the scale (counted by the estimator for the
  // fixed pattern's patch condition), after it not.
  ErrorCov P_wide = P;
  P_wide(ErrIdx::kAlpha, ErrIdx::kAlpha) = 1e6;
  m.checkDivergence(good, P_wide, true, true, "", &reason);
  EXPECT_NE(reason.find("before convergence"), std::string::npos) << reason;
  EXPECT_TRUE(m.scaleLost());
  reason.clear();
  m.checkDivergence(good, P, true, true, "", &reason);
  EXPECT_FALSE(m.scaleLost());
  ErrorCov P_bad = P;
  P_bad(2, 2) = -1.0;
  m.checkDivergence(good, P_bad, true, true, "", &reason);
  EXPECT_NE(reason.find("negative variance"), std::string::npos) << reason;
  reason.clear();
  // Bad frames count only after an applied update of the run, and only on usable images.
  for (int i = 0; i < 5; ++i) m.checkDivergence(good, P, false, true, "skipped", &reason);
  EXPECT_TRUE(reason.empty()) << "no update applied in this run yet: " << reason;
  m.countUpdate(true);
  m.checkDivergence(good, P, true, true, "", &reason);
  for (int i = 0; i < 5; ++i) m.checkDivergence(good, P, false, false, "unusable", &reason);
  EXPECT_TRUE(reason.empty()) << reason;
  EXPECT_EQ(m.badFrames(), 0);
  for (int i = 0; i < 3; ++i) m.checkDivergence(good, P, false, true, "update rejected: test", &reason);
  EXPECT_EQ(reason, "3 consecutive frames with a bad or skipped update (last: update rejected: test)");
}

TEST(RestartPolicy, WarmPriorFromAStateAtLeastALagOld) {
  EstimatorParams params;
  RestartPolicy policy(params);
  State x;
  ErrorCov P;
  policy.coldStart(false, 0.0, &x, &P);
  EXPECT_EQ(x.alpha, params.init.alpha0_inv_m);
  EXPECT_FALSE(policy.warmStarted());
  // Healthy states offered at 0.0 .. 2.0 s, one every 0.1 s; kept one per kSnapshotSpacingS (0.25 s): those of
  // 0.0, 0.3, 0.6, 0.9, 1.2, 1.5 and 1.8 s.
  for (int i = 0; i <= 20; ++i) {
    State good = x;
    good.alpha = 1.0 + i;  // d = 1 / (1 + i): which one is used is visible
    policy.rememberGood(0.1 * i, good);
  }
  // A fault at 2.0 s: the newest kept snapshot at least 1 s old is the one of 0.9 s (alpha 10).
  policy.applyWarmPrior(2.0, &x, &P);
  EXPECT_TRUE(policy.warmStarted());
  EXPECT_DOUBLE_EQ(x.alpha, 10.0);
  const double sigma = params.init.warm_restart_sigma_alpha_relative * 10.0;
  EXPECT_DOUBLE_EQ(P(ErrIdx::kAlpha, ErrIdx::kAlpha), sigma * sigma);
  // Too old: no warm prior.
  State y;
  ErrorCov Q;
  policy.coldStart(false, 0.0, &y, &Q);
  policy.applyWarmPrior(2.0 + params.init.warm_restart_max_age_s + 1.0, &y, &Q);
  EXPECT_FALSE(policy.warmStarted());
  EXPECT_EQ(y.alpha, params.init.alpha0_inv_m);
  // Forgotten history: no warm prior.
  policy.forgetHistory();
  policy.applyWarmPrior(2.0, &y, &Q);
  EXPECT_FALSE(policy.warmStarted());
  // A converged run keeps its time offset across a cold start, an unconverged one does not.
  y.t_d_s = 0.012;
  policy.coldStart(true, 0.0, &y, &Q);
  EXPECT_EQ(y.t_d_s, 0.012);
  policy.coldStart(false, 0.0, &y, &Q);
  EXPECT_EQ(y.t_d_s, 0.0);
  policy.noteRestart("test");
  EXPECT_EQ(policy.count(), 1);
  EXPECT_EQ(policy.lastReason(), "test");
}

TEST(ImuPropagator, GravityFromTheAccelerometerWithHowFarItMayBeOff) {
  // At rest the samples agree and the frame does not turn: no spread. A multirotor turning at a constant rate
  // about x with its specific force along its thrust (fixed in its frame): the samples agree, but the frame turned
  // by w (t_end - t_i) from each: the spread is the mean square of that, per tangent axis.
  EstimatorParams params;
  params.imu.input_rate_hz = 100.0;
  params.imu.decimation_factor = 1;
  for (const double rate_radps : {0.0, 0.4}) {
    ImuPropagator imu(params);
    for (int i = 0; i <= 100; ++i) {
      ImuSample s;
      s.t_s = 0.01 * i;
      s.gyro_radps = Vec3(rate_radps, 0.0, 0.0);
      s.accel_mps2 = Vec3(0.0, 0.0, -9.81);
      ASSERT_TRUE(imu.push(s));
    }
    UnitVector g;
    double spread_rad2 = -1.0;
    ASSERT_TRUE(imu.gravityFromAccel(1.0, &g, &spread_rad2));
    EXPECT_LT((g.vector() - Vec3(0.0, 0.0, 1.0)).norm(), 1e-12);
    // The samples in (0.5, 1.0], 0.01 s apart: mean of (w k 0.01)^2 for k = 0..49 (the window's end is the newest).
    double expected = 0.0;
    int n = 0;
    for (int k = 0; k <= 50; ++k, ++n) expected += std::pow(rate_radps * 0.01 * k, 2);
    expected *= 0.5 / n;
    EXPECT_NEAR(spread_rad2, expected, 0.05 * expected + 1e-15) << "rate " << rate_radps;
  }
}

TEST(ImuPropagator, IntervalMeanGyroAndInterpolation) {
  EstimatorParams params;
  params.imu.input_rate_hz = 100.0;
  params.imu.decimation_factor = 1;
  ImuPropagator imu(params);
  const Vec3 w(0.1, -0.2, 0.3);
  for (int i = 0; i <= 100; ++i) {
    ImuSample s;
    s.t_s = 0.01 * i;
    s.gyro_radps = w * (1.0 + 0.01 * i);  // rate rising linearly in time
    s.accel_mps2 = Vec3(0.0, 0.0, -9.81);
    ASSERT_TRUE(imu.push(s));
  }
  ImuSample stale;
  stale.t_s = 0.5;
  EXPECT_FALSE(imu.push(stale)) << "older than the newest sample";
  EXPECT_LT((imu.imuAt(0.255).gyro_radps - w * 1.255).norm(), 1e-12);
  State x;
  ErrorCov P = ErrorCov::Identity() * 1e-4;
  imu.startAt(0.2);
  imu.setReference(0.2);
  EXPECT_LT((imu.rateChangeSinceReference(0.6) - w * 0.4).norm(), 1e-12);
  imu.propagateTo(0.45, &x, &P);
  EXPECT_EQ(imu.stateTime(), 0.45);
  // Mean over (0.2, 0.6] of the linear rate: its value at 0.4 s, whatever part was already propagated.
  EXPECT_LT((imu.meanGyroOverInterval(0.6) - w * 1.4).norm(), 1e-12);
  UnitVector g;
  ASSERT_TRUE(imu.gravityFromAccel(0.6, &g));
  EXPECT_LT((g.vector() - Vec3(0.0, 0.0, 1.0)).norm(), 1e-12);

  // A reference re-timed by a changed time offset estimate (docs/algorithm.md section 3.6), later and earlier
  // than the state's time: the interval's mean rate and the rate change are those of the moved window, exactly
  // (the rate at t is w (1 + t)).
  for (const double to_s : {0.23, 0.17}) {
    ImuPropagator moved(params);
    for (int i = 0; i <= 100; ++i) {
      ImuSample s;
      s.t_s = 0.01 * i;
      s.gyro_radps = w * (1.0 + 0.01 * i);
      s.accel_mps2 = Vec3(0.0, 0.0, -9.81);
      ASSERT_TRUE(moved.push(s));
    }
    State y;
    ErrorCov Q = ErrorCov::Identity() * 1e-4;
    moved.startAt(0.1);
    moved.propagateTo(0.2, &y, &Q);  // the state at the reference, the samples before it used
    moved.setReference(0.2);
    moved.moveReference(0.2, to_s);
    EXPECT_LT((moved.rateChangeSinceReference(0.6) - w * (0.6 - to_s)).norm(), 1e-12) << to_s;
    EXPECT_LT((moved.meanGyroOverInterval(0.6) - w * (1.0 + 0.5 * (to_s + 0.6))).norm(), 1e-12) << to_s;
    moved.propagateTo(0.4, &y, &Q);
    EXPECT_LT((moved.meanGyroOverInterval(0.6) - w * (1.0 + 0.5 * (to_s + 0.6))).norm(), 1e-12) << to_s;
  }
}

// The gyro's noise density from its filtered samples (docs/noise_model.md section 6): white noise of a known
// density, with and without a slow turn and propeller vibration, through the IMU preprocessing (500 Hz, 20 Hz
// low-pass, 100 Hz out) into the propagator. An inflated calibration is replaced by what the samples show;
// vibration does not raise it above the calibration. Until 1 s of samples: the calibration's density.
TEST(ImuPropagator, GyroNoiseDensityIsMeasuredFromTheSamples) {
  const double density = 2e-3;  // rad/s/sqrt(Hz)
  auto measure = [&](double vibration_radps, double turn_radps, double seconds, double calibrated) {
    EstimatorParams params;
    params.imu.gyro_noise_density = calibrated;
    ImuPreprocessor pre(Eigen::Isometry3d::Identity(), params.imu);
    ImuPropagator imu(params);
    const int D = params.imu.decimation_factor;
    imu.setFilterNoise(pre.noiseAutocovariances(D));
    std::mt19937 rng(11);
    std::normal_distribution<double> n01(0.0, 1.0);
    const double rate = params.imu.input_rate_hz, sd = density * std::sqrt(rate);
    for (int k = 0; k < static_cast<int>(seconds * rate); ++k) {
      const double t = k / rate;
      ImuSample s, o;
      s.t_s = t;
      s.accel_mps2 = Vec3(0.0, 0.0, 9.81);
      s.gyro_radps = Vec3(sd * n01(rng), sd * n01(rng), sd * n01(rng)) +
                     turn_radps * Vec3(std::sin(2.0 * M_PI * 0.3 * t), 0.0, std::cos(2.0 * M_PI * 0.2 * t)) +
                     vibration_radps * Vec3(std::sin(2.0 * M_PI * 137.0 * t), 0.0, 0.0);
      if (pre.push(s, &o)) imu.push(o);
    }
    if (seconds > 10.0 && vibration_radps == 0.0 && turn_radps == 0.0) {
      // One sample's variance (white noise through the low-pass: density^2 f_in autocov0), the same measured
      // from the specific force (no noise on it here: zero).
      const double expect = density * density * rate * pre.noiseAutocovariance(0);
      EXPECT_NEAR(imu.gyroSampleVariance().maxCoeff(), expect, 0.3 * expect);
      EXPECT_NEAR(imu.gyroSampleVariance().minCoeff(), expect, 0.3 * expect);
      EXPECT_LT(imu.accelSampleVariance().maxCoeff(), 1e-12);
    }
    return std::sqrt(imu.gyroNoiseDensitySq());
  };
  EXPECT_EQ(measure(0.0, 0.0, 0.5, 7e-3), 7e-3) << "before 1 s of samples: the calibration's";
  const double quiet = measure(0.0, 0.0, 30.0, 7e-3), turning = measure(0.0, 0.5, 30.0, 7e-3);
  // 4.5 rad/s at 137 Hz: 0.09 rad/s left after the low-pass, 0.02 after the decimation's mean of five (imu/
  // decimation_mean), more than the white noise's 0.013.
  const double vibrating = measure(4.5, 0.0, 30.0, 7e-3), vibrating_calibrated = measure(4.5, 0.0, 30.0, density);
  std::printf("density (white %.3g, calibration 7e-3): measured %.3g, turning %.3g, with vibration %.3g; "
              "calibration right, with vibration %.3g rad/s/sqrt(Hz)\n",
              density, quiet, turning, vibrating, vibrating_calibrated);
  EXPECT_NEAR(quiet, density, 0.15 * density) << "the samples, not the inflated calibration";
  EXPECT_NEAR(turning, density, 0.15 * density) << "a turn of 0.5 rad/s at 0.2-0.3 Hz is not noise";
  EXPECT_GT(vibrating, 1.5 * density) << "the samples' spread includes the vibration...";
  EXPECT_EQ(vibrating_calibrated, density) << "...which does not raise the density above the calibration";
}

// The filtered samples' noise is measured from second differences of samples 10 ms apart whatever the prediction
// rate (ImuPropagator::setFilterNoise): at 500 Hz (decimation 1) neighbouring samples of the 20 Hz low-pass are so
// closely correlated that their second difference keeps 0.3 % of the noise, and what the low-pass leaves of a
// propeller's vibration was taken for 300 times that much noise (the distance's column was then shrunk to nothing
// and the distance was found 7 % high for 10 s on clean flight 2). White noise alone and with vibration, at 100 and
// 500 Hz: one filtered sample's variance (the same quantity at both rates) measured alike, and as it is for the
// white noise.
TEST(ImuPropagator, MeasuredSampleNoiseDoesNotDependOnThePredictionRate) {
  const double density = 2e-2;  // m/s^2/sqrt(Hz)
  auto measure = [&](int D, double vibration_mps2, bool mean = false) {
    EstimatorParams params;
    params.imu.decimation_factor = D;
    params.imu.decimation_mean = mean;  // the n-th filtered sample: the same quantity at both rates
    ImuPreprocessor pre(Eigen::Isometry3d::Identity(), params.imu);
    ImuPropagator imu(params);
    imu.setFilterNoise(pre.noiseAutocovariances(D));
    std::mt19937 rng(21);
    std::normal_distribution<double> n01(0.0, 1.0);
    const double rate = params.imu.input_rate_hz, sd = density * std::sqrt(rate);
    for (int k = 0; k < static_cast<int>(20.0 * rate); ++k) {
      const double t = k / rate;
      ImuSample s, o;
      s.t_s = t;
      s.gyro_radps = Vec3::Zero();
      s.accel_mps2 = Vec3(sd * n01(rng) + vibration_mps2 * std::sin(2.0 * M_PI * 137.0 * t) +
                              0.5 * std::sin(2.0 * M_PI * 0.3 * t),
                          0.0, 9.81);
      if (pre.push(s, &o)) imu.push(o);
    }
    return imu.accelSampleVariance().x();
  };
  EstimatorParams params;
  params.imu.decimation_mean = false;
  const ImuPreprocessor pre(Eigen::Isometry3d::Identity(), params.imu);
  const double white = density * density * params.imu.input_rate_hz * pre.noiseAutocovariance(0);
  const double w100 = measure(5, 0.0), w500 = measure(1, 0.0), v100 = measure(5, 2.0), v500 = measure(1, 2.0);
  // The default's mean of five (imu/decimation_mean) is a sample of its own: the low-pass's white noise nearly
  // unchanged (its band is far below the mean's first null at 100 Hz), the 137 Hz tone's residual cut.
  const double w100_mean = measure(5, 0.0, true), v100_mean = measure(5, 2.0, true);
  params.imu.decimation_mean = true;
  const double white_mean = density * density * params.imu.input_rate_hz *
                            ImuPreprocessor(Eigen::Isometry3d::Identity(), params.imu).noiseAutocovariance(0);
  std::printf("one filtered sample's variance: white noise %.3g; measured at 100 / 500 Hz %.3g / %.3g, with "
              "vibration %.3g / %.3g (m/s^2)^2; the mean of five: white %.3g, measured %.3g, with vibration %.3g\n",
              white, w100, w500, v100, v500, white_mean, w100_mean, v100_mean);
  EXPECT_NEAR(w100, white, 0.15 * white);
  EXPECT_NEAR(w500, white, 0.15 * white);
  EXPECT_NEAR(v500 / v100, 1.0, 0.2) << "the prediction rate does not change what the samples show";
  EXPECT_NEAR(w100_mean, white_mean, 0.15 * white_mean);
  EXPECT_LT(v100_mean - w100_mean, 0.5 * (v100 - w100)) << "the mean removes most of the tone's residual";
}

// The distance's column of the prediction Jacobian (docs/algorithm.md section 2.1, "The distance's column"). A
// camera at rest 1 m above the ground, an accelerometer with white noise of a typical Kalibr density, and an
// image update every 1/30 s that measures vartheta = v / d = 0 (a 3 mrad/s 1-sigma; Kalman update of those
// three states). Nothing observes the distance, so alpha = 1 / d should only wander about the truth. With each
// step's own reading in the column (the textbook EKF), the column holds the noise that the next innovation
// measures; their correlation moves alpha by -alpha P_alpha,alpha q / S per update (q the noise the
// prediction integrated, S the innovation variance) and the distance drifts up. With the column's
// acceleration smoothed, held from the last update and shrunk to its expected value given its noise, it carries
// none of the new noise and the drift shrinks, inside the reported 1-sigma.
TEST(ImuPropagator, LevelVarianceCountsEachSampleOnceHoweverThePiecesAreCut) {
  // White noise per filtered sample, propagated to every image and to each image interval's middle (the cuts of
  // the estimator): the level's spread over many runs is the reported factor times one sample's variance. The
  // pieces between two samples share their noise; counted as independent samples, the spread was 1.10 times the
  // factor, counted per interval 0.91 times.
  const double rate_hz = 100.0, frame_s = 1.0 / 30.0, seconds = 1.0, sd = 0.05;
  const int runs = 3000;
  double sum = 0.0, sum_sq = 0.0, factor = 0.0;
  for (int r = 0; r < runs; ++r) {
    EstimatorParams params;
    params.imu.input_rate_hz = rate_hz;
    params.imu.decimation_factor = 1;
    ImuPropagator imu(params);
    std::mt19937 rng(500 + r);
    std::normal_distribution<double> n01(0.0, 1.0);
    for (int i = 0; i <= static_cast<int>(seconds * rate_hz) + 2; ++i) {
      ImuSample s;
      s.t_s = i / rate_hz;
      s.accel_mps2 = Vec3(sd * n01(rng), 0.0, -9.81);  // at rest: -g0 g, g = +z; noise on x
      if (!imu.push(s)) ADD_FAILURE();
    }
    State x = restingStateAt1m();
    ErrorCov P = ErrorCov::Identity() * 1e-6;
    imu.startAt(0.0);
    for (int f = 1; f * frame_s <= seconds; ++f) {
      imu.propagateTo((f - 0.5) * frame_s, &x, &P);
      imu.propagateTo(f * frame_s, &x, &P);
    }
    const double level = imu.smoothedAccelLevel().x();
    sum += level;
    sum_sq += level * level;
    factor = imu.levelVarianceFactor();  // the same cuts in every run
  }
  const double mean = sum / runs;
  const double var = (sum_sq - runs * mean * mean) / (runs - 1);
  const double ratio = var / (factor * sd * sd);
  std::printf("level variance over %d runs / reported factor x sample variance: %.3f (factor %.4f)\n", runs, ratio,
              factor);
  EXPECT_NEAR(ratio, 1.0, 0.06);  // the variance's own standard error: sqrt(2 / runs) = 2.6 %
}

// The same level with the samples of the real preprocessing: white noise at 500 Hz through the 20 Hz low-pass,
// decimated to 100 Hz (D = 5) or not (D = 1). The filtered samples are correlated over about the low-pass's time
// constant: one or two periods at 100 Hz, ten and more at 500 Hz. The level's spread over many runs is the reported
// factor times the correlation factor times one sample's variance; with the correlation one and two periods apart
// only (before) it was 0.86 of that at 100 Hz and 2.2 times it at 500 Hz, where the distance's column then kept
// the noise's share of the acceleration (clean flight 2 at 500 Hz: the distance 7 % high for 10 s).
TEST(ImuPropagator, LevelVarianceCountsTheFilteredSamplesCorrelation) {
  const double seconds = 1.5, sd = 0.05;  // per raw sample, m/s^2
  const int runs = 1200;
  for (const int D : {5, 1}) {
    double sum = 0.0, sum_sq = 0.0, factor = 0.0, correlation = 0.0, sample_var = 0.0;
    for (int r = 0; r < runs; ++r) {
      EstimatorParams params;
      params.imu.decimation_factor = D;
      ImuPreprocessor pre(Eigen::Isometry3d::Identity(), params.imu);
      ImuPropagator imu(params);
      imu.setFilterNoise(pre.noiseAutocovariances(D));
      std::mt19937 rng(900 + r);
      std::normal_distribution<double> n01(0.0, 1.0);
      const double rate = params.imu.input_rate_hz;
      double t_last = 0.0;
      for (int k = 0; k < static_cast<int>(seconds * rate); ++k) {
        ImuSample s, o;
        s.t_s = k / rate;
        s.accel_mps2 = Vec3(sd * n01(rng), 0.0, 9.81);  // at rest, noise on x
        if (pre.push(s, &o) && imu.push(o)) t_last = o.t_s;
      }
      State x = restingStateAt1m();
      ErrorCov P = ErrorCov::Identity() * 1e-6;
      imu.startAt(0.2);
      imu.propagateTo(t_last, &x, &P);
      const double level = imu.smoothedAccelLevel().x();
      sum += level;
      sum_sq += level * level;
      factor = imu.levelVarianceFactor();
      correlation = imu.sampleCorrelationFactor();
      sample_var = sd * sd * pre.noiseAutocovariance(0);
    }
    const double mean = sum / runs;
    const double var = (sum_sq - runs * mean * mean) / (runs - 1);
    const double ratio = var / (factor * correlation * sample_var);
    std::printf("D = %d: level variance over %d runs / reported: %.3f (factor %.4f, correlation factor %.3f)\n", D,
                runs, ratio, factor, correlation);
    EXPECT_NEAR(ratio, 1.0, 0.12) << D;  // the variance's standard error: sqrt(2 / runs) = 4.1 %
  }
}

// A 100 Hz IMU on a vibrating airframe: the 130 Hz propeller tone folds to 30 Hz, where the order-4 low-pass leaves
// 8 % of it. The samples' second differences take that residual for white noise (one sample's variance 800 times
// the calibration's here), but the column's level, averaged over 0.1 s, keeps almost none of it. Shrunk by the
// measured variance, a real 0.3 m/s^2 acceleration lost 40 % of itself in the column (the distance was found 4-5 %
// high for seconds on a simulated flight with a 100 Hz IMU); shrunk by at most the calibration's, it stays.
TEST(ImuPropagator, FoldedVibrationIsNotTakenForNoiseInTheDistanceColumn) {
  EstimatorParams params;
  params.imu.input_rate_hz = 100.0;
  params.imu.decimation_factor = 1;
  params.imu.aliased_notch = false;  // the low-pass alone (the notches take the tone out once they have found it)
  params.imu.accel_noise_density = 2e-3;
  ImuPreprocessor pre(Eigen::Isometry3d::Identity(), params.imu);
  ImuPropagator imu(params);
  imu.setFilterNoise(pre.noiseAutocovariances(1));
  std::mt19937 rng(7);
  std::normal_distribution<double> n01(0.0, 1.0);
  const double rate = params.imu.input_rate_hz, sd = params.imu.accel_noise_density * std::sqrt(rate);
  const double accel_mps2 = 0.3;
  double t_last = 0.0;
  for (int k = 0; k < static_cast<int>(4.0 * rate); ++k) {
    ImuSample s, o;
    s.t_s = k / rate;
    // Specific force at rest is -g0 g (g = +z in restingStateAt1m); the acceleration on x.
    s.accel_mps2 = Vec3(accel_mps2 + sd * n01(rng) + 1.8 * std::sin(2.0 * M_PI * 130.0 * s.t_s + 0.4),
                        sd * n01(rng), -9.81 + sd * n01(rng));
    if (pre.push(s, &o) && imu.push(o)) t_last = o.t_s;
  }
  State x = restingStateAt1m();
  ErrorCov P = ErrorCov::Identity() * 1e-6;
  imu.startAt(t_last - 1.0);
  imu.propagateTo(t_last, &x, &P);
  imu.holdColumnAccel();
  const double measured = imu.accelSampleVariance().x(), counted = imu.accelLevelSampleVariance().x();
  const double level = imu.smoothedAccelLevel().x(), held = imu.heldColumnAccel().x();
  std::printf("folded 30 Hz tone: one sample's variance measured %.3g, counted %.3g (m/s^2)^2; level %.3f, held "
              "%.3f m/s^2 (true 0.3)\n", measured, counted, level, held);
  EXPECT_GT(measured, 10.0 * counted);          // the tone, read as noise
  EXPECT_NEAR(level, accel_mps2, 0.03);         // the level's average removed it
  EXPECT_NEAR(held, accel_mps2, 0.03);          // and the column keeps the acceleration
  // With the measured variance the same level would have lost 40 % (0.175 m/s^2 held).
  const double factor = imu.levelVarianceFactor() * imu.sampleCorrelationFactor();
  EXPECT_LT(level * std::max(0.0, 1.0 - factor * measured / (level * level)), 0.7 * level);
}

TEST(ImuPropagator, HeldJacobianAccelerationCutsTheDistanceDrift) {
  const double density = 2e-2, rate_hz = 100.0, frame_s = 1.0 / 30.0, seconds = 8.0, meas_sigma = 3e-3;
  auto final_alpha_error = [&](double smoothing_s, unsigned seed, double* sigma_alpha) {
    EstimatorParams params;
    params.imu.input_rate_hz = rate_hz;
    params.imu.decimation_factor = 1;
    params.imu.accel_noise_density = density;
    params.imu.jacobian_accel_smoothing_s = smoothing_s;
    ImuPropagator imu(params);
    std::mt19937 rng(seed);
    std::normal_distribution<double> n01(0.0, 1.0);
    const double sd = density * std::sqrt(rate_hz);
    for (int i = 0; i <= static_cast<int>(seconds * rate_hz) + 1; ++i) {
      ImuSample s;
      s.t_s = i / rate_hz;
      s.accel_mps2 = Vec3(sd * n01(rng), sd * n01(rng), -9.81 + sd * n01(rng));  // at rest: -g0 g, g = +z
      if (!imu.push(s)) ADD_FAILURE();
    }
    State x = restingStateAt1m();
    ErrorCov P = ErrorCov::Identity() * 1e-10;
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = 0.3 * 0.3;
    for (int k = 0; k < 3; ++k) P(ErrIdx::kVartheta + k, ErrIdx::kVartheta + k) = 0.1 * 0.1;
    imu.startAt(0.0);
    for (int f = 1; f * frame_s <= seconds; ++f) {
      imu.propagateTo(f * frame_s, &x, &P);
      const Eigen::Matrix3d S = P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) +
                                Eigen::Matrix3d::Identity() * meas_sigma * meas_sigma;
      const Eigen::Matrix<double, kErrorDim, 3> K = P.middleCols<3>(ErrIdx::kVartheta) * S.inverse();
      const Vec3 innovation = Vec3(meas_sigma * n01(rng), meas_sigma * n01(rng), meas_sigma * n01(rng)) - x.vartheta;
      x = x.boxplus(K * innovation);
      P -= K * P.middleRows<3>(ErrIdx::kVartheta);
      P = 0.5 * (P + P.transpose()).eval();
      imu.holdColumnAccel();
    }
    *sigma_alpha = std::sqrt(P(ErrIdx::kAlpha, ErrIdx::kAlpha));
    return x.alpha - 1.0;
  };
  const int runs = 40;
  const double held_s = EstimatorParams().imu.jacobian_accel_smoothing_s;  // the default
  double mean[2] = {0.0, 0.0}, sq[2] = {0.0, 0.0}, sigma[2] = {0.0, 0.0};
  for (int m = 0; m < 2; ++m) {
    for (int r = 0; r < runs; ++r) {
      double sigma_alpha = 0.0;
      const double e = final_alpha_error(m == 0 ? -1.0 : held_s, 100 + r, &sigma_alpha);
      mean[m] += e / runs;
      sq[m] += e * e / runs;
      sigma[m] += sigma_alpha / runs;
    }
  }
  const double se0 = std::sqrt((sq[0] - mean[0] * mean[0]) / (runs - 1));
  const double se1 = std::sqrt((sq[1] - mean[1] * mean[1]) / (runs - 1));
  std::printf("alpha error after %.0f s at rest, mean over %d runs (1/m): each step's reading %.4f +- %.4f "
              "(reported 1-sigma %.3f), held (%.2f s) %.4f +- %.4f (%.3f); prior 1-sigma 0.3\n", seconds, runs,
              mean[0], se0, sigma[0], held_s, mean[1], se1, sigma[1]);
  EXPECT_LT(mean[0], -5.0 * se0) << "the textbook column pulls alpha down (the distance up)...";
  EXPECT_GT(std::abs(mean[0]), 3.0 * sigma[0]) << "...and the filter believes it";
  // Held, the column still carries the noise of the samples before the update, of which the vartheta error
  // keeps a part: the drift is cut, not removed (docs/algorithm.md 2.1), and stays inside the reported sigma.
  EXPECT_LT(std::abs(mean[1]), 0.3 * std::abs(mean[0]));
  EXPECT_LT(std::sqrt(sq[1]), sigma[1]) << "RMS error within the reported 1-sigma";
}

// ImageUpdate::usable counts black and saturated pixels 16 at a time and the rest of each row one by one: the
// count is exact on both sides of input/min_unclipped_ratio, with clipped pixels in the blocks and in the tails.
TEST(ImageCheck, ClippedFractionIsCountedExactly) {
  const CameraModel cam = test_util::syntheticCamera();
  EstimatorParams params;
  params.input.min_unclipped_ratio = 0.25;
  params.input.min_image_contrast_grey = 1.5;
  const ImagePreprocessor pre(cam, params.preprocess);
  const internal::ImageUpdate update(cam, params, pre);
  // 37 x 10 pixels (370): 2 blocks of 16 and a tail of 5 per row. Textured mid-grey, then clipped pixels
  // (alternately 0 and 255) in row-major order, so that they fill blocks and tails alike.
  cv::Mat img(10, 37, CV_8UC1);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) img.at<uint8_t>(y, x) = static_cast<uint8_t>(60 + (x * 7 + y * 13) % 120);
  const int total = img.rows * img.cols;
  const int allowed = total - static_cast<int>(std::ceil(0.25 * total));  // most clipped pixels still usable
  auto clip = [&](int n) {
    cv::Mat m = img.clone();
    for (int i = 0; i < n; ++i) m.at<uint8_t>(i / m.cols, i % m.cols) = (i % 2 == 0) ? 0 : 255;
    return m;
  };
  std::string why;
  EXPECT_TRUE(update.usable(clip(allowed), &why)) << why;
  EXPECT_FALSE(update.usable(clip(allowed + 1), &why));
  EXPECT_NE(why.find("black or saturated"), std::string::npos) << why;
  // Uniform grey: no texture, with the reason.
  why.clear();
  EXPECT_FALSE(update.usable(cv::Mat(10, 37, CV_8UC1, cv::Scalar(128)), &why));
  EXPECT_NE(why.find("no texture"), std::string::npos) << why;
}

// "No texture" (input/min_image_contrast_grey, docs/algorithm.md section 3.1) on the MYNT EYE's 752 x 480 at 180 px:
// a uniform scene under the configured sensor noise (2 grey levels per raw pixel) is refused, with room to spare; a
// faint texture that the old default, 1.5 grey levels, refused (low-contrast ground, a carpet seen from 1.2 m) is
// used.
TEST(ImageCheck, AUniformSceneHasNoTextureAFaintOneHas) {
  const CameraModel cam = myntEyeCamera();
  EstimatorParams params;
  const ImagePreprocessor pre(cam, params.preprocess);
  const internal::ImageUpdate update(cam, params, pre);
  const double s = params.photometric.sensor_noise_grey;
  cv::RNG rng(41);
  const auto working = [&](double texture_std_raw) {
    cv::Mat tex(480, 752, CV_32FC1), noise(480, 752, CV_32FC1);
    rng.fill(tex, cv::RNG::NORMAL, 0.0, 1.0);
    cv::GaussianBlur(tex, tex, cv::Size(0, 0), 8.0);
    cv::Scalar m, sd;
    cv::meanStdDev(tex, m, sd);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, s);
    cv::Mat raw;
    cv::Mat(128.0 + tex * (texture_std_raw / sd[0]) + noise).convertTo(raw, CV_8UC1);  // (rounds)
    PreprocessedFrame f;
    ImagePreprocessor(cam, params.preprocess).process(raw, 0.0, &f);
    return f.gray8.clone();
  };
  const auto greyStd = [](const cv::Mat& g) {
    cv::Scalar m, sd;
    cv::meanStdDev(g, m, sd);
    return sd[0];
  };
  std::string why;
  const cv::Mat uniform = working(0.0), faint = working(1.4);
  std::printf("[no texture] working image's grey-level std: uniform scene %.3f, faint texture %.3f; threshold %.2f\n",
              greyStd(uniform), greyStd(faint), params.input.min_image_contrast_grey);
  EXPECT_LT(greyStd(uniform), 0.6 * params.input.min_image_contrast_grey);  // twice over, nearly
  EXPECT_FALSE(update.usable(uniform, &why));
  EXPECT_NE(why.find("no texture"), std::string::npos) << why;
  EXPECT_LT(greyStd(faint), 1.5);  // the old default's side
  EXPECT_TRUE(update.usable(faint, &why)) << why;
}

}  // namespace
}  // namespace diekf
