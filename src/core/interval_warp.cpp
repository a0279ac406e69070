// The warp of an image pair and the derivatives the time states and the focal length need: warpToReference,
// the time offset's and the readout's rates (stateRateMap, timeOffsetMap, shiftedAlong, readoutRowWeights,
// readoutPixelWeights) and the focal-length scale's map (docs/algorithm.md sections 3.2, 3.6-3.8). The per-pixel
// sweep of the photometric update (photometric_update.cpp) builds its single-precision warp from the same
// IntervalWarp.
#include "interval_warp.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>

#include "diekf/photometric_update.h"
#include "expected_value.h"

namespace diekf {

// -------------------------------------------------------------------------------------------------------------
// Warp (docs/algorithm.md §3.2, without its first-order approximations in time). Over the image interval the camera
// turns at the constant rate w = gyro - b_w and moves at constant velocity; the state (vartheta, mu) refers to
// the time `lag` before the current image (0: the current image; dt/2: the interval's midpoint, the default
// of the estimator). With rotations E = exp(dt [w]x) (current -> reference), E_a = exp(lag [w]x) (current ->
// state) and E_b = exp((dt - lag) [w]x) (state -> reference), a world point on the plane seen along the
// current ray q = K^-1 p (q_z = 1) is seen in the reference camera along
//   Q = E q + c (b . q) a,   a = E_b vartheta,   b = E_a^T mu,   c = dt / kappa,   kappa = 1 - lag (mu . vartheta)
// and p_r = (fx Q_x / Q_z + cx, fy Q_y / Q_z + cy). To first order in dt this is the paper's
// p_r = p + dt (I - p e_z^T) K ([w]x + vartheta mu^T) K^-1 p; the higher-order terms matter at speed: at
// 76 deg/s and 30 Hz the dropped second-order rotation reads as a scale change, i.e. a velocity error of
// several cm/s along the optical axis, and a state at the midpoint must be moved to the images' times.
// With D_r = [[fx, 0, cx - x_r], [0, fy, cy - y_r]] / Q_z (= dp_r / dQ), s_b = b . q, J(.) the left Jacobian of
// exp and f = lag / dt, the derivatives (checked against finite differences in test_photometric_update.cpp):
//   d p_r / d vartheta = c s_b D_r N,            N = E_b + (lag c / dt) a mu^T
//   d p_r / d mu       = c (D_r a) q^T P,        P = (E_a^T + (lag c / dt) b vartheta^T) M(mu)
//   d p_r / d b_w      = D_r [ dt [E q]x J(dt w) + c s_b (dt - lag) [a]x J((dt - lag) w)
//                              + c lag a (mu x E_a q)^T J(lag w) ]
// Rays that do not stay in front of the reference camera (Q_z <= kMinDepthRatio), or kappa <= kMinKappa
// (the plane reached within the interval), give NaN: no measurement.
// -------------------------------------------------------------------------------------------------------------
namespace internal {

IntervalWarp::IntervalWarp(const State& x, const Vec3& gyro_mean_C, double dt_s, double state_lag_s) {
  dt = dt_s;
  lag = std::min(std::max(state_lag_s, 0.0), dt_s);
  const Vec3 w = gyro_mean_C - x.b_w;  // rad/s
  E = expSO3(dt * w);
  Ea = expSO3(lag * w);
  const Mat3 Eb = expSO3((dt - lag) * w);
  J = leftJacobianSO3(dt * w);
  Ja = leftJacobianSO3(lag * w);
  Jb = leftJacobianSO3((dt - lag) * w);
  mu = x.mu.vector();
  a = Eb * x.vartheta;
  b = Ea.transpose() * mu;
  kappa = 1.0 - lag * mu.dot(x.vartheta);
  ok = kappa > kMinKappa && dt > 0.0;
  c = ok ? dt / kappa : 0.0;
  const double k = ok ? lag * c / dt : 0.0;
  H = E + c * a * b.transpose();
  N = Eb + k * a * mu.transpose();
  P = (Ea.transpose() + k * b * x.vartheta.transpose()) * x.mu.M();
}

}  // namespace internal

using internal::IntervalWarp;
using internal::kMinDepthRatio;
using internal::warpWith;

Vec3 stateRateAcceleration(const State& x, const ImageTiming& in, bool expected) {
  if (!in.rates_valid) return Vec3::Zero();
  const Vec3 accel = in.accel_C - x.b_a + in.gravity_mps2 * x.g.vector();  // m/s^2
  return expected ? internal::expectedGivenReading(accel, in.accel_noise_var) : accel;
}

ObservedVec stateRateMap(const State& x, const Vec3& gyro_mean_C, const ImageTiming& in, double dt_s,
                         bool expected) {
  ObservedVec m = ObservedVec::Zero();
  if (!in.rates_valid || !(dt_s > 0.0)) return m;
  const Vec3 w = gyro_mean_C - x.b_w;   // rad/s
  const Vec3& th = x.vartheta;
  const Vec3 accel = stateRateAcceleration(x, in, expected);  // m/s^2
  Vec3 rate_change = in.rate_change_C;                        // rad/s
  if (expected)
    rate_change = internal::expectedGivenReading(rate_change, in.rate_change_noise_var, in.rate_change_mean_sq);
  m.segment<3>(0) = x.alpha * accel - w.cross(th) + x.mu.vector().dot(th) * th;
  m.segment<2>(3) = -x.mu.N().transpose() * w;
  m.segment<3>(5) = -rate_change / dt_s;
  return m;
}

ObservedVec timeOffsetMap(const State& x, const Vec3& gyro_mean_C, const ImageTiming& in, double dt_s) {
  // The readings' expected values given their noise (as for the readout's rows): in slow flight the rate change
  // between the images is mostly the gyro's noise, and with the readings as they are the offset was pulled toward
  // its current value with a 1-sigma that fell regardless (errors in the variables; docs/algorithm.md section 3.6).
  return in.estimate_offset || in.consider_offset ? stateRateMap(x, gyro_mean_C, in, dt_s, true) : ObservedVec::Zero();
}

std::vector<float> readoutRowWeights(const CameraModel& cam, const PinholeK& K_working) {
  std::vector<float> w(static_cast<size_t>(std::max(0, K_working.height)), 0.0f);
  if (cam.K.height < 2 || !(K_working.fx > 0.0) || !(K_working.fy > 0.0)) return w;
  const double v_mid = 0.5 * (cam.K.height - 1), span = cam.K.height - 1;
  for (int y = 0; y < K_working.height; ++y) {
    double sum = 0.0;
    int n = 0;
    for (int x = 0; x < K_working.width; ++x) {
      const Vec2 xn((x - K_working.cx) / K_working.fx, (y - K_working.cy) / K_working.fy);
      const Vec2 xd = cam.distort(xn);
      const double v = cam.K.fy * xd.y() + cam.K.cy;  // raw row of the working pixel
      if (!std::isfinite(v) || v < -0.5 || v > cam.K.height - 0.5) continue;
      sum += v;
      ++n;
    }
    // Rows without a pixel inside the raw image (none in practice): the pinhole row.
    const double v = n > 0 ? sum / n : cam.K.cy + (y - K_working.cy) * cam.K.fy / K_working.fy;
    w[static_cast<size_t>(y)] = static_cast<float>((v - v_mid) / span);
  }
  return w;
}

cv::Mat readoutPixelWeights(const CameraModel& cam, const PinholeK& K_working) {
  const int W = std::max(0, K_working.width), H = std::max(0, K_working.height);
  cv::Mat out(kReadoutPixelPlanes * H, W, CV_32FC1, cv::Scalar(0.0f));
  if (cam.K.height < 2 || W < 2 || H < 2 || !(K_working.fx > 0.0) || !(K_working.fy > 0.0)) return out;
  const std::vector<float> rows = readoutRowWeights(cam, K_working);
  const double v_mid = 0.5 * (cam.K.height - 1), span = cam.K.height - 1;
  cv::Mat w(H, W, CV_64FC1);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Vec2 xn((x - K_working.cx) / K_working.fx, (y - K_working.cy) / K_working.fy);
      const double v = cam.K.fy * cam.distort(xn).y() + cam.K.cy;  // raw row of the working pixel
      w.at<double>(y, x) = std::isfinite(v) ? (v - v_mid) / span : static_cast<double>(rows[static_cast<size_t>(y)]);
    }
  // Central differences inside, one-sided at the edges (the second ones from the nearest three-point stencil).
  auto at = [&](int y, int x) { return w.at<double>(y, x); };
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const int x0 = std::max(0, x - 1), x1 = std::min(W - 1, x + 1), y0 = std::max(0, y - 1), y1 = std::min(H - 1, y + 1);
      const int xc = std::clamp(x, 1, W - 2), yc = std::clamp(y, 1, H - 2);  // centres of the second differences
      out.at<float>(y, x) = static_cast<float>(at(y, x) - rows[static_cast<size_t>(y)]);
      out.at<float>(H + y, x) = static_cast<float>((at(y, x1) - at(y, x0)) / (x1 - x0));
      out.at<float>(2 * H + y, x) = static_cast<float>((at(y1, x) - at(y0, x)) / (y1 - y0));
      out.at<float>(3 * H + y, x) = static_cast<float>(at(y, xc + 1) - 2.0 * at(y, xc) + at(y, xc - 1));
      out.at<float>(4 * H + y, x) =
          static_cast<float>((at(y1, x1) - at(y1, x0) - at(y0, x1) + at(y0, x0)) / ((x1 - x0) * (y1 - y0)));
      out.at<float>(5 * H + y, x) = static_cast<float>(at(yc + 1, x) - 2.0 * at(yc, x) + at(yc - 1, x));
    }
  return out;
}

