// End-to-end check of the whole core: a short flight over a textured level plane is rendered inside the test
// (no external files), the matching 500 Hz IMU is generated analytically, both are fed to the Estimator in a
// realistic interleaving, and distance and velocity must converge to the truth.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/estimator.h"

namespace diekf {
namespace {

constexpr double kGravity = 9.81;

/// Analytic IMU trajectory in W (z up): position, velocity, acceleration, attitude about a fixed axis.
struct Flight {
  Vec3 axis = Vec3(1.0, 0.6, 0.2).normalized();
  double height_m = 0.9;

  Vec3 position(double t) const {
    return Vec3(0.4 * std::sin(0.9 * t), 0.3 * std::sin(0.7 * t + 0.5), height_m + 0.25 * std::sin(0.5 * t));
  }
  Vec3 velocity(double t) const {
    return Vec3(0.36 * std::cos(0.9 * t), 0.21 * std::cos(0.7 * t + 0.5), 0.125 * std::cos(0.5 * t));
  }
  Vec3 acceleration(double t) const {
    return Vec3(-0.324 * std::sin(0.9 * t), -0.147 * std::sin(0.7 * t + 0.5), -0.0625 * std::sin(0.5 * t));
  }
  double angle(double t) const { return 0.08 * std::sin(1.3 * t); }
  double angleRate(double t) const { return 0.08 * 1.3 * std::cos(1.3 * t); }
  Mat3 R_WI(double t) const { return Eigen::AngleAxisd(angle(t), axis).toRotationMatrix(); }
  /// Body rate about a fixed axis: omega_I = theta'(t) axis.
  Vec3 gyro_I(double t) const { return angleRate(t) * axis; }
  /// Specific force f_I = R_WI^T (a_W - g_W), g_W = (0, 0, -g).
  Vec3 accel_I(double t) const { return R_WI(t).transpose() * (acceleration(t) + Vec3(0, 0, kGravity)); }
};

/// Smooth texture on the plane z = 0 (sum of sinusoids, wavelengths 6-40 cm), grey levels 0-255.
double texture(double X, double Y) {
  static const double k[6][3] = {{2 * M_PI / 0.40, 0.3, 0.0},  {2 * M_PI / 0.23, 1.9, 1.3},
                                  {2 * M_PI / 0.15, 0.8, 2.1}, {2 * M_PI / 0.11, 2.6, 0.4},
                                  {2 * M_PI / 0.08, 4.0, 5.0}, {2 * M_PI / 0.06, 5.3, 3.3}};
  double v = 128.0;
  for (const auto& c : k) v += 20.0 * std::sin(c[0] * (std::cos(c[1]) * X + std::sin(c[1]) * Y) + c[2]);
  return std::min(255.0, std::max(0.0, v));
}

/// Renders the level plane seen by a pinhole camera with pose (R_WC, p_WC), 2x2 supersampled.
void render(const CameraModel& cam, const Mat3& R_WC, const Vec3& p_WC, cv::Mat* out) {
  out->create(cam.K.height, cam.K.width, CV_8UC1);
  for (int v = 0; v < cam.K.height; ++v) {
    for (int u = 0; u < cam.K.width; ++u) {
      double sum = 0.0;
      for (int s = 0; s < 4; ++s) {
        const double uu = u - 0.25 + 0.5 * (s & 1), vv = v - 0.25 + 0.5 * (s >> 1);
        const Vec3 ray = R_WC * Vec3((uu - cam.K.cx) / cam.K.fx, (vv - cam.K.cy) / cam.K.fy, 1.0);
        const double lambda = -p_WC.z() / ray.z();
        const Vec3 X = p_WC + lambda * ray;
        sum += texture(X.x(), X.y());
      }
      out->at<uint8_t>(v, u) = static_cast<uint8_t>(std::lround(sum / 4.0));
    }
  }
}

/// A downward camera (quarter of the MYNT EYE resolution, no distortion) rotated 90 deg about its axis
/// relative to the IMU (IMU x forward, y left, z up), a few cm away.
CameraModel makeCamera() {
  CameraModel cam;
  cam.K.width = 188;
  cam.K.height = 120;
  cam.K.fx = 91.2;
  cam.K.fy = 91.2;
  cam.K.cx = 94.5;
  cam.K.cy = 61.0;
  cam.distortion = DistortionModel::kNone;
  Mat3 R_CI;
  R_CI << 0, -1, 0,  //
      -1, 0, 0,      //
      0, 0, -1;
  const Vec3 r_I(0.03, 0.0, -0.02);  // camera centre in the IMU frame, m
  cam.T_cam_imu.linear() = R_CI;
  cam.T_cam_imu.translation() = -R_CI * r_I;
  return cam;
}

struct Truth {
  double d_m;
  Vec3 v_C;
};

Truth truthAt(const Flight& f, const CameraModel& cam, double t) {
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();
  const Mat3 R_WI = f.R_WI(t);
  const Mat3 R_WC = R_WI * R_IC;
  const Vec3 p_WC = f.position(t) + R_WI * r_I;
  const Vec3 v_WC = f.velocity(t) + (R_WI * f.gyro_I(t)).cross(R_WI * r_I);
  return {p_WC.z(), R_WC.transpose() * v_WC};
}

/// Arrival lag of the IMU stream relative to the images, s: positive = IMU data arrives late (behind the images),
/// negative = the images arrive late (IMU ahead).
class EndToEnd : public ::testing::TestWithParam<double> {};

TEST_P(EndToEnd, DistanceAndVelocityConvergeOnSyntheticFlight) {
  const double imu_lag_s = GetParam();
  const Flight flight;
  const CameraModel cam = makeCamera();
  EstimatorParams params;  // the paper's initial values: alpha0 = 10 /m (d0 = 0.1 m, truth ~0.9 m)
  params.preprocess.working_width_px = 90;
  Estimator estimator(cam, params);

  const double duration_s = 10.0, imu_rate_hz = 500.0, cam_rate_hz = 30.0;
  const int n_imu = static_cast<int>(duration_s * imu_rate_hz);
  const int n_img = static_cast<int>((duration_s - 0.1) * cam_rate_hz);
  const Mat3 R_IC = cam.R_CI().transpose();
  const Vec3 r_I = -R_IC * cam.t_CI();
  cv::Mat image;
  std::vector<FrameResult> results;
  // Merge the two streams by arrival time: IMU sample k arrives at t_k + max(lag, 0), image j at t_j + max(-lag, 0).
  int k = 0, j = 0;
  while (k < n_imu || j < n_img) {
    const double t_imu = k / imu_rate_hz, t_img = j / cam_rate_hz;
    const double arrive_imu = k < n_imu ? t_imu + std::max(imu_lag_s, 0.0) : 1e9;
    const double arrive_img = j < n_img ? t_img + std::max(-imu_lag_s, 0.0) : 1e9;
    if (arrive_imu <= arrive_img) {
      estimator.addImu({t_imu, flight.accel_I(t_imu), flight.gyro_I(t_imu)});
      ++k;
    } else {
      const Mat3 R_WI = flight.R_WI(t_img);
      render(cam, R_WI * R_IC, flight.position(t_img) + R_WI * r_I, &image);
      EXPECT_TRUE(estimator.addImage(t_img, image));
      ++j;
    }
    FrameResult r;
    while (estimator.popResult(&r)) results.push_back(r);
  }
  ASSERT_GT(results.size(), 250u);

  double sq_d = 0.0, sq_v = 0.0;
  int n = 0, tracking = 0;
  for (const FrameResult& r : results) {
    ASSERT_TRUE(r.state.allFinite());
    if (r.status == FilterStatus::kTracking) ++tracking;
    EXPECT_NE(r.status, FilterStatus::kReset) << r.message;
    const Truth truth = truthAt(flight, cam, r.t_s);
    if (std::getenv("DIEKF_E2E_TRACE") != nullptr) {
      std::printf("t %.2f d %.3f/%.3f v (%.3f %.3f %.3f)/(%.3f %.3f %.3f) sd %.3f passes %d rms %.3f valid %.2f %s\n", r.t_s,
                  r.distance_m(), truth.d_m, r.velocity_mps().x(), r.velocity_mps().y(), r.velocity_mps().z(),
                  truth.v_C.x(), truth.v_C.y(), truth.v_C.z(), r.sigma_distance_m(), r.passes, r.photometric_rms, r.valid_ratio,
                  toString(r.status));
    }
    if (r.t_s < 5.0) continue;
    sq_d += std::pow(r.distance_m() - truth.d_m, 2);
    sq_v += (r.velocity_mps() - truth.v_C).squaredNorm();
    ++n;
  }
  const double rmse_d = std::sqrt(sq_d / n), rmse_v = std::sqrt(sq_v / n);
  std::printf("[end-to-end] IMU lag %+.0f ms: frames %zu, tracking %d, from 5 s: distance RMSE %.2f cm, velocity RMSE %.2f cm/s\n",
              1000.0 * imu_lag_s, results.size(), tracking, 100.0 * rmse_d, 100.0 * rmse_v);
  EXPECT_GT(tracking, static_cast<int>(results.size()) / 2);  // converged (sigma_d/d < 15 %) within 5 s
  EXPECT_LT(rmse_d, 0.05);  // 5 cm at ~0.9 m
  EXPECT_LT(rmse_v, 0.05);  // 5 cm/s, speeds up to ~0.45 m/s
}

// IMU 100 ms ahead of the images, and 100 ms behind them.
INSTANTIATE_TEST_SUITE_P(Interleavings, EndToEnd, ::testing::Values(-0.1, 0.1));

}  // namespace
}  // namespace diekf
