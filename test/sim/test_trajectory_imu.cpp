// Trajectory derivatives and IMU consistency: dead-reckoning the noise-free IMU reproduces the ground truth.
#include <gtest/gtest.h>

#include <cmath>

#include "diekf/sim/imu_sim.h"
#include "diekf/sim/simulator.h"
#include "diekf/sim/trajectory.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

Trajectory presetTrajectory(const std::string& name, double duration, double incline_deg = 0.0) {
  SimulationOptions o;
  o.preset = name;
  o.duration_s = duration;
  o.seed = 7;
  o.incline_deg = incline_deg;
  return makeTrajectory(o);
}

Eigen::Vector3d logSO3(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

}  // namespace

TEST(Trajectory, DerivativesMatchFiniteDifferences) {
  const Trajectory tr = presetTrajectory("flight6", 30.0);
  const double h = 1e-4;
  for (double t : {0.5, 2.0, 3.7, 9.3, 17.1, 25.0}) {
    const KinematicState a = tr.evaluate(t - h), b = tr.evaluate(t + h), k = tr.evaluate(t);
    EXPECT_LT(((b.p_W - a.p_W) / (2 * h) - k.v_W).norm(), 1e-6) << "t " << t;
    EXPECT_LT(((b.v_W - a.v_W) / (2 * h) - k.a_W).norm(), 1e-5) << "t " << t;
    // w_I from the rotation increment over [t - h, t + h].
    const Eigen::Vector3d w_fd = logSO3(a.R_WI.transpose() * b.R_WI) / (2 * h);
    EXPECT_LT((w_fd - k.w_I).norm(), 1e-5) << "t " << t;
    EXPECT_NEAR(k.R_WI.determinant(), 1.0, 1e-12);
    // Quadrotor-like: body z along the thrust a - g.
    const Eigen::Vector3d thrust = (k.a_W + Eigen::Vector3d(0, 0, kGravityMps2)).normalized();
    EXPECT_LT((k.R_WI.col(2) - thrust).norm(), 1e-12);
  }
}

TEST(Trajectory, StartsFromHoverAndStaysAboveInclinedPlane) {
  const Trajectory tr = presetTrajectory("flight7", 60.0, 25.0);
  const KinematicState k0 = tr.evaluate(0.0);
  EXPECT_LT(k0.v_W.norm(), 1e-12);
  EXPECT_LT(k0.w_I.norm(), 1e-12);
  EXPECT_NEAR(k0.f_I.z(), kGravityMps2, 1e-9);  // specific force at rest: +g along body up
  const SpeedStats st = tr.stats(100.0);
  EXPECT_GT(st.min_height_m, 0.3);
  EXPECT_LT(st.max_height_m, 1.6);
}

TEST(Trajectory, TakeOffRestsClimbsThenFlies) {
  SimulationOptions o;
  o.preset = "flight4";
  o.duration_s = 20.0;
  o.seed = 7;
  o.takeoff_from_m = 0.08;
  const Trajectory tr = makeTrajectory(o);
  // At rest on the ground for 2 s, at the preset's height after the 3 s climb.
  for (double t : {0.0, 1.0, 1.99}) {
    const KinematicState k = tr.evaluate(t);
    EXPECT_NEAR(k.p_W.z(), 0.08, 1e-9) << t;
    EXPECT_LT(k.v_W.norm(), 1e-9) << t;
  }
  EXPECT_NEAR(tr.evaluate(5.0).p_W.z(), tr.params().height_m, 1e-9);
  EXPECT_GT(tr.evaluate(3.5).v_W.z(), 0.2);  // climbing
  // The climb's derivatives are consistent (the IMU is generated from them).
  const double h = 1e-4;
  for (double t : {2.3, 3.5, 4.6, 9.0}) {
    const KinematicState a = tr.evaluate(t - h), b = tr.evaluate(t + h), k = tr.evaluate(t);
    EXPECT_LT(((b.p_W - a.p_W) / (2 * h) - k.v_W).norm(), 1e-6) << "t " << t;
    EXPECT_LT(((b.v_W - a.v_W) / (2 * h) - k.a_W).norm(), 1e-5) << "t " << t;
  }
}

TEST(Trajectory, PresetsReachTheirTargetSpeeds) {
  for (const PresetSpec& p : presetSpecs()) {
    if (p.rms_speed_mps <= 0.0) continue;
    SimulationOptions o;
    o.preset = p.name;
    const SpeedStats st = makeTrajectory(o).stats(100.0);
    EXPECT_NEAR(st.rms_mps, p.rms_speed_mps, 0.02 * p.rms_speed_mps) << p.name;
    EXPECT_NEAR(st.max_mps, p.max_speed_mps, 0.02 * p.max_speed_mps) << p.name;
    EXPECT_GT(st.min_height_m, 0.35) << p.name;
    EXPECT_LT(st.max_height_m, 1.35) << p.name;
  }
}