State shiftedAlong(const State& x, const ObservedVec& m, double delta_s) {
  State out = x;
  if (delta_s == 0.0) return out;
  out.vartheta += delta_s * m.segment<3>(0);
  out.mu = x.mu.boxplus(delta_s * m.segment<2>(3));
  out.b_w += delta_s * m.segment<3>(5);
  return out;
}

namespace internal {
Vec2 warpWith(const IntervalWarp& iw, const PinholeK& K, double px, double py, WarpJacobian* J, Vec2* d_focal,
              bool translation_only) {
  const Vec3 q((px - K.cx) / K.fx, (py - K.cy) / K.fy, 1.0);
  const Vec3 Q = iw.H * q;
  if (!iw.ok || !(Q.z() > kMinDepthRatio)) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    if (J != nullptr) J->setConstant(nan);
    return Vec2(nan, nan);
  }
  const double iz = 1.0 / Q.z();
  const Vec2 p_r(K.fx * Q.x() * iz + K.cx, K.fy * Q.y() * iz + K.cy);
  if (J != nullptr) {
    Mat23 Dr;  // dp_r / dQ
    Dr << K.fx * iz, 0.0, (K.cx - p_r.x()) * iz, 0.0, K.fy * iz, (K.cy - p_r.y()) * iz;
    const double s_b = iw.b.dot(q);
    const Vec3 Eq = iw.E * q;
    const Vec3 Eaq = iw.Ea * q;
    J->block<2, 3>(0, 0) = (iw.c * s_b) * (Dr * iw.N);
    J->block<2, 2>(0, 3) = (iw.c * (Dr * iw.a)) * (q.transpose() * iw.P);
    const Mat3 dQ_dbw = iw.dt * skew(Eq) * iw.J + (iw.c * s_b * (iw.dt - iw.lag)) * skew(iw.a) * iw.Jb +
                        (iw.c * iw.lag) * iw.a * (iw.mu.cross(Eaq).transpose() * iw.Ja);
    J->block<2, 3>(0, 5) = Dr * dQ_dbw;
  }
  if (d_focal != nullptr) {
    // p_r = K_e pi(H K_e^-1 p) with K_e's focal lengths (1 + e) K's: d/de at e = 0 is (p_r - c) + D_r H dq/de,
    // dq/de = -(q_x, q_y, 0).
    Mat23 Dr;
    Dr << K.fx * iz, 0.0, (K.cx - p_r.x()) * iz, 0.0, K.fy * iz, (K.cy - p_r.y()) * iz;
    *d_focal = Vec2(p_r.x() - K.cx, p_r.y() - K.cy) - Dr * (iw.H * Vec3(q.x(), q.y(), 0.0));
    if (translation_only) {
      // Less the same derivative of the rotation alone (H = E): what the focal length does to the flow of the
      // gyro's rotation is the rotation model error's (section 6), not evidence about the focal length.
      const Vec3 QE = iw.E * q;
      if (!(QE.z() > kMinDepthRatio)) {
        d_focal->setConstant(std::numeric_limits<double>::quiet_NaN());
      } else {
        const double izE = 1.0 / QE.z();
        const Vec2 pE(K.fx * QE.x() * izE + K.cx, K.fy * QE.y() * izE + K.cy);
        Mat23 DrE;
        DrE << K.fx * izE, 0.0, (K.cx - pE.x()) * izE, 0.0, K.fy * izE, (K.cy - pE.y()) * izE;
        *d_focal -= Vec2(pE.x() - K.cx, pE.y() - K.cy) - DrE * (iw.E * Vec3(q.x(), q.y(), 0.0));
      }
    }
  }
  return p_r;
}
}  // namespace internal

