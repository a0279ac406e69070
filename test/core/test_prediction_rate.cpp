// Prediction accuracy against the step size, isolated from the images: a noise-free 500 Hz IMU of an analytic
// flight goes through the estimator's IMU path (ImuPreprocessor: rotation into C, lever arm, low-pass,
// decimation, delay-compensated stamps; then internal::forEachImuPiece + predict, as Estimator::propagateTo),
// and the propagated state and the inter-frame gyro rotation are compared with the truth at 30 Hz image times,
// decimated to 100 Hz (the default) and not decimated (500 Hz). docs/algorithm.md §2, docs/results.md
// ("Prediction rate").
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "../../src/core/imu_propagation.h"
#include "diekf/imu_filter.h"
#include "diekf/prediction.h"
#include "synthetic_flight.h"

namespace diekf {
namespace {

constexpr double kG0 = 9.81;  // m/s^2

/// A fast flight (about the benchmark's flight 6-7): speeds up to ~1.3 m/s, accelerations ~2 m/s^2, roll and
/// pitch 0.2 rad at 0.45 Hz (rates ~0.6 rad/s), yaw 0.5 rad at 0.2 Hz, height 0.6-1.2 m. W: z up, the plane z = 0.
struct FastFlight {
  Vec3 position(double t) const {
    return Vec3(0.5 * std::sin(2.0 * t), 0.4 * std::sin(1.6 * t + 0.5), 0.9 + 0.3 * std::sin(2.1 * t));
  }
  Vec3 velocity(double t) const {
    return Vec3(1.0 * std::cos(2.0 * t), 0.64 * std::cos(1.6 * t + 0.5), 0.63 * std::cos(2.1 * t));
  }
  Vec3 acceleration(double t) const {
    return Vec3(-2.0 * std::sin(2.0 * t), -1.024 * std::sin(1.6 * t + 0.5), -1.323 * std::sin(2.1 * t));
  }
  /// Yaw, pitch, roll (rad) and their rates (rad/s); R_WI = Rz(yaw) Ry(pitch) Rx(roll).
  void euler(double t, Vec3* e, Vec3* de) const {
    *e = Vec3(0.5 * std::sin(1.3 * t), 0.2 * std::sin(3.0 * t + 1.0), 0.2 * std::sin(2.7 * t + 2.0));
    *de = Vec3(0.65 * std::cos(1.3 * t), 0.6 * std::cos(3.0 * t + 1.0), 0.54 * std::cos(2.7 * t + 2.0));
  }
  Mat3 R_WI(double t) const {
    Vec3 e, de;
    euler(t, &e, &de);
    return (Eigen::AngleAxisd(e(0), Vec3::UnitZ()) * Eigen::AngleAxisd(e(1), Vec3::UnitY()) *
            Eigen::AngleAxisd(e(2), Vec3::UnitX()))
        .toRotationMatrix();
  }
  /// Body rate in I (exact): Rx^T Ry^T (0, 0, yaw') + Rx^T (0, pitch', 0) + (roll', 0, 0).
  Vec3 gyro_I(double t) const {
    Vec3 e, de;
    euler(t, &e, &de);
    const Mat3 Rx = Eigen::AngleAxisd(e(2), Vec3::UnitX()).toRotationMatrix();
    const Mat3 Ry = Eigen::AngleAxisd(e(1), Vec3::UnitY()).toRotationMatrix();
    return Rx.transpose() * (Ry.transpose() * Vec3(0, 0, de(0)) + Vec3(0, de(1), 0)) + Vec3(de(2), 0, 0);
  }
  ImuSample imuSample(double t) const {
    return {t, R_WI(t).transpose() * (acceleration(t) + Vec3(0, 0, kG0)), gyro_I(t)};
  }
};

struct Truth {
  State x;    // biases zero
  Mat3 R_WC;  // camera attitude
};

Truth truthAt(const FastFlight& f, const CameraModel& cam, double t) {
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();  // camera centre in I, m
  const Mat3 R_WI = f.R_WI(t);
  Truth tr;
  tr.R_WC = R_WI * R_IC;
  const Vec3 p_WC = f.position(t) + R_WI * r_I;
  const Vec3 v_WC = f.velocity(t) + (R_WI * f.gyro_I(t)).cross(R_WI * r_I);
  tr.x.alpha = 1.0 / p_WC.z();
  tr.x.vartheta = tr.R_WC.transpose() * v_WC * tr.x.alpha;
  tr.x.mu = UnitVector(tr.R_WC.transpose() * Vec3(0, 0, -1));  // camera -> plane
  tr.x.g = UnitVector(tr.R_WC.transpose() * Vec3(0, 0, -1));
  return tr;
}

/// The filtered samples of the flight's raw 500 Hz IMU over [0, duration_s] with the given decimation.
std::vector<ImuSample> filteredImu(const FastFlight& f, const CameraModel& cam, int decimation, double duration_s) {
  ImuParams ip;
  ip.decimation_factor = decimation;
  ImuPreprocessor pre(cam.T_cam_imu, ip);
  std::vector<ImuSample> out;
  ImuSample s;
  for (int k = 0; k <= static_cast<int>(duration_s * ip.input_rate_hz); ++k) {
    if (pre.push(f.imuSample(k / ip.input_rate_hz), &s)) out.push_back(s);
  }
  return out;
}

/// Estimator::propagateTo without gaps: x, P from t0 to t1; adds the gyro integral (rad).
void propagate(const std::vector<ImuSample>& buf, int decimation, double t0_s, double t1_s, State* x, ErrorCov* P,
               Vec3* gyro_integral) {
  const ImuParams imu;
  const ProcessNoiseParams process;
  const double nominal_dt_s = decimation / imu.input_rate_hz;
  internal::forEachImuPiece(buf, t0_s, t1_s, 2.0 * nominal_dt_s, [&](double a_s, double b_s, const ImuSample& s) {
    predict(s.accel_mps2, s.gyro_radps, b_s - a_s, imu, process, x, P);
    *gyro_integral += s.gyro_radps * (b_s - a_s);
  });
}

struct RateErrors {
  double velocity_mps = 0.0;  // RMS
  double distance_m = 0.0;
  double gravity_rad = 0.0;
  double rotation_rad = 0.0;  // inter-frame rotation exp(gyro integral) against the true one
};

/// RMS errors of the prediction over `horizon_s` started from the truth at 30 Hz image times (as between two
/// images: to the interval's midpoint, then on to the image).
RateErrors predictionErrors(int decimation, double horizon_s) {
  const FastFlight f;
  const CameraModel cam = test_util::syntheticCamera();
  const double duration_s = 24.0;
  const std::vector<ImuSample> buf = filteredImu(f, cam, decimation, duration_s);
  RateErrors e;
  int n = 0;
  // Image times off the IMU grid (the filter delay shifts the sample stamps as well).
  for (double t0 = 2.0123; t0 + horizon_s < duration_s - 0.5; t0 += 1.0 / 30.0) {
    const double t1 = t0 + horizon_s;
    const Truth a = truthAt(f, cam, t0), b = truthAt(f, cam, t1);
    State x = a.x;
    ErrorCov P = ErrorCov::Identity() * 1e-4;
    Vec3 gyro_integral = Vec3::Zero();
    propagate(buf, decimation, t0, 0.5 * (t0 + t1), &x, &P, &gyro_integral);
    propagate(buf, decimation, 0.5 * (t0 + t1), t1, &x, &P, &gyro_integral);
    e.velocity_mps += (x.velocity_mps() - b.x.velocity_mps()).squaredNorm();
    e.distance_m += std::pow(x.distance_m() - b.x.distance_m(), 2);
    e.gravity_rad += x.g.boxminus(b.x.g).squaredNorm();
    const Eigen::AngleAxisd rot_err(Mat3((a.R_WC.transpose() * b.R_WC).transpose() * expSO3(gyro_integral)));
    e.rotation_rad += rot_err.angle() * rot_err.angle();
    ++n;
  }
  e.velocity_mps = std::sqrt(e.velocity_mps / n);
  e.distance_m = std::sqrt(e.distance_m / n);
  e.gravity_rad = std::sqrt(e.gravity_rad / n);
  e.rotation_rad = std::sqrt(e.rotation_rad / n);
  return e;
}

void print(const char* what, const RateErrors& e) {
  std::printf("%-20s velocity %.3g m/s  distance %.3g m  gravity %.3g rad", what, e.velocity_mps, e.distance_m,
              e.gravity_rad);
  if (e.rotation_rad > 0.0) std::printf("  inter-frame rotation %.3g rad", e.rotation_rad);
  std::printf("\n");
}

TEST(PredictionRate, MeanImuOverIsTheIntegralOfTheInterpolation) {
  const ImuSample p{1.0, Vec3(1, 2, 3), Vec3(0.1, 0.2, 0.3)};
  const ImuSample q{1.01, Vec3(2, 0, 3), Vec3(0.3, 0.2, -0.1)};
  const ImuSample m = meanImuOver(p, q, 1.002, 1.006);  // midpoint 1.004: 40 % of the way
  EXPECT_LT((m.accel_mps2 - Vec3(1.4, 1.2, 3.0)).norm(), 1e-12);
  EXPECT_LT((m.gyro_radps - Vec3(0.18, 0.2, 0.14)).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(m.t_s, 1.006);
}

TEST(PredictionRate, PiecesCoverTheIntervalAndHoldAcrossAGap) {
  // Samples every 10 ms, then a 100 ms gap. A linear gyro signal w(t) = t is integrated exactly where the
  // samples are dense; across the gap the sample after it is held.
  std::vector<ImuSample> buf;
  for (int k = 0; k <= 10; ++k) buf.push_back({0.01 * k, Vec3::Zero(), Vec3(0.01 * k, 0, 0)});
  buf.push_back({0.2, Vec3::Zero(), Vec3(0.2, 0, 0)});
  double covered_s = 0.0, integral = 0.0;
  int pieces = 0;
  const double reached = internal::forEachImuPiece(buf, 0.013, 0.095, 0.02, [&](double a, double b, const ImuSample& s) {
    covered_s += b - a;
    integral += s.gyro_radps.x() * (b - a);
    ++pieces;
  });
  EXPECT_DOUBLE_EQ(reached, 0.095);
  EXPECT_NEAR(covered_s, 0.095 - 0.013, 1e-15);
  EXPECT_NEAR(integral, 0.5 * (0.095 * 0.095 - 0.013 * 0.013), 1e-15);
  EXPECT_EQ(pieces, 9);  // (0.013, 0.02], ..., (0.09, 0.095]
  integral = 0.0;
  internal::forEachImuPiece(buf, 0.1, 0.2, 0.02,
                            [&](double a, double b, const ImuSample& s) { integral += s.gyro_radps.x() * (b - a); });
  EXPECT_NEAR(integral, 0.2 * 0.1, 1e-15);  // held, not interpolated across the gap
  // Nothing after the last sample.
  const double end = internal::forEachImuPiece(buf, 0.19, 0.3, 0.02, [](double, double, const ImuSample&) {});
  EXPECT_DOUBLE_EQ(end, 0.2);
}

TEST(PredictionRate, HundredHertzAsAccurateAsFiveHundredPerFrame) {
  // One image interval (33 ms), started from the truth each frame. Before the fix (sample k held over
  // (t_{k-1}, t_k], forward Euler with the S^2 steps projected) this gave at 100 / 500 Hz: velocity 1.8e-3 /
  // 3.9e-4 m/s, distance 1.4e-4 / 3.3e-5 m, gravity 2.8e-4 / 5.7e-5 rad, rotation 2.9e-4 / 5.9e-5 rad: errors
  // proportional to the step, like a time error of a few ms (docs/results.md, "Prediction rate").
  const RateErrors e100 = predictionErrors(5, 1.0 / 30.0);
  const RateErrors e500 = predictionErrors(1, 1.0 / 30.0);
  print("100 Hz, one frame:", e100);
  print("500 Hz, one frame:", e500);
  // Against the truth: far below what the images resolve (and 60x below the old 500 Hz errors).
  for (const RateErrors* e : {&e100, &e500}) {
    EXPECT_LT(e->velocity_mps, 1.5e-5);
    EXPECT_LT(e->distance_m, 2e-6);
    EXPECT_LT(e->gravity_rad, 3e-6);
    EXPECT_LT(e->rotation_rad, 1e-5);
  }
  // 100 Hz against 500 Hz: the step no longer matters (what remains is the low-pass and the lever-arm
  // difference, common to both rates).
  EXPECT_LT(e100.velocity_mps, 1.5 * e500.velocity_mps);
  EXPECT_LT(e100.rotation_rad, 1.5 * e500.rotation_rad);
  EXPECT_LT(e100.distance_m - e500.distance_m, 1e-6);
  EXPECT_LT(e100.gravity_rad - e500.gravity_rad, 2e-6);
}

TEST(PredictionRate, HundredHertzDeadReckoningOverOneSecond) {
  // One second without images. Before the fix: 100 / 500 Hz velocity 3.9e-2 / 7.9e-3 m/s, distance 5.3e-3 /
  // 1.1e-3 m, gravity 5.5e-3 / 1.1e-3 rad.
  RateErrors e100 = predictionErrors(5, 1.0);
  RateErrors e500 = predictionErrors(1, 1.0);
  e100.rotation_rad = e500.rotation_rad = 0.0;  // one exp of a 1 s gyro integral is not the rotation: not shown
  print("100 Hz, one second:", e100);
  print("500 Hz, one second:", e500);
  for (const RateErrors* e : {&e100, &e500}) {
    EXPECT_LT(e->velocity_mps, 5e-4);
    EXPECT_LT(e->distance_m, 1e-4);
    EXPECT_LT(e->gravity_rad, 5e-5);
  }
  EXPECT_LT(e100.velocity_mps, 3.0 * e500.velocity_mps);
}

}  // namespace
}  // namespace diekf