TEST(Trajectory, SeedChangesTheFlight) {
  SimulationOptions o;
  o.preset = "flight3";
  o.seed = 1;
  const KinematicState a = makeTrajectory(o).evaluate(20.0);
  o.seed = 2;
  const KinematicState b = makeTrajectory(o).evaluate(20.0);
  EXPECT_GT((a.p_W - b.p_W).norm(), 1e-3);
  o.seed = 1;
  const KinematicState c = makeTrajectory(o).evaluate(20.0);
  EXPECT_EQ((a.p_W - c.p_W).norm(), 0.0);
}

// Drift bound: 10 s of trapezoidal dead reckoning at 500 Hz on exact readings stays within 5 mm and 0.01 deg.
TEST(Imu, NoiseFreeDeadReckoningReproducesGroundTruth) {
  const Trajectory tr = presetTrajectory("flight6", 20.0);
  ImuSimOptions opt;
  opt.errors = false;
  const ImuSimResult imu = simulateImu(tr, 16.0, opt, 3);
  ASSERT_EQ(imu.samples.size(), 16u * 500u + 1u);
  const std::size_t i0 = 5 * 500, i1 = 15 * 500;  // integrate t = 5 s .. 15 s, in motion
  const KinematicState s0 = tr.evaluate(imu.samples[i0].t_s);
  Eigen::Matrix3d R = s0.R_WI;
  Eigen::Vector3d v = s0.v_W, p = s0.p_W;
  const Eigen::Vector3d g_W(0, 0, -kGravityMps2);
  for (std::size_t i = i0; i < i1; ++i) {
    const ImuSample& a = imu.samples[i];
    const ImuSample& b = imu.samples[i + 1];
    const double dt = b.t_s - a.t_s;
    const Eigen::Matrix3d R1 = R * Eigen::AngleAxisd(0.5 * (a.gyro_radps + b.gyro_radps).norm() * dt,
                                                      (a.gyro_radps + b.gyro_radps).normalized())
                                       .toRotationMatrix();
    const Eigen::Vector3d acc0 = R * a.accel_mps2 + g_W, acc1 = R1 * b.accel_mps2 + g_W;
    const Eigen::Vector3d v1 = v + 0.5 * (acc0 + acc1) * dt;
    p += 0.5 * (v + v1) * dt;
    v = v1;
    R = R1;
  }
  const KinematicState s1 = tr.evaluate(imu.samples[i1].t_s);
  const double travelled = (s1.p_W - s0.p_W).norm();
  EXPECT_GT(travelled, 0.2);  // the test really moves
  EXPECT_LT((p - s1.p_W).norm(), 0.005);
  EXPECT_LT((v - s1.v_W).norm(), 0.002);
  EXPECT_LT(logSO3(R.transpose() * s1.R_WI).norm() * 180.0 / M_PI, 0.01);
}

TEST(Imu, ErrorsHaveTheRequestedSizes) {
  const Trajectory tr = presetTrajectory("hover", 20.0);
  ImuSimOptions exact;
  exact.errors = false;
  ImuSimOptions noisy;
  noisy.vibration.enabled = false;
  const auto a = simulateImu(tr, 20.0, exact, 5), b = simulateImu(tr, 20.0, noisy, 5);
  // Gyro white noise: sample std ~ density * sqrt(rate) (bias is slow and subtracted via differences).
  double s2 = 0;
  for (std::size_t i = 1; i < a.samples.size(); ++i) {
    const Eigen::Vector3d e1 = b.samples[i].gyro_radps - a.samples[i].gyro_radps;
    const Eigen::Vector3d e0 = b.samples[i - 1].gyro_radps - a.samples[i - 1].gyro_radps;
    s2 += (e1 - e0).squaredNorm() / 2.0 / 3.0;
  }
  const double sd = std::sqrt(s2 / (a.samples.size() - 1));
  const double expected = noisy.noise.gyro_noise_density * std::sqrt(noisy.noise.rate_hz);
  EXPECT_NEAR(sd, expected, 0.05 * expected);
  // Initial biases are drawn and reported.
  EXPECT_GT(b.gyro_bias0.norm(), 0.0);
  // Mean error over the first 0.1 s is the initial bias (white noise averages to ~0.006 m/s^2 per axis).
  Eigen::Vector3d mean_err = Eigen::Vector3d::Zero();
  for (int i = 0; i < 50; ++i) mean_err += (b.samples[i].accel_mps2 - a.samples[i].accel_mps2) / 50.0;
  EXPECT_LT((mean_err - b.accel_bias0).norm(), 0.03);
  EXPECT_GT(b.accel_bias0.norm(), 0.0);
  // Vibration: with it on, the accelerometer shows 100-200 Hz content of about the set amplitude.
  ImuSimOptions vib;
  vib.noise.accel_noise_density = 0;
  vib.noise.accel_random_walk = 0;
  vib.noise.accel_bias_sigma = 0;
  const auto c = simulateImu(tr, 2.0, vib, 5);
  double peak = 0;
  for (std::size_t i = 0; i < c.samples.size(); ++i)
    peak = std::max(peak, (c.samples[i].accel_mps2 - a.samples[i].accel_mps2).cwiseAbs().maxCoeff());
  EXPECT_GT(peak, 0.5 * vib.vibration.accel_amplitude_mps2);
  EXPECT_LT(peak, 2.5 * vib.vibration.accel_amplitude_mps2);
}
