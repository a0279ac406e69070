// Ground truth of analytic motions (docs/conventions.md section 2).
#include <cmath>

#include <gtest/gtest.h>

#include "diekf/eval/ground_truth.h"

namespace diekf {
namespace eval {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// Downward camera on a z-up IMU: x_C = x_I, y_C = -y_I, z_C = -z_I, camera centre 5 cm below the IMU origin.
Eigen::Isometry3d downwardCameraExtrinsics() {
  Eigen::Isometry3d T_cam_imu = Eigen::Isometry3d::Identity();
  T_cam_imu.linear() = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  // Camera centre at p_I = (0, 0, -0.05): t_CI = -R_CI p_I = (0, 0, -0.05).
  T_cam_imu.translation() = Eigen::Vector3d(0.0, 0.0, -0.05);
  return T_cam_imu;
}

/// Straight track at constant velocity `v_W` (m/s) and attitude `q`, from t = 100 s.
std::vector<PoseSample> track(double duration_s, double rate_hz, const Eigen::Vector3d& p0, const Eigen::Vector3d& v_W,
                              const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity()) {
  std::vector<PoseSample> poses;
  const int n = static_cast<int>(duration_s * rate_hz) + 1;
  for (int i = 0; i < n; ++i) {
    PoseSample s;
    s.t_s = 100.0 + i / rate_hz;
    s.p_WI_m = p0 + v_W * (s.t_s - 100.0);
    s.q_WI = q;
    poses.push_back(s);
  }
  return poses;
}

TEST(GroundTruth, LevelHoverGivesDownwardNormalAndGravity) {
  const GroundTruth gt(track(2.0, 100.0, Eigen::Vector3d(0.3, -0.2, 1.5), Eigen::Vector3d::Zero()), GroundPlane(),
                       downwardCameraExtrinsics());
  TruthSample t;
  ASSERT_TRUE(gt.at(101.005, &t));
  EXPECT_NEAR(t.d_m, 1.45, 1e-12);  // camera 5 cm below the IMU at 1.5 m
  EXPECT_NEAR(t.h_m, 1.45, 1e-12);
  EXPECT_NEAR((t.mu_C - Eigen::Vector3d(0, 0, 1)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((t.g_C - Eigen::Vector3d(0, 0, 1)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(t.v_C_mps.norm(), 0.0, 1e-12);
}

TEST(GroundTruth, OutsideThePoseStreamHasNoValue) {
  const GroundTruth gt(track(1.0, 100.0, Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::Zero()), GroundPlane(),
                       downwardCameraExtrinsics());
  TruthSample t;
  EXPECT_FALSE(gt.at(99.99, &t));
  EXPECT_FALSE(gt.at(101.01, &t));
  EXPECT_TRUE(gt.at(100.0, &t));
  EXPECT_TRUE(gt.at(101.0, &t));
}

TEST(GroundTruth, ConstantVelocityByCentralDifferencesInCameraFrame) {
  const Eigen::Vector3d v_W(0.4, -0.3, 0.1);
  for (double window_s : {0.0, 0.1}) {
    GroundTruthOptions options;
    options.velocity_window_s = window_s;
    const GroundTruth gt(track(3.0, 200.0, Eigen::Vector3d(0, 0, 1), v_W), GroundPlane(),
                         downwardCameraExtrinsics(), options);
    TruthSample t;
    ASSERT_TRUE(gt.at(101.2345, &t));
    // v_C = R_WC^T v_W with R_WC = diag(1, -1, -1).
    EXPECT_NEAR((t.v_C_mps - Eigen::Vector3d(0.4, 0.3, -0.1)).norm(), 0.0, 1e-9) << "window " << window_s;
    // The distance grows with the climb rate.
    EXPECT_NEAR(t.d_m, 1.0 - 0.05 + 0.1 * 1.2345, 1e-9);
    // Also at the first and last samples (one-sided differences are exact for a straight line).
    ASSERT_TRUE(gt.at(100.0, &t));
    EXPECT_NEAR((t.v_C_mps - Eigen::Vector3d(0.4, 0.3, -0.1)).norm(), 0.0, 1e-9);
  }
}

TEST(GroundTruth, SmoothingWindowAveragesJitter) {
  // Alternating +-1 mm position jitter at 100 Hz: adjacent differences see +-0.1 m/s, a 0.2 s base far less.
  std::vector<PoseSample> poses = track(4.0, 100.0, Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::Zero());
  for (std::size_t i = 0; i < poses.size(); ++i) poses[i].p_WI_m.x() += (i % 2 == 0 ? 1e-3 : -1e-3);
  GroundTruthOptions smooth;
  smooth.velocity_window_s = 0.2;
  const GroundTruth raw(poses, GroundPlane(), downwardCameraExtrinsics());
  const GroundTruth filtered(poses, GroundPlane(), downwardCameraExtrinsics(), smooth);
  TruthSample a, b;
  ASSERT_TRUE(raw.at(102.0, &a));
  ASSERT_TRUE(filtered.at(102.0, &b));
  EXPECT_LT(b.v_C_mps.norm(), 0.25 * a.v_C_mps.norm() + 1e-12);
  EXPECT_LT(b.v_C_mps.norm(), 0.02);
}

TEST(GroundTruth, TiltedPlaneGivesOrthogonalDistanceAndNormal) {
  // Plane through the origin tilted 30 deg about world x; camera level at 2 m above the origin.
  const double a = 30.0 * kPi / 180.0;
  const GroundPlane plane = GroundPlane::inclined(30.0);
  EXPECT_NEAR(plane.n_W.norm(), 1.0, 1e-12);
  Eigen::Isometry3d T_cam_imu = Eigen::Isometry3d::Identity();
  T_cam_imu.linear() = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  const GroundTruth gt(track(1.0, 100.0, Eigen::Vector3d(0, 0, 2.0), Eigen::Vector3d::Zero()), plane, T_cam_imu);
  TruthSample t;
  ASSERT_TRUE(gt.at(100.5, &t));
  EXPECT_NEAR(t.d_m, 2.0 * std::cos(a), 1e-12);
  // Height along gravity is the vertical distance to the plane.
  EXPECT_NEAR(t.h_m, 2.0, 1e-12);
  EXPECT_NEAR(t.mu_C.norm(), 1.0, 1e-12);
  EXPECT_NEAR(std::acos(t.mu_C.dot(t.g_C)), a, 1e-12);
  // mu_C = -R_WC^T n with n = (0, -sin a, cos a), R_WC = diag(1, -1, -1).
  EXPECT_NEAR((t.mu_C - Eigen::Vector3d(0.0, -std::sin(a), std::cos(a))).norm(), 0.0, 1e-12);
  // A plane point P in C satisfies mu . P = d.
  const Eigen::Vector3d P_W(0.0, 1.0, std::tan(a));  // on the plane: -sin a * 1 + cos a * tan a = 0
  const Eigen::Vector3d P_C = T_cam_imu.linear() * (P_W - Eigen::Vector3d(0, 0, 2.0));
  EXPECT_NEAR(t.mu_C.dot(P_C), t.d_m, 1e-12);
}

TEST(GroundTruth, PlaneCoefficientsAreNormalised) {
  const GroundPlane p = GroundPlane::fromCoefficients(0.0, 0.0, 2.0, -1.0);  // z = 0.5
  EXPECT_NEAR(p.n_W.z(), 1.0, 1e-15);
  EXPECT_NEAR(p.e_m, -0.5, 1e-15);
  EXPECT_THROW(GroundPlane::fromCoefficients(0, 0, 0, 1), std::invalid_argument);
  const GroundTruth gt(track(1.0, 50.0, Eigen::Vector3d(0, 0, 2.0), Eigen::Vector3d::Zero()), p,
                       downwardCameraExtrinsics());
  TruthSample t;
  ASSERT_TRUE(gt.at(100.3, &t));
  EXPECT_NEAR(t.d_m, 2.0 - 0.05 - 0.5, 1e-12);
}

TEST(GroundTruth, RotationIsSlerpedBetweenPoses) {
  // Yaw from 0 to 90 deg between two poses: halfway the camera is yawed 45 deg; mu and g stay (0, 0, 1).
  std::vector<PoseSample> poses(2);
  poses[0].t_s = 0.0;
  poses[1].t_s = 1.0;
  poses[0].p_WI_m = poses[1].p_WI_m = Eigen::Vector3d(0, 0, 1);
  poses[1].q_WI = Eigen::Quaterniond(Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()));
  const GroundTruth gt(poses, GroundPlane(), downwardCameraExtrinsics());
  const PoseSample mid = gt.poseAt(0.5);
  EXPECT_NEAR(mid.q_WI.angularDistance(Eigen::Quaterniond::Identity()), kPi / 4, 1e-12);
  TruthSample t;
  ASSERT_TRUE(gt.at(0.5, &t));
  EXPECT_NEAR((t.g_C - Eigen::Vector3d(0, 0, 1)).norm(), 0.0, 1e-12);
  // The camera centre (5 cm below the IMU) is on the yaw axis: still 0.95 m.
  EXPECT_NEAR(t.d_m, 0.95, 1e-12);
}

TEST(GroundTruth, PitchedCameraSeesTiltedGravity) {
  // Pitch the vehicle by 20 deg about world y: gravity in C tilts by 20 deg from the optical axis.
  const double a = 20.0 * kPi / 180.0;
  const Eigen::Quaterniond q(Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()));
  Eigen::Isometry3d T_cam_imu = Eigen::Isometry3d::Identity();
  T_cam_imu.linear() = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  const GroundTruth gt(track(1.0, 100.0, Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d::Zero(), q), GroundPlane(),
                       T_cam_imu);
  TruthSample t;
  ASSERT_TRUE(gt.at(100.5, &t));
  EXPECT_NEAR(std::acos(t.g_C.z()), a, 1e-12);
  EXPECT_NEAR((t.mu_C - t.g_C).norm(), 0.0, 1e-12);  // level ground: normal and gravity coincide
  EXPECT_NEAR(t.d_m, 1.0, 1e-12);
  EXPECT_NEAR(t.h_m, 1.0, 1e-12);
}

TEST(GroundTruth, RejectsTooFewOrNonFinitePoses) {
  std::vector<PoseSample> one(1);
  EXPECT_THROW(GroundTruth(one, GroundPlane(), Eigen::Isometry3d::Identity()), std::invalid_argument);
  std::vector<PoseSample> dup(2);  // same stamp twice
  EXPECT_THROW(GroundTruth(dup, GroundPlane(), Eigen::Isometry3d::Identity()), std::invalid_argument);
  std::vector<PoseSample> nan(3);
  nan[1].t_s = 1.0;
  nan[2].t_s = 2.0;
  nan[2].p_WI_m.x() = std::nan("");
  EXPECT_THROW(GroundTruth(nan, GroundPlane(), Eigen::Isometry3d::Identity()), std::invalid_argument);
}

TEST(GroundTruth, UnsortedInputIsSorted) {
  std::vector<PoseSample> poses = track(1.0, 10.0, Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1.0, 0, 0));
  std::swap(poses[2], poses[7]);
  const GroundTruth gt(poses, GroundPlane(), downwardCameraExtrinsics());
  TruthSample t;
  ASSERT_TRUE(gt.at(100.55, &t));
  EXPECT_NEAR(t.v_C_mps.x(), 1.0, 1e-9);
  EXPECT_NEAR(gt.poseAt(100.55).p_WI_m.x(), 0.55, 1e-12);
}

}  // namespace
}  // namespace eval
}  // namespace diekf