Vec2 warpToReference(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double px,
                     double py, WarpJacobian* J, double state_lag_s) {
  const IntervalWarp iw(x, gyro_mean_C, dt_s, state_lag_s);
  return warpWith(iw, K, px, py, J, nullptr);
}

Vec2 focalScaleDerivative(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double px,
                          double py, double state_lag_s) {
  const IntervalWarp iw(x, gyro_mean_C, dt_s, state_lag_s);
  Vec2 d(std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN());
  warpWith(iw, K, px, py, nullptr, &d);
  return d;
}

ObservedVec focalScaleMap(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s,
                          double state_lag_s) {
  const IntervalWarp iw(x, gyro_mean_C, dt_s, state_lag_s);
  ObservedInfo JtJ = ObservedInfo::Zero();
  ObservedVec Jtd = ObservedVec::Zero();
  constexpr int kGrid = 5;
  int used = 0;
  for (int i = 0; i < kGrid; ++i) {
    for (int j = 0; j < kGrid; ++j) {
      const double px = (K.width - 1) * (0.05 + 0.9 * i / (kGrid - 1));
      const double py = (K.height - 1) * (0.05 + 0.9 * j / (kGrid - 1));
      WarpJacobian J;
      Vec2 d;
      const Vec2 p_r = warpWith(iw, K, px, py, &J, &d);
      if (!p_r.allFinite() || !J.allFinite() || !d.allFinite()) continue;
      JtJ.noalias() += J.transpose() * J;
      Jtd.noalias() += J.transpose() * d;
      ++used;
    }
  }
  if (used < kGrid * kGrid / 2) return ObservedVec::Zero();
  // Directions the grid's flow does not see (mu at vartheta = 0) get no share of the fit: a ridge far below the
  // flow's scale.
  const double ridge = 1e-9 * std::max(1e-300, JtJ.trace());
  JtJ.diagonal().array() += ridge;
  const Eigen::LDLT<ObservedInfo> ldlt(JtJ);
  if (ldlt.info() != Eigen::Success) return ObservedVec::Zero();
  const ObservedVec m = ldlt.solve(Jtd);
  return m.allFinite() ? m : ObservedVec::Zero();
}


}  // namespace diekf
