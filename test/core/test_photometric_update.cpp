#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "diekf/photometric_update.h"
#include "../../src/core/bspline.h"
#include "two_view_scene.h"
#include "../../src/core/lanes.h"
#include "../../src/core/select.h"
#include "../../src/core/window_sum.h"

namespace diekf {
namespace {

using test_util::TwoViewScene;

constexpr int kObserved[8] = {ErrIdx::kVartheta, ErrIdx::kVartheta + 1, ErrIdx::kVartheta + 2, ErrIdx::kMu,
                              ErrIdx::kMu + 1,    ErrIdx::kBw,           ErrIdx::kBw + 1,       ErrIdx::kBw + 2};

State randomState(std::mt19937* rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  State x;
  x.alpha = 1.0 + 0.3 * std::fabs(n(*rng));
  x.vartheta = Vec3(n(*rng), n(*rng), n(*rng)) * 0.5;
  x.mu = UnitVector(Vec3(0.3 * n(*rng), 0.3 * n(*rng), 1.0));
  x.g = UnitVector(Vec3(0.2 * n(*rng), 0.2 * n(*rng), 1.0));
  x.b_a = Vec3(n(*rng), n(*rng), n(*rng)) * 0.1;
  x.b_w = Vec3(n(*rng), n(*rng), n(*rng)) * 0.05;
  return x;
}

ErrorCov priorCov() {
  ErrorVec sd;
  sd << 0.5, 0.5, 0.5, 0.5, 0.1, 0.1, 0.05, 0.05, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01, 0.005, 0.005, 0.01;
  return sd.array().square().matrix().asDiagonal();
}

double angleBetween(const Vec3& a, const Vec3& b) { return std::atan2(a.cross(b).norm(), a.dot(b)); }

// --------------------------------------------------------------------------------------------------------
// Warp Jacobian vs central finite differences of warpToReference with State::boxplus.
// --------------------------------------------------------------------------------------------------------
TEST(WarpToReference, JacobianMatchesFiniteDifferences) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> px(0.0, 90.0), py(0.0, 58.0);
  std::normal_distribution<double> n(0.0, 1.0);
  const PinholeK K = test_util::makeK(90, 58);
  const double dt = 1.0 / 30.0;
  const double h = 1e-6;
  // The state at the current image, at the interval's midpoint (the estimator's default) and in between;
  // rates up to a few rad/s (fast flight), where the higher-order terms of the warp are not negligible.
  for (const double lag : {0.0, 0.5 * dt, 0.3 * dt}) {
    for (int trial = 0; trial < 20; ++trial) {
      const State x = randomState(&rng);
      const Vec3 gyro = Vec3(n(rng), n(rng), n(rng)) * 1.5;
      const double u = px(rng), v = py(rng);
      WarpJacobian J;
      warpToReference(x, K, gyro, dt, u, v, &J, lag);
      ASSERT_TRUE(J.allFinite());
      for (int col = 0; col < kErrorDim; ++col) {
        ErrorVec d = ErrorVec::Zero();
        d(col) = h;
        const Vec2 fd = (warpToReference(x.boxplus(d), K, gyro, dt, u, v, nullptr, lag) -
                         warpToReference(x.boxplus(-d), K, gyro, dt, u, v, nullptr, lag)) /
                        (2.0 * h);
        Vec2 analytic = Vec2::Zero();
        for (int k = 0; k < 8; ++k) {
          if (kObserved[k] == col) analytic = J.col(k);
        }
        EXPECT_NEAR((fd - analytic).norm(), 0.0, 1e-6)
            << "lag " << lag << " trial " << trial << " column " << col << " fd " << fd.transpose()
            << " analytic " << analytic.transpose();
      }
    }
  }
}

// The focal-length scale (docs/algorithm.md section 3.8): d p_r / d e against central differences of the warp with
// both focal lengths scaled by (1 +- h), and its fit by the observed columns (focalScaleMap): J m_f reproduces the
// focal flow to first order, the residual is small against the flow itself.
TEST(FocalScale, DerivativeMatchesFiniteDifferencesAndTheObservedColumnsSpanIt) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> px(0.0, 180.0), py(0.0, 116.0);
  std::normal_distribution<double> n(0.0, 1.0);
  const PinholeK K = test_util::makeK(180, 116);
  const double dt = 1.0 / 30.0, h = 1e-6;
  double sum_res2 = 0.0, sum_d2 = 0.0;
  for (const double lag : {0.0, 0.5 * dt}) {
    for (int trial = 0; trial < 20; ++trial) {
      const State x = randomState(&rng);
      const Vec3 gyro = Vec3(n(rng), n(rng), n(rng)) * 1.5;
      const ObservedVec m_f = focalScaleMap(x, K, gyro, dt, lag);
      ASSERT_TRUE(m_f.allFinite());
      for (int k = 0; k < 5; ++k) {
        const double u = px(rng), v = py(rng);
        const Vec2 d = focalScaleDerivative(x, K, gyro, dt, u, v, lag);
        const Vec2 fd = (warpToReference(x, scaledFocal(K, h), gyro, dt, u, v, nullptr, lag) -
                         warpToReference(x, scaledFocal(K, -h), gyro, dt, u, v, nullptr, lag)) /
                        (2.0 * h);
        ASSERT_TRUE(d.allFinite());
        EXPECT_NEAR((fd - d).norm(), 0.0, 1e-5 * (1.0 + d.norm())) << "trial " << trial;
        WarpJacobian J;
        warpToReference(x, K, gyro, dt, u, v, &J, lag);
        sum_res2 += (J * m_f - d).squaredNorm();
        sum_d2 += d.squaredNorm();
      }
    }
  }
  const double relative = std::sqrt(sum_res2 / sum_d2);
  std::printf("[focal scale] RMS residual of the observed columns' fit: %.2e of the focal flow\n", relative);
  EXPECT_LT(relative, 0.05);
  EXPECT_TRUE(scaledFocal(K, 0.0).fx == K.fx && scaledFocal(K, 0.1).cx == K.cx);
}

// The warp against the rigid-body geometry it models: a camera turning at a constant body rate and moving at
// a constant world velocity (test_util::propagate) over a tilted plane. The state is the true plane state at the
// time `lag` before the current image; the current pixel's ray is intersected with the plane and the point
// projected into the reference camera. Exact for every lag, at a fast 2.4 rad/s; the paper's first-order
// continuous homography is off by a tenth of a pixel at 180 px here.
TEST(WarpToReference, MatchesRigidMotionOverAPlane) {
  const PinholeK K = test_util::makeK(180, 116);
  const double dt = 1.0 / 30.0;
  test_util::Plane plane;
  plane.n = Vec3(0.15, -0.1, 1.0).normalized();
  const Vec3 v_W(0.6, -0.4, 0.25);       // m/s
  const Vec3 w_C(1.3, -1.9, 0.6);        // rad/s, about 136 deg/s
  const test_util::CameraPose cur = test_util::lookDownPose(Vec3(0.2, -0.1, 0.8), 0.4, 0.2);
  const test_util::CameraPose ref = test_util::propagate(cur, v_W, w_C, -dt);
  double first_order_max_px = 0.0;
  for (const double lag : {0.0, 0.5 * dt, 0.8 * dt}) {
    const test_util::CameraPose at_state = test_util::propagate(cur, v_W, w_C, -lag);
    const test_util::PlaneTruth truth = test_util::planeTruth(plane, at_state, v_W);
    State x;
    x.alpha = 1.0 / truth.d_m;
    x.vartheta = truth.vartheta_inv_s;
    x.mu = UnitVector(truth.mu);
    for (double py = 0.0; py <= 116.0; py += 29.0) {
      for (double px = 0.0; px <= 180.0; px += 30.0) {
        // Ray of the current pixel in W, intersected with the plane n . X + e = 0.
        const Vec3 ray_W = cur.R_WC * Vec3((px - K.cx) / K.fx, (py - K.cy) / K.fy, 1.0);
        const double t = -(plane.n.dot(cur.p_WC) + plane.e) / plane.n.dot(ray_W);
        ASSERT_GT(t, 0.0);
        const Vec3 X_r = ref.R_WC.transpose() * (cur.p_WC + t * ray_W - ref.p_WC);
        const Vec2 expected(K.fx * X_r.x() / X_r.z() + K.cx, K.fy * X_r.y() / X_r.z() + K.cy);
        const Vec2 warped = warpToReference(x, K, w_C, dt, px, py, nullptr, lag);
        EXPECT_LT((warped - expected).norm(), 1e-8) << "lag " << lag << " pixel " << px << ", " << py;
        if (lag == 0.0) {  // docs/algorithm.md §3.2: p_r = p + dt (I - p e_z^T) K ([w]x + vartheta mu^T) K^-1 p
          const Vec3 q((px - K.cx) / K.fx, (py - K.cy) / K.fy, 1.0);
          const Vec3 m = w_C.cross(q) + x.vartheta * truth.mu.dot(q);
          const Vec2 first(px + dt * (K.fx * m.x() + (K.cx - px) * m.z()),
                           py + dt * (K.fy * m.y() + (K.cy - py) * m.z()));
          first_order_max_px = std::max(first_order_max_px, (first - expected).norm());
        }
      }
    }
  }
  EXPECT_GT(first_order_max_px, 0.1);  // what the exact form buys at this rate
}

TEST(WarpToReference, RayBehindTheReferenceCameraIsNaN) {
  State x;
  x.alpha = 1.0;
  const PinholeK K = test_util::makeK(90, 58);
  // Half a turn about x within the interval: the current view's rays point away from the reference camera.
  const Vec3 gyro(M_PI * 30.0, 0.0, 0.0);
  WarpJacobian J;
  const Vec2 p = warpToReference(x, K, gyro, 1.0 / 30.0, 45.0, 29.0, &J);
  EXPECT_FALSE(p.allFinite());
  EXPECT_FALSE(J.allFinite());
}

TEST(WarpToReference, ZeroMotionIsIdentity) {
  State x;
  const PinholeK K = test_util::makeK(90, 58);
  const Vec2 p = warpToReference(x, K, Vec3::Zero(), 1.0 / 30.0, 12.25, 40.5);
  EXPECT_NEAR(p.x(), 12.25, 1e-12);
  EXPECT_NEAR(p.y(), 40.5, 1e-12);
}

// --------------------------------------------------------------------------------------------------------
// The single-precision pixel loop against a straightforward double-precision evaluation of docs/algorithm.md §3.3.
// --------------------------------------------------------------------------------------------------------
/// The reference image as a cubic B-spline in double precision, built independently of src/core/bspline.cpp:
/// the coefficients by solving the tridiagonal interpolation system (c(k-1) + 4 c(k) + c(k+1)) / 6 = f(k) (mirror
/// boundaries) per row and then per column, the value and gradient from the basis function beta3 itself.
class SplineReference {
 public:
  explicit SplineReference(const cv::Mat& f) : W_(f.cols), H_(f.rows), c_(static_cast<size_t>(W_) * H_) {
    for (int y = 0; y < H_; ++y)
      for (int x = 0; x < W_; ++x) c_[idx(x, y)] = f.at<float>(y, x);
    std::vector<double> line;
    for (int y = 0; y < H_; ++y) {
      line.assign(c_.begin() + idx(0, y), c_.begin() + idx(0, y) + W_);
      solve(&line);
      std::copy(line.begin(), line.end(), c_.begin() + idx(0, y));
    }
    line.resize(H_);
    for (int x = 0; x < W_; ++x) {
      for (int y = 0; y < H_; ++y) line[y] = c_[idx(x, y)];
      solve(&line);
      for (int y = 0; y < H_; ++y) c_[idx(x, y)] = line[y];
    }
  }
  /// Value and gradient (d/dx, d/dy) of the spline at (x, y).
  double value(double x, double y, Vec2* grad) const {
    double v = 0.0, gx = 0.0, gy = 0.0;
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    for (int j = y0 - 1; j <= y0 + 2; ++j) {
      for (int i = x0 - 1; i <= x0 + 2; ++i) {
        const double c = c_[idx(i, j)];
        v += c * beta3(x - i) * beta3(y - j);
        gx += c * dbeta3(x - i) * beta3(y - j);
        gy += c * beta3(x - i) * dbeta3(y - j);
      }
    }
    *grad = Vec2(gx, gy);
    return v;
  }

 private:
  static double beta3(double t) {
    const double a = std::abs(t);
    return a < 1.0 ? 2.0 / 3.0 - a * a + 0.5 * a * a * a : (a < 2.0 ? (2.0 - a) * (2.0 - a) * (2.0 - a) / 6.0 : 0.0);
  }
  static double dbeta3(double t) {
    const double a = std::abs(t), s = t < 0.0 ? -1.0 : 1.0;
    return s * (a < 1.0 ? -2.0 * a + 1.5 * a * a : (a < 2.0 ? -0.5 * (2.0 - a) * (2.0 - a) : 0.0));
  }
  /// Thomas algorithm on the mirror-boundary system (first row 4 c0 + 2 c1, last row 2 c(n-2) + 4 c(n-1)).
  static void solve(std::vector<double>* f) {
    const int n = static_cast<int>(f->size());
    std::vector<double> lo(n, 1.0 / 6.0), di(n, 4.0 / 6.0), up(n, 1.0 / 6.0);
    up[0] = 2.0 / 6.0;
    lo[n - 1] = 2.0 / 6.0;
    std::vector<double>& d = *f;
    for (int k = 1; k < n; ++k) {
      const double m = lo[k] / di[k - 1];
      di[k] -= m * up[k - 1];
      d[k] -= m * d[k - 1];
    }
    d[n - 1] /= di[n - 1];
    for (int k = n - 2; k >= 0; --k) d[k] = (d[k] - up[k] * d[k + 1]) / di[k];
  }
  size_t idx(int x, int y) const { return static_cast<size_t>(y) * W_ + x; }
  int W_, H_;
  std::vector<double> c_;
};

/// The reference as a quintic B-spline: the coefficients of src/core/bspline.cpp (tested against the samples in
/// test_bspline.cpp), the value and gradient from the basis function beta5 in double precision over the 6 x 6 taps.
class QuinticReference {
 public:
  explicit QuinticReference(const cv::Mat& f) {
    cv::Mat c;
    internal::bSplineCoefficients(f, 5, &c);
    c.convertTo(c_, CV_64FC1);
  }
  double value(double x, double y, Vec2* grad) const {
    double v = 0.0, gx = 0.0, gy = 0.0;
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    for (int j = y0 - 2; j <= y0 + 3; ++j) {
      for (int i = x0 - 2; i <= x0 + 3; ++i) {
        const double c = c_.at<double>(j, i);
        v += c * beta5(x - i) * beta5(y - j);
        gx += c * dbeta5(x - i) * beta5(y - j);
        gy += c * beta5(x - i) * dbeta5(y - j);
      }
    }
    *grad = Vec2(gx, gy);
    return v;
  }

 private:
  /// beta5(x) = sum_k (-1)^k C(6, k) (x + 3 - k)_+^5 / 120, and its derivative.
  static double beta5(double x) { return powers(x, 5) / 120.0; }
  static double dbeta5(double x) { return 5.0 * powers(x, 4) / 120.0; }
  static double powers(double x, int n) {
    const double binom[7] = {1, 6, 15, 20, 15, 6, 1};
    double s = 0.0;
    for (int k = 0; k <= 6; ++k) s += (k % 2 ? -1.0 : 1.0) * binom[k] * std::pow(std::max(0.0, x + 3.0 - k), n);
    return s;
  }
  cv::Mat c_;
};

void referenceLinearization(const TwoViewScene& s, const State& x, const Vec3& gyro, double sigma,
                            double huber_k, ObservedInfo* A, ObservedVec* b, int* valid, double lag = 0.0,
                            int degree = 3) {
  A->setZero();
  b->setZero();
  *valid = 0;
  const int W = s.cur.intensity.cols, H = s.cur.intensity.rows;
  std::optional<SplineReference> cubic;  // only the spline evaluated is built
  std::optional<QuinticReference> quintic;
  if (degree == 5) {
    quintic.emplace(s.ref.intensity);
  } else {
    cubic.emplace(s.ref.intensity);
  }
  const double lead = degree / 2;  // the taps' reach below floor(x): 1 (cubic) or 2 (quintic)
  for (int y = 1; y < H - 1; ++y) {
    for (int xp = 1; xp < W - 1; ++xp) {
      WarpJacobian J;
      const Vec2 pr = warpToReference(x, s.K, gyro, s.dt_s, xp, y, &J, lag);
      if (!(pr.x() >= lead && pr.x() < W - 1.0 - lead && pr.y() >= lead && pr.y() < H - 1.0 - lead)) continue;
      ++*valid;
      Vec2 g_ref;
      const double I_r = quintic ? quintic->value(pr.x(), pr.y(), &g_ref) : cubic->value(pr.x(), pr.y(), &g_ref);
      const double r = s.cur.intensity.at<float>(y, xp) - I_r;
      const Vec2 g(0.5 * (s.cur.grad_x.at<float>(y, xp) + g_ref.x()), 0.5 * (s.cur.grad_y.at<float>(y, xp) + g_ref.y()));
      const Eigen::Matrix<double, 1, 8> S = g.transpose() * J;
      double w = 1.0 / (sigma * sigma);
      if (huber_k > 0.0 && std::fabs(r) > huber_k * sigma) w *= huber_k * sigma / std::fabs(r);
      *A += w * S.transpose() * S;
      *b += w * S.transpose() * r;
    }
  }
}

class PhotometricScene : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { scene_ = new TwoViewScene(test_util::makeTwoViewScene(180, 116)); }
  static void TearDownTestSuite() {
    delete scene_;
    scene_ = nullptr;
  }
  /// Truth except vartheta scaled by `vartheta_factor` and mu tilted by ~0.05 rad.
  static State startState(double vartheta_factor) {
    State x;
    x.alpha = 1.0 / scene_->truth.d_m;
    x.vartheta = vartheta_factor * scene_->truth.vartheta_inv_s;
    x.mu = UnitVector(scene_->truth.mu).boxplus(Vec2(0.04, -0.03));
    x.g = UnitVector(Vec3(0.0, 0.0, 1.0));
    return x;
  }
  /// A rolling shutter over the current image's rows (each row's time per second of readout into `row_weight`,
  /// which must outlive the timing) with the filtered readings accel_C (m/s^2) and rate_change_C (rad/s).
  static ImageTiming rollingTiming(const Vec3& accel_C, const Vec3& rate_change_C, std::vector<float>* row_weight) {
    const int rows = scene_->cur.intensity.rows;
    row_weight->resize(static_cast<size_t>(rows));
    for (int y = 0; y < rows; ++y) (*row_weight)[static_cast<size_t>(y)] = (y - 0.5f * (rows - 1)) / (rows - 1);
    ImageTiming timing;
    timing.rates_valid = true;
    timing.gravity_mps2 = 9.81;
    timing.accel_C = accel_C;
    timing.rate_change_C = rate_change_C;
    timing.row_weight = row_weight->data();
    timing.rows = rows;
    return timing;
  }
  /// A consider-state test: one update of the pair (one pass) from startState(0) with a time state (`idx` of the
  /// error state, `field` of State, prior 1-sigma 10 ms) estimated, considered and ignored (the flags `estimate`
  /// and `consider` of `timing`). Considered, the state and its variance are held; the other states are the
  /// estimated update's (Schmidt); the cross-covariance with vartheta builds up; and the update is more cautious
  /// than without the column.
  static void expectConsideredStateHeld(const ImageTiming& timing, bool ImageTiming::*estimate,
                                        bool ImageTiming::*consider, int idx, double State::*field, const char* name) {
    PhotometricParams params;
    params.max_passes = 1;
    const double prior_var = 0.01 * 0.01;  // s^2: the time states' priors as configured by default
    State x[3];
    ErrorCov P[3];
    UpdateStats st[3];
    for (int v = 0; v < 3; ++v) {
      PhotometricUpdate update(params, PreprocessParams{});
      ImageTiming t = timing;
      t.*estimate = v == 0;
      t.*consider = v == 1;
      x[v] = startState(0.0);
      P[v] = priorCov();
      P[v](idx, idx) = prior_var;
      st[v] = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x[v], &P[v], 0.0, t);
    }
    ASSERT_TRUE(st[0].applied && st[1].applied && st[2].applied);
    ASSERT_LT(st[0].nis, 15.507) << "a probable frame: the estimated " << name << " is not held";
    EXPECT_NE(x[0].*field, 0.0) << "estimated, the frame moves the " << name;
    EXPECT_EQ(x[1].*field, 0.0) << "considered, it does not";
    EXPECT_EQ(P[1](idx, idx), prior_var);
    EXPECT_LT((x[1].vartheta - x[0].vartheta).norm(), 1e-9 * (1.0 + x[0].vartheta.norm()));
    EXPECT_LT((x[1].b_w - x[0].b_w).norm(), 1e-9);
    ErrorCov diff = P[1] - P[0];
    diff(idx, idx) = 0.0;
    EXPECT_LT(diff.cwiseAbs().maxCoeff(), 1e-9 * P[0].cwiseAbs().maxCoeff());
    const double cross = P[1].block<1, 3>(idx, ErrIdx::kVartheta).norm();
    EXPECT_GT(cross, 0.0) << "the cross-covariance builds up";
    EXPECT_EQ((P[2].block<1, 3>(idx, ErrIdx::kVartheta).norm()), 0.0);
    const double var_con = P[1].block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta).trace();
    const double var_off = P[2].block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta).trace();
    std::printf("tr P_vartheta: %s considered %.4g, ignored %.4g; |P_%s,vartheta| %.3g\n", name, var_con, var_off,
                name, cross);
    EXPECT_GT(var_con, var_off);
    EXPECT_GT(P[1].ldlt().vectorD().minCoeff(), 0.0) << "the covariance stays positive definite";
    if (idx == ErrIdx::kTd) {
      EXPECT_LT(st[1].nis, st[2].nis) << "the offset's uncertainty is in the innovation's covariance";
    }
  }
  /// One update of the pair (ref, cur) from startState(0.5) with the given brightness model (all passes): the
  /// updated vartheta; the stats to `st`.
  static Vec3 updatedVartheta(BrightnessModel model, const PreprocessedFrame& ref, const PreprocessedFrame& cur,
                              UpdateStats* st) {
    PhotometricParams params;
    params.brightness_model = model;
    params.stop_threshold = 0.0;
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(0.5);
    ErrorCov P = priorCov();
    *st = update.update(ref, cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
    EXPECT_TRUE(st->applied);
    return x.vartheta;
  }
  static TwoViewScene* scene_;
};
TwoViewScene* PhotometricScene::scene_ = nullptr;

TEST_F(PhotometricScene, PixelLoopMatchesDoublePrecisionReference) {
  // The state at the current image with the scene's rate, and at the interval's midpoint with a fast rate
  // (every term of the b_w row of PixelWarp non-negligible).
  // The quintic spline's 6 x 6 taps too (photometric/spline_degree 5), both the consecutive-column loads and
  // the gathered ones (the fast rates turn the image).
  struct Case {
    double huber, lag_s;
    Vec3 gyro;
    int degree;
  };
  const double dt = scene_->dt_s;
  const Case cases[] = {{0.0, 0.0, scene_->w_C, 3},
                        {1.0, 0.0, scene_->w_C, 3},
                        {0.0, 0.5 * dt, scene_->w_C + Vec3(1.2, -0.9, 0.6), 3},
                        {1.0, 0.3 * dt, scene_->w_C + Vec3(-0.7, 1.1, -0.4), 3},
                        {0.0, 0.0, scene_->w_C, 5},
                        {1.0, 0.3 * dt, scene_->w_C + Vec3(-0.7, 1.1, -0.4), 5}};
  for (const Case& c : cases) {
    SCOPED_TRACE("spline degree " + std::to_string(c.degree));
    PhotometricParams params;
    params.huber_threshold = c.huber;
    params.spline_degree = c.degree;
    PreprocessParams pre;
    pre.border_px = 1;
    PhotometricUpdate update(params, pre);
    const State x = startState(0.5);
    ObservedInfo A, A_ref;
    ObservedVec b, b_ref;
    int candidates = 0, valid_ref = 0;
    const int valid = update.linearize(scene_->ref, scene_->cur, scene_->K, c.gyro, dt, x, &A, &b, &candidates,
                                       c.lag_s);
    referenceLinearization(*scene_, x, c.gyro, params.intensity_noise_sigma, c.huber, &A_ref, &b_ref, &valid_ref,
                           c.lag_s, c.degree);
    if (c.degree == 5) {  // the two splines differ by more than the tolerances below on this texture
      ObservedInfo A3;
      ObservedVec b3;
      int valid3 = 0;
      referenceLinearization(*scene_, x, c.gyro, params.intensity_noise_sigma, c.huber, &A3, &b3, &valid3, c.lag_s, 3);
      EXPECT_GT((b3 - b_ref).norm(), 1e-2 * b_ref.norm());
    }
    EXPECT_EQ(candidates, 178 * 114);
    EXPECT_NEAR(valid, valid_ref, 2);  // float vs double at the exact bounds
    EXPECT_LT((A - A_ref).norm(), 1e-3 * A_ref.norm()) << "huber " << c.huber << " lag " << c.lag_s;
    EXPECT_LT((b - b_ref).norm(), 1e-3 * b_ref.norm()) << "huber " << c.huber << " lag " << c.lag_s;
    // The b_w block separately (small next to the vartheta block, so not covered by the norms above).
    const Mat3 Abw = A.block<3, 3>(5, 5), Abw_ref = A_ref.block<3, 3>(5, 5);
    EXPECT_LT((Abw - Abw_ref).norm(), 1e-3 * Abw_ref.norm());
    EXPECT_LT((b.tail<3>() - b_ref.tail<3>()).norm(), 2e-3 * b_ref.tail<3>().norm() + 1e-9 * b_ref.norm());
    EXPECT_LT((A - A.transpose()).norm(), 1e-12 * A.norm());
  }
}

// The vectorised sweep with pixel_stride and gradient weighting (+ Huber) against the same plain double
// evaluation over the strided pixels, weights |grad I_c| normalised by their mean over the valid pixels.
TEST_F(PhotometricScene, StridedGradientWeightedLoopMatchesDoublePrecisionReference) {
  for (int stride : {2, 3}) {
    PhotometricParams params;
    params.pixel_stride = stride;
    params.gradient_weighting = true;
    params.huber_threshold = 1.0;
    PhotometricUpdate update(params, PreprocessParams{});
    const State x = startState(0.5);
    ObservedInfo A;
    ObservedVec b;
    int candidates = 0;
    const int valid =
        update.linearize(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, x, &A, &b, &candidates);

    const TwoViewScene& s = *scene_;
    const double sigma = params.intensity_noise_sigma, k = params.huber_threshold;
    const int W = s.cur.intensity.cols, H = s.cur.intensity.rows;
    const SplineReference spline(s.ref.intensity);
    ObservedInfo A_ref = ObservedInfo::Zero();
    ObservedVec b_ref = ObservedVec::Zero();
    int valid_ref = 0, cand_ref = 0;
    double grad_sum = 0.0;
    for (int y = 1; y < H - 1; y += stride) {
      for (int xp = 1; xp < W - 1; xp += stride) {
        ++cand_ref;
        WarpJacobian J;
        const Vec2 pr = warpToReference(x, s.K, s.w_C, s.dt_s, xp, y, &J);
        if (!(pr.x() >= 1.0 && pr.x() < W - 2.0 && pr.y() >= 1.0 && pr.y() < H - 2.0)) continue;
        ++valid_ref;
        Vec2 g_ref;
        const double r = s.cur.intensity.at<float>(y, xp) - spline.value(pr.x(), pr.y(), &g_ref);
        const double gcx = s.cur.grad_x.at<float>(y, xp), gcy = s.cur.grad_y.at<float>(y, xp);
        const Vec2 g(0.5 * (gcx + g_ref.x()), 0.5 * (gcy + g_ref.y()));
        const Eigen::Matrix<double, 1, 8> S = g.transpose() * J;
        const double gmag = std::hypot(gcx, gcy);
        grad_sum += gmag;
        double w = gmag / (sigma * sigma);
        if (std::fabs(r) > k * sigma) w *= k * sigma / std::fabs(r);
        A_ref += w * S.transpose() * S;
        b_ref += w * S.transpose() * r;
      }
    }
    A_ref *= valid_ref / grad_sum;
    b_ref *= valid_ref / grad_sum;
    EXPECT_EQ(candidates, cand_ref) << "stride " << stride;
    EXPECT_NEAR(valid, valid_ref, 2) << "stride " << stride;
    EXPECT_LT((A - A_ref).norm(), 1e-3 * A_ref.norm()) << "stride " << stride;
    EXPECT_LT((b - b_ref).norm(), 1e-3 * b_ref.norm()) << "stride " << stride;
    // The residual image holds r on the strided pixels only.
    const cv::Mat& res = update.residualImage();
    EXPECT_EQ(res.at<float>(2, 2), 0.0f);  // candidates lie at 1 + k stride: (2, 2) is never one
    EXPECT_GT(cv::countNonZero(res), valid_ref / 2);
    EXPECT_LE(cv::countNonZero(res), valid_ref);
  }
}

// --------------------------------------------------------------------------------------------------------
// Update behaviour.
// --------------------------------------------------------------------------------------------------------
// The brightness model's columns (docs/noise_model.md section 12): the sweep's information with the pair's gain
// (and offset) marginalised equals the Schur complement of a double-precision system over [S, I_r (, 1)] (the
// model g I_r + o at g = 1, o = 0: its derivatives are I_r and 1).
TEST_F(PhotometricScene, BrightnessModelIsMarginalisedLikeTheDoublePrecisionSystem) {
  const double dt = scene_->dt_s;
  PreprocessParams pre;
  pre.border_px = 1;
  const State x = startState(0.5);
  ObservedInfo A_plain;
  ObservedVec b_plain;
  PhotometricUpdate plain(PhotometricParams{}, pre);
  plain.linearize(scene_->ref, scene_->cur, scene_->K, scene_->w_C, dt, x, &A_plain, &b_plain);

  using Mat10 = Eigen::Matrix<double, 10, 10>;
  using Vec10 = Eigen::Matrix<double, 10, 1>;
  Mat10 A10 = Mat10::Zero();
  Vec10 b10 = Vec10::Zero();
  const int W = scene_->cur.intensity.cols, H = scene_->cur.intensity.rows;
  const SplineReference spline(scene_->ref.intensity);
  const double w = 1.0 / (PhotometricParams{}.intensity_noise_sigma * PhotometricParams{}.intensity_noise_sigma);
  for (int y = 1; y < H - 1; ++y) {
    for (int xp = 1; xp < W - 1; ++xp) {
      WarpJacobian J;
      const Vec2 pr = warpToReference(x, scene_->K, scene_->w_C, dt, xp, y, &J);
      if (!(pr.x() >= 1.0 && pr.x() < W - 2.0 && pr.y() >= 1.0 && pr.y() < H - 2.0)) continue;
      Vec2 g_ref;
      const double ref = spline.value(pr.x(), pr.y(), &g_ref);
      const double r = scene_->cur.intensity.at<float>(y, xp) - ref;
      const Vec2 g(0.5 * (scene_->cur.grad_x.at<float>(y, xp) + g_ref.x()),
                   0.5 * (scene_->cur.grad_y.at<float>(y, xp) + g_ref.y()));
      Vec10 row;
      row.head<8>() = (g.transpose() * J).transpose();
      row(8) = ref;
      row(9) = 1.0;
      A10 += w * row * row.transpose();
      b10 += w * row * r;
    }
  }
  for (BrightnessModel model : {BrightnessModel::kGain, BrightnessModel::kAffine}) {
    PhotometricParams params;
    params.brightness_model = model;
    PhotometricUpdate update(params, pre);
    ObservedInfo A;
    ObservedVec b;
    update.linearize(scene_->ref, scene_->cur, scene_->K, scene_->w_C, dt, x, &A, &b);
    const int k = model == BrightnessModel::kAffine ? 2 : 1;
    const Eigen::MatrixXd D = A10.block(8, 8, k, k);
    const Eigen::MatrixXd C = A10.block(0, 8, 8, k);
    const ObservedInfo A_ref = A10.topLeftCorner<8, 8>() - C * D.inverse() * C.transpose();
    const ObservedVec b_ref = b10.head<8>() - C * D.inverse() * b10.segment(8, k);
    EXPECT_LT((A - A_ref).norm(), 1e-3 * A_ref.norm()) << toString(model);
    EXPECT_LT((b - b_ref).norm(), 1e-3 * b_ref.norm()) << toString(model);
    // The marginalisation removes information, never adds any.
    const Eigen::SelfAdjointEigenSolver<ObservedInfo> lost(A_plain - A);
    EXPECT_GT(lost.eigenvalues().minCoeff(), -1e-6 * A_plain.norm()) << toString(model);
    EXPECT_GT(lost.eigenvalues().maxCoeff(), 0.0) << toString(model);
  }
}

// A pair whose current image is g I + o of the scene's (an exposure and black-level change the per-image
// normalisation does not remove): the affine model finds g and o and moves the state as it does on the unchanged
// pair; the gain model finds g of a pure gain change; the images compared as they are keep the change in the
// residual.
TEST_F(PhotometricScene, BrightnessModelRecoversAGainAndOffsetChange) {
  auto changedBy = [](double gain, double offset) {
    // New buffers: assigning an expression to a header that shares the scene's data would write into it.
    PreprocessedFrame changed = scene_->cur;
    changed.intensity = cv::Mat(scene_->cur.intensity * gain + offset);
    changed.grad_x = cv::Mat(scene_->cur.grad_x * gain);
    changed.grad_y = cv::Mat(scene_->cur.grad_y * gain);
    return changed;
  };
  constexpr double kGain = 1.15, kOffset = -0.08;
  const PreprocessedFrame affine_change = changedBy(kGain, kOffset), gain_change = changedBy(kGain, 0.0);
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  auto run = [&](BrightnessModel model, const PreprocessedFrame& cur, UpdateStats* st) {
    return (updatedVartheta(model, scene_->ref, cur, st) - truth).norm();
  };
  UpdateStats st_same, st_affine, st_plain, st_off, st_gain;
  const double e_same = run(BrightnessModel::kAffine, scene_->cur, &st_same);
  const double e_affine = run(BrightnessModel::kAffine, affine_change, &st_affine);
  const double e_off = run(BrightnessModel::kNormalised, scene_->cur, &st_off);
  const double e_gain = run(BrightnessModel::kGain, gain_change, &st_gain);
  run(BrightnessModel::kNormalised, affine_change, &st_plain);
  EXPECT_NEAR(st_same.brightness_gain, 1.0, 0.01);
  EXPECT_NEAR(st_same.brightness_offset, 0.0, 0.01);
  EXPECT_NEAR(st_affine.brightness_gain, kGain, 0.01);
  EXPECT_NEAR(st_affine.brightness_offset, kOffset, 0.01);
  EXPECT_NEAR(st_gain.brightness_gain, kGain, 0.01);
  EXPECT_EQ(st_gain.brightness_offset, 0.0);
  EXPECT_EQ(st_plain.brightness_gain, 1.0);
  EXPECT_EQ(st_plain.brightness_offset, 0.0);
  EXPECT_LT(e_affine, e_same + 0.005 * truth.norm()) << e_same << " -> " << e_affine;
  EXPECT_LT(e_gain, e_off + 0.005 * truth.norm()) << e_off << " -> " << e_gain;
  EXPECT_LT(e_same, e_off + 0.005 * truth.norm()) << "the model on an unchanged pair";
  // The residual of the last linearisation: the change removed with the model, kept without.
  EXPECT_LT(st_affine.rms_residual, 1.5 * st_same.rms_residual + 1e-3);
  EXPECT_LT(st_gain.rms_residual, 1.5 * st_off.rms_residual + 1e-3);
  EXPECT_GT(st_plain.rms_residual, 3.0 * st_affine.rms_residual);
}

// Row gains (brightness model rows, docs/noise_model.md section 12): the sweep's information with the gains of
// the spline's knots marginalised equals the Schur complement of a double-precision system whose knot columns are
// beta_k(s_y) (I_r + ref level); the residual is I_c + cur level - (I_r + ref level) at gains 1. Without per-pixel
// times the capture time of a row is its place in the image (u_y = y / (H - 1) - 1/2).
TEST_F(PhotometricScene, RowGainsAreMarginalisedLikeTheDoublePrecisionSystem) {
  const double dt = scene_->dt_s;
  PreprocessParams pre;
  pre.border_px = 1;
  const State x = startState(0.5);
  PreprocessedFrame ref = scene_->ref, cur = scene_->cur;
  ref.level_offset = 2.5;  // the images' means over their standard deviations
  cur.level_offset = 2.4;
  constexpr int kKnots = 7;
  using MatX = Eigen::MatrixXd;
  MatX A_all = MatX::Zero(8 + kKnots, 8 + kKnots);
  Eigen::VectorXd b_all = Eigen::VectorXd::Zero(8 + kKnots);
  const int W = cur.intensity.cols, H = cur.intensity.rows;
  const SplineReference spline(ref.intensity);
  const double w = 1.0 / (PhotometricParams{}.intensity_noise_sigma * PhotometricParams{}.intensity_noise_sigma);
  for (int y = 1; y < H - 1; ++y) {
    const double s = (static_cast<double>(y) / (H - 1)) * (kKnots - 3);
    const int k0 = std::min(kKnots - 4, static_cast<int>(std::floor(s)));
    float bw[4], dbw[4];
    internal::cubicBSplineWeights(static_cast<float>(s - k0), bw, dbw);
    for (int xp = 1; xp < W - 1; ++xp) {
      WarpJacobian J;
      const Vec2 pr = warpToReference(x, scene_->K, scene_->w_C, dt, xp, y, &J);
      if (!(pr.x() >= 1.0 && pr.x() < W - 2.0 && pr.y() >= 1.0 && pr.y() < H - 2.0)) continue;
      Vec2 g_ref;
      const double level = spline.value(pr.x(), pr.y(), &g_ref) + ref.level_offset;
      const double r = cur.intensity.at<float>(y, xp) + cur.level_offset - level;
      const Vec2 g(0.5 * (cur.grad_x.at<float>(y, xp) + g_ref.x()), 0.5 * (cur.grad_y.at<float>(y, xp) + g_ref.y()));
      Eigen::VectorXd row = Eigen::VectorXd::Zero(8 + kKnots);
      row.head<8>() = (g.transpose() * J).transpose();
      for (int j = 0; j < 4; ++j) row(8 + k0 + j) = bw[j] * level;
      A_all += w * row * row.transpose();
      b_all += w * row * r;
    }
  }
  PhotometricParams params;
  params.brightness_model = BrightnessModel::kRows;
  params.brightness_row_knots = kKnots;
  PhotometricUpdate update(params, pre);
  ObservedInfo A;
  ObservedVec b;
  update.linearize(ref, cur, scene_->K, scene_->w_C, dt, x, &A, &b);
  const MatX D = A_all.bottomRightCorner(kKnots, kKnots);
  const MatX C = A_all.topRightCorner(8, kKnots);
  const ObservedInfo A_ref = A_all.topLeftCorner<8, 8>() - C * D.ldlt().solve(C.transpose());
  const ObservedVec b_ref = b_all.head<8>() - C * D.ldlt().solve(b_all.tail(kKnots));
  EXPECT_LT((A - A_ref).norm(), 1e-3 * A_ref.norm());
  EXPECT_LT((b - b_ref).norm(), 1e-3 * b_ref.norm());
  // The knots take information (the images' motion along the rows is partly a change of the rows' gains).
  ObservedInfo A_plain;
  ObservedVec b_plain;
  PhotometricUpdate plain(PhotometricParams{}, pre);
  plain.linearize(ref, cur, scene_->K, scene_->w_C, dt, x, &A_plain, &b_plain);
  const Eigen::SelfAdjointEigenSolver<ObservedInfo> lost(A_plain - A);
  EXPECT_GT(lost.eigenvalues().minCoeff(), -1e-6 * A_plain.norm());
  EXPECT_GT(lost.eigenvalues().maxCoeff(), 0.0);
}

namespace {
/// The scene's image lit by a light whose brightness varies down the rows as a rolling shutter sees a flickering
/// light, 0.8 (1 + depth sin(2 pi cycles y / H + phase)) on the grey levels (0.8: no grey level clipped), then
/// blurred and standardised like the preprocessing (level_offset set).
PreprocessedFrame bandedFrame(const cv::Mat& gray8, double t_s, double depth, double cycles, double phase) {
  cv::Mat grey;
  gray8.convertTo(grey, CV_32FC1);
  for (int y = 0; y < grey.rows; ++y)
    grey.row(y) *= 0.8 * (1.0 + depth * std::sin(2.0 * M_PI * cycles * y / grey.rows + phase));  // none clipped
  cv::Mat banded;
  grey.convertTo(banded, CV_8UC1);
  PreprocessedFrame f = test_util::makeFrame(banded, t_s);
  // makeFrame standardises the blurred image; its level is the blurred image's mean over its standard deviation.
  cv::Mat blurred;
  banded.convertTo(blurred, CV_32FC1);
  cv::GaussianBlur(blurred, blurred, cv::Size(0, 0), 0.8, 0.8, cv::BORDER_REFLECT101);
  cv::Scalar mean, sd;
  cv::meanStdDev(blurred, mean, sd);
  f.level_offset = mean[0] / sd[0];
  return f;
}
}  // namespace

// Levels (docs/noise_model.md section 12): the images compared at their grey levels. (1) The current image
// standardised with a mean off by delta (ground of another brightness entered the view outside the overlap): the
// levels' relation (each image's level and spread) restores it, and the state moves as on the unchanged pair,
// while the images compared as standardised are biased. (2) An exposure change (the raw image times 1.15: the
// standardised image is the same, its spread 1.15 times larger): the pair's mean residual says the light changed
// and the pair is compared as standardised, bit for bit.
TEST_F(PhotometricScene, LevelsRestoreTheStandardisationsLevelAndFallBackOnALightChange) {
  constexpr double kLevel = 4.0, kSpread = 40.0, kDelta = 0.1;
  PreprocessedFrame ref = scene_->ref, same = scene_->cur;
  ref.level_offset = same.level_offset = kLevel;
  ref.grey_per_unit = same.grey_per_unit = kSpread;
  PreprocessedFrame shifted = same;
  shifted.intensity = cv::Mat(same.intensity - kDelta);  // new buffer; the gradients are unchanged
  shifted.level_offset = kLevel + kDelta;
  PreprocessedFrame brighter = same;
  brighter.grey_per_unit = 1.15 * kSpread;
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  auto run = [&](BrightnessModel model, const PreprocessedFrame& cur, UpdateStats* st) {
    return updatedVartheta(model, ref, cur, st);
  };
  UpdateStats st;
  const Vec3 v_norm_same = run(BrightnessModel::kNormalised, same, &st);
  const Vec3 v_norm_shifted = run(BrightnessModel::kNormalised, shifted, &st);
  const Vec3 v_levels_same = run(BrightnessModel::kLevels, same, &st);
  EXPECT_FALSE(st.light_change);
  const Vec3 v_levels_shifted = run(BrightnessModel::kLevels, shifted, &st);
  EXPECT_FALSE(st.light_change);
  const Vec3 v_levels_brighter = run(BrightnessModel::kLevels, brighter, &st);
  EXPECT_TRUE(st.light_change);
  EXPECT_EQ(v_levels_brighter, v_norm_same);  // compared as standardised
  // Equal levels and spreads: the levels' relation is the standardised one.
  EXPECT_LT((v_levels_same - v_norm_same).norm(), 1e-6 * truth.norm());
  // The spurious offset: restored by the levels, a bias when compared as standardised.
  const double e_same = (v_norm_same - truth).norm();
  EXPECT_LT((v_levels_shifted - v_levels_same).norm(), 1e-4 * truth.norm());
  EXPECT_GT((v_norm_shifted - v_norm_same).norm(), 0.01 * truth.norm()) << e_same;
}


// A pair under flickering light: the bands of the two images differ (their phase moved between the images). The
// row gains take them out and the state moves as on the unlit pair; the images compared as they are keep the bands
// in the residual and the state goes wrong. `auto` finds the bands from the first update on and switches the row
// gains on for the next; on the steady pair it does neither.
TEST_F(PhotometricScene, RowGainsRemoveBandsOfTheRows) {
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  const PreprocessedFrame ref = bandedFrame(scene_->ref.gray8, 0.0, 0.0, 1.6, 0.0);
  const PreprocessedFrame cur_steady = bandedFrame(scene_->cur.gray8, scene_->dt_s, 0.0, 1.6, 0.0);
  const PreprocessedFrame ref_banded = bandedFrame(scene_->ref.gray8, 0.0, 0.2, 1.6, 0.3);
  const PreprocessedFrame cur_banded = bandedFrame(scene_->cur.gray8, scene_->dt_s, 0.2, 1.6, 2.4);
  auto run = [&](BrightnessModel model, const PreprocessedFrame& r, const PreprocessedFrame& c, UpdateStats* st,
                 int updates = 1) {
    PhotometricParams params;
    params.brightness_model = model;
    params.stop_threshold = 0.0;
    PhotometricUpdate update(params, PreprocessParams{});
    double e = 0.0;
    for (int i = 0; i < updates; ++i) {
      State x = startState(0.5);
      ErrorCov P = priorCov();
      *st = update.update(r, c, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
      EXPECT_TRUE(st->applied);
      e = (x.vartheta - truth).norm();
    }
    return e;
  };
  UpdateStats st_steady, st_rows, st_plain, st_rows_steady, st_auto, st_auto_steady;
  const double e_steady = run(BrightnessModel::kNormalised, ref, cur_steady, &st_steady);
  const double e_rows = run(BrightnessModel::kRows, ref_banded, cur_banded, &st_rows);
  const double e_plain = run(BrightnessModel::kNormalised, ref_banded, cur_banded, &st_plain);
  const double e_rows_steady = run(BrightnessModel::kRows, ref, cur_steady, &st_rows_steady);
  EXPECT_LT(e_rows, e_steady + 0.01 * truth.norm()) << e_steady << " -> " << e_rows;
  EXPECT_GT(e_plain, e_rows + 0.02 * truth.norm()) << "the bands bias the images compared as they are";
  EXPECT_LT(e_rows_steady, e_steady + 0.01 * truth.norm()) << "the row gains on a steady pair";
  EXPECT_GT(st_rows.brightness_row_spread, 0.3);  // the pair's gain ratio spans about 1 -+ 0.35 down the rows
  EXPECT_LT(st_rows_steady.brightness_row_spread, 0.02);
  // What is left: the blur of a banded image is not the banded blurred image (sigma^2 grad g . grad I).
  EXPECT_LT(st_rows.rms_residual, 3.0 * st_steady.rms_residual);
  EXPECT_GT(st_plain.rms_residual, 5.0 * st_rows.rms_residual);
  EXPECT_GT(st_plain.row_gain_rms, 0.1);   // bands of about 17 % RMS in the residual
  EXPECT_LT(st_steady.row_gain_rms, 0.005);
  // auto: found on the first update, the row gains used from the second.
  const double e_auto = run(BrightnessModel::kAuto, ref_banded, cur_banded, &st_auto, 2);
  EXPECT_TRUE(st_auto.row_bands_found);
  EXPECT_TRUE(st_auto.row_gains);
  EXPECT_NEAR(e_auto, e_rows, 0.005 * truth.norm());
  run(BrightnessModel::kAuto, ref, cur_steady, &st_auto_steady, 3);
  EXPECT_FALSE(st_auto_steady.row_bands_found);
  EXPECT_FALSE(st_auto_steady.row_gains);
}

// The image's own measurement of vartheta (UpdateStats::vartheta_image, for the batch start-up of the distance):
// with a prior that holds vartheta far from the truth the posterior stays near the prior, the image's measurement
// does not; with the usual prior both agree.
TEST_F(PhotometricScene, ImageOnlyVarthetaDoesNotLeanOnThePrior) {
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  PhotometricParams params;
  params.gate_nis = 0.0;  // the tight prior's innovation is far outside the gate on purpose
  for (double sd : {0.5, 0.002}) {
    PhotometricUpdate update(params, PreprocessParams{});
    update.setReportImageVartheta(true);
    State x = startState(0.5);
    ErrorCov P = priorCov();
    P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) = sd * sd * Mat3::Identity();
    const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
    ASSERT_TRUE(st.applied);
    ASSERT_TRUE(st.vartheta_image_valid);
    const double e_image = (st.vartheta_image - truth).norm(), e_post = (x.vartheta - truth).norm();
    EXPECT_LT(e_image, 0.03 * truth.norm()) << "prior sd " << sd;
    if (sd < 0.01) EXPECT_GT(e_post, 0.3 * truth.norm()) << "the tight prior holds the posterior";
    else EXPECT_LT((st.vartheta_image - x.vartheta).norm(), 0.03 * truth.norm());
    const Eigen::SelfAdjointEigenSolver<Mat3> eig(st.vartheta_image_cov);
    EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
    EXPECT_LT((st.vartheta_image_cov - st.vartheta_image_cov.transpose()).norm(), 1e-9 * st.vartheta_image_cov.norm());
  }
}

TEST_F(PhotometricScene, ZeroMotionLeavesStateAlone) {
  PhotometricUpdate update(PhotometricParams{}, PreprocessParams{});
  State x;
  x.alpha = 1.0;
  x.mu = UnitVector(scene_->truth.mu);
  const State x0 = x;
  ErrorCov P = priorCov();
  const UpdateStats st = update.update(scene_->cur, scene_->cur, scene_->K, Vec3::Zero(), scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_LT(st.rms_residual, 1e-5);
  EXPECT_GT(st.valid_ratio, 0.95);
  EXPECT_LT(x.vartheta.norm(), 1e-3);
  EXPECT_LT(x.b_w.norm(), 1e-4);
  EXPECT_LT(x.mu.boxminus(x0.mu).norm(), 1e-3);
  EXPECT_EQ(x.alpha, x0.alpha);  // unobserved and uncorrelated in the prior
  const cv::Mat& res = update.residualImage();
  ASSERT_EQ(res.size(), scene_->cur.intensity.size());
  EXPECT_LT(cv::norm(res, cv::NORM_INF), 1e-5);
}

TEST_F(PhotometricScene, OnePassMovesVarthetaTowardTruth) {
  PhotometricParams params;
  params.max_passes = 1;
  PhotometricUpdate update(params, PreprocessParams{});
  for (double factor : {0.0, 0.5}) {
    State x = startState(factor);
    ErrorCov P = priorCov();
    const Vec3 truth = scene_->truth.vartheta_inv_s;
    const double err0 = (x.vartheta - truth).norm();
    const double mu_err0 = angleBetween(x.mu.vector(), scene_->truth.mu);
    const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
    ASSERT_TRUE(st.applied);
    EXPECT_EQ(st.passes, 1);
    const double err1 = (x.vartheta - truth).norm();
    const double mu_err1 = angleBetween(x.mu.vector(), scene_->truth.mu);
    // One pass removes at least 90 % of the vartheta error (measured: ~96 % from 0, ~97 % from half).
    EXPECT_LT(err1, 0.1 * err0) << "start factor " << factor << ": " << err0 << " -> " << err1;
    EXPECT_LE(mu_err1, mu_err0 + 1e-3) << "start factor " << factor;
  }
}

TEST_F(PhotometricScene, IteratedIsAtLeastAsCloseAsOnePass) {
  PhotometricParams one;
  one.max_passes = 1;
  PhotometricParams three;
  three.max_passes = 3;
  three.stop_threshold = 0.0;
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  State x1 = startState(0.0), x3 = startState(0.0);
  ErrorCov P1 = priorCov(), P3 = priorCov();
  PhotometricUpdate u1(one, PreprocessParams{}), u3(three, PreprocessParams{});
  const UpdateStats s1 = u1.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x1, &P1);
  const UpdateStats s3 = u3.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x3, &P3);
  ASSERT_TRUE(s1.applied);
  ASSERT_TRUE(s3.applied);
  EXPECT_EQ(s3.passes, 3);
  const double e1 = (x1.vartheta - truth).norm(), e3 = (x3.vartheta - truth).norm();
  EXPECT_LE(e3, e1 + 1e-3) << "one pass " << e1 << ", three passes " << e3;
  EXPECT_LT(e3, 0.02 * truth.norm());  // measured ~0.6 %
  EXPECT_LE(s3.rms_residual, s1.rms_residual + 1e-4);
  EXPECT_LT(s3.last_step_norm, s1.last_step_norm);
}

TEST_F(PhotometricScene, StopsEarlyBelowThreshold) {
  PhotometricParams params;
  params.max_passes = 10;
  params.stop_threshold = 0.05;
  PhotometricUpdate update(params, PreprocessParams{});
  State x = startState(0.0);
  ErrorCov P = priorCov();
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_LT(st.passes, 10);
  EXPECT_LT(st.last_step_norm, 0.05);
}

TEST_F(PhotometricScene, PosteriorCovarianceIsSymmetricPositiveAndSmaller) {
  for (int passes : {1, 3}) {
    PhotometricParams params;
    params.max_passes = passes;
    params.adaptive_noise = false;  // the fixed per-pixel noise: the information this scene is known to carry
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(0.5);
    const ErrorCov P0 = priorCov();
    ErrorCov P = P0;
    ASSERT_TRUE(update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P).applied);
    EXPECT_EQ((P - P.transpose()).cwiseAbs().maxCoeff(), 0.0);
    const Eigen::LLT<ErrorCov> llt(P);
    EXPECT_EQ(llt.info(), Eigen::Success) << passes << " passes";
    // Every observed direction gains information; vartheta much, mu less (its information scales with
    // |vartheta|^2), b_w least (rotation about x/y and translation along y/x look alike over a small field of
    // view).
    for (int k : kObserved) EXPECT_LT(P(k, k), P0(k, k)) << "index " << k << ", " << passes << " passes";
    for (int k = ErrIdx::kVartheta; k < ErrIdx::kVartheta + 3; ++k) {
      EXPECT_LT(P(k, k), 0.1 * P0(k, k)) << "index " << k << ", " << passes << " passes";
    }
    for (int k = ErrIdx::kMu; k < ErrIdx::kMu + 2; ++k) {
      EXPECT_LT(P(k, k), 0.5 * P0(k, k)) << "index " << k << ", " << passes << " passes";
    }
    // Unobserved, uncorrelated blocks keep their prior variance.
    EXPECT_NEAR(P(ErrIdx::kAlpha, ErrIdx::kAlpha), P0(ErrIdx::kAlpha, ErrIdx::kAlpha), 1e-12);
    EXPECT_NEAR(P(ErrIdx::kBa, ErrIdx::kBa), P0(ErrIdx::kBa, ErrIdx::kBa), 1e-12);
    if (passes == 1) {
      // Information only adds: P0 - P+ is positive semi-definite (Cholesky succeeds after a 1e-12 shift).
      const Eigen::LLT<ErrorCov> psd(P0 - P + 1e-12 * ErrorCov::Identity());
      EXPECT_EQ(psd.info(), Eigen::Success);
    }
  }
}

TEST_F(PhotometricScene, GradientWeightingAndHuberStillConverge) {
  PhotometricParams params;
  params.gradient_weighting = true;
  params.huber_threshold = 1.345;
  PhotometricUpdate update(params, PreprocessParams{});
  State x = startState(0.0);
  ErrorCov P = priorCov();
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  ASSERT_TRUE(update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P).applied);
  EXPECT_LT((x.vartheta - truth).norm(), 0.25 * truth.norm());
}

TEST_F(PhotometricScene, TooFewValidPixelsSkipsUpdate) {
  PhotometricUpdate update(PhotometricParams{}, PreprocessParams{});
  State x = startState(0.0);
  x.vartheta = Vec3(60.0, 0.0, 0.0);  // 1/s: every pixel maps ~180 px away, outside the reference image
  const State x0 = x;
  const ErrorCov P0 = priorCov();
  ErrorCov P = P0;
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  EXPECT_FALSE(st.applied);
  EXPECT_LT(st.valid_ratio, PhotometricParams{}.min_valid_ratio);
  EXPECT_EQ(x.vartheta, x0.vartheta);
  EXPECT_EQ(x.mu.quaternion().coeffs(), x0.mu.quaternion().coeffs());
  EXPECT_EQ(x.b_w, x0.b_w);
  EXPECT_EQ(P, P0);
}

TEST_F(PhotometricScene, NonFiniteInputSkipsUpdate) {
  PhotometricUpdate update(PhotometricParams{}, PreprocessParams{});
  State x = startState(0.0);
  const State x0 = x;
  const ErrorCov P0 = priorCov();
  ErrorCov P = P0;
  const Vec3 bad_gyro(std::nan(""), 0.0, 0.0);
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, bad_gyro, scene_->dt_s, &x, &P);
  EXPECT_FALSE(st.applied);
  EXPECT_EQ(x.vartheta, x0.vartheta);
  EXPECT_EQ(P, P0);
  // A prior that is not positive definite is refused as well.
  ErrorCov P_bad = P0;
  P_bad(ErrIdx::kVartheta, ErrIdx::kVartheta) = -1.0;
  const ErrorCov P_bad0 = P_bad;
  EXPECT_FALSE(update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P_bad).applied);
  EXPECT_EQ(P_bad, P_bad0);
  EXPECT_EQ(x.vartheta, x0.vartheta);
}

TEST_F(PhotometricScene, ResidualImageIsZeroOutsideTheMask) {
  PhotometricUpdate update(PhotometricParams{}, PreprocessParams{});
  State x = startState(0.0);
  ErrorCov P = priorCov();
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  const cv::Mat& res = update.residualImage();
  ASSERT_EQ(res.type(), CV_32FC1);
  EXPECT_EQ(res.at<float>(0, 0), 0.0f);
  EXPECT_EQ(res.at<float>(res.rows - 1, res.cols / 2), 0.0f);
  // RMS over the nonzero entries matches the reported RMS.
  const double sum2 = res.dot(res);
  const int nonzero = cv::countNonZero(res);
  ASSERT_GT(nonzero, 0);
  EXPECT_NEAR(std::sqrt(sum2 / (st.valid_ratio * 178 * 114)), st.rms_residual, 1e-3);
  EXPECT_GT(st.rms_residual, 0.0);
}


// --------------------------------------------------------------------------------------------------------
// Noise model and innovation gate (docs/noise_model.md).
// --------------------------------------------------------------------------------------------------------

/// The current frame with `noise` added to its intensity (gradients kept: the residual is what changes).
PreprocessedFrame withNoise(const PreprocessedFrame& f, const cv::Mat& noise) {
  PreprocessedFrame out = f;
  // A new buffer: assigning the sum to out.intensity would write into the data it shares with f.
  cv::Mat sum;
  cv::add(f.intensity, noise, sum);
  out.intensity = sum;
  return out;
}

TEST_F(PhotometricScene, NoiseModelMeasuresResidualScaleAndCorrelation) {
  const cv::Size size = scene_->cur.intensity.size();
  cv::RNG rng(7);
  cv::Mat white(size, CV_32FC1), raw(size, CV_32FC1), blurred;
  rng.fill(white, cv::RNG::NORMAL, 0.0, 0.3);
  rng.fill(raw, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(raw, blurred, cv::Size(0, 0), 2.0);
  cv::Scalar mean, sd;
  cv::meanStdDev(blurred, mean, sd);
  blurred *= 0.3 / sd[0];  // the same per-pixel scale, correlated over ~4 pi 2^2 = 50 px
  PhotometricParams params;
  params.max_passes = 1;
  params.gate_nis = 0.0;
  UpdateStats st[2];
  const cv::Mat* noise[2] = {&white, &blurred};
  for (int i = 0; i < 2; ++i) {
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(1.0);
    ErrorCov P = priorCov();
    st[i] = update.update(scene_->ref, withNoise(scene_->cur, *noise[i]), scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
    ASSERT_TRUE(st[i].applied);
    // The robust scale sees the added noise (plus the scene's own small residual).
    EXPECT_GT(st[i].residual_sigma, 0.27) << i;
    EXPECT_LT(st[i].residual_sigma, 0.45) << i;
    EXPECT_NEAR(st[i].noise_sigma, st[i].residual_sigma, 1e-12) << "first frame: its own estimate";
  }
  // Independent pixels: about one pixel per independent measurement; correlated ones: many.
  EXPECT_GT(st[0].correlation, 0.5);
  EXPECT_LT(st[0].correlation, 2.5);
  EXPECT_GT(st[1].correlation, 4.0 * st[0].correlation) << st[0].correlation << " vs " << st[1].correlation;
  // The information used follows: per-pixel variance times correlation area.
  EXPECT_GT(st[1].noise_correlation, 4.0 * st[0].noise_correlation);
}

TEST_F(PhotometricScene, NoiseModelFloorsAreTheSensorNoiseAndTheBlur) {
  PhotometricParams params;
  params.max_passes = 1;
  params.gate_nis = 0.0;
  params.sensor_noise_grey = 50.0;  // far above the scene's residual: the floor decides
  PhotometricUpdate update(params, PreprocessParams{});
  update.setPreprocessNoise(0.1, 8.0);
  State x = startState(1.0);
  ErrorCov P = priorCov();
  PreprocessedFrame cur = scene_->cur;
  cur.grey_per_unit = 40.0;
  const UpdateStats st = update.update(scene_->ref, cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_NEAR(st.noise_sigma, std::sqrt(2.0 * 50.0 * 50.0 * 0.1) / 40.0, 1e-9);
  EXPECT_GE(st.noise_correlation, 8.0);
}

TEST_F(PhotometricScene, GateBoundsTheStepOfAnInconsistentUpdate) {
  // A prior far too confident for its error (vartheta 0 against the truth, 1-sigma 5 mm/s): the innovation fails
  // the chi-square test and the frame is down-weighted until its NIS is the target; the step, in prior sigmas,
  // is then at most sqrt(target).
  PhotometricParams params;
  params.max_passes = 1;
  PhotometricUpdate update(params, PreprocessParams{});
  State x = startState(0.0);
  const State x_prior = x;
  const ErrorCov P0 = priorCov() * 1e-4;
  ErrorCov P = P0;
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_TRUE(st.gated);
  EXPECT_GT(st.nis, params.gate_nis);
  EXPECT_GT(st.gate_inflation, 1.0);
  const ErrorVec e = x.boxminus(x_prior);
  const double step2 = e.dot(P0.ldlt().solve(e));
  EXPECT_LE(step2, params.gate_target_nis * 1.05) << "NIS " << st.nis << ", inflation " << st.gate_inflation;
  EXPECT_GT(step2, 1e-4) << "down-weighted, not discarded";

  // The same frame with a prior that admits the error passes the gate untouched.
  PhotometricUpdate update2(params, PreprocessParams{});
  State x2 = startState(0.0);
  ErrorCov P2 = priorCov();
  const UpdateStats st2 = update2.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x2, &P2);
  ASSERT_TRUE(st2.applied);
  EXPECT_FALSE(st2.gated) << "NIS " << st2.nis;
  EXPECT_EQ(st2.gate_inflation, 1.0);
}

TEST_F(PhotometricScene, AnImprobableFrameDoesNotMoveTheTimeStates) {
  // The time offset's column active (rates given), the gate off: a frame whose NIS lies above the 95 % quantile of
  // chi-square(8) updates the state but not the offset (docs/algorithm.md section 3.6); one below it moves the offset.
  PhotometricParams params;
  params.max_passes = 1;
  params.gate_nis = 0.0;  // the quantile alone
  ImageTiming timing;
  timing.estimate_offset = true;
  timing.rates_valid = true;
  timing.gravity_mps2 = 9.81;
  timing.accel_C = Vec3(0.8, -0.5, -9.81);   // m/s^2
  timing.rate_change_C = Vec3(0.3, -0.2, 0.1);  // rad/s between the images: the offset is seen
  auto run = [&](double cov_scale, State* x, UpdateStats* st) {
    PhotometricUpdate update(params, PreprocessParams{});
    *x = startState(0.0);
    ErrorCov P = priorCov() * cov_scale;
    P(ErrIdx::kTd, ErrIdx::kTd) = 0.01 * 0.01;  // s^2: the offset's prior as configured by default
    *st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, x, &P, 0.0, timing);
  };
  State x_tight, x_loose;
  UpdateStats st_tight, st_loose;
  run(1e-4, &x_tight, &st_tight);  // vartheta 0 against the truth with a 1-sigma of a few mm/s: improbable
  run(1.0, &x_loose, &st_loose);
  std::printf("NIS %.1f: offset step %.3g ms; NIS %.1f: offset step %.3g ms\n", st_tight.nis, 1e3 * x_tight.t_d_s,
              st_loose.nis, 1e3 * x_loose.t_d_s);
  ASSERT_TRUE(st_tight.applied);
  ASSERT_TRUE(st_loose.applied);
  EXPECT_GT(st_tight.nis, 15.507);
  EXPECT_FALSE(st_tight.gated);
  EXPECT_EQ(x_tight.t_d_s, 0.0) << "an improbable frame must not move the offset";
  EXPECT_GT((x_tight.vartheta - startState(0.0).vartheta).norm(), 0.0) << "the frame still updates the state";
  EXPECT_LT(st_loose.nis, 15.507);
  EXPECT_NE(x_loose.t_d_s, 0.0) << "a probable frame moves the offset";
}

TEST_F(PhotometricScene, AnImprobableFrameHoldsCorrelatedTimeStates) {
  // As above, with the time states correlated with vartheta (a filter that has estimated them for a while): an
  // improbable frame must leave the offset, the readout and the focal scale and their covariance block as they were
  // (consider states), while vartheta and its cross-covariance with them are updated.
  PhotometricParams params;
  params.max_passes = 1;
  params.gate_nis = 0.0;
  ImageTiming timing;
  timing.estimate_offset = true;
  timing.rates_valid = true;
  timing.gravity_mps2 = 9.81;
  timing.accel_C = Vec3(0.8, -0.5, -9.81);      // m/s^2
  timing.rate_change_C = Vec3(0.3, -0.2, 0.1);  // rad/s
  PhotometricUpdate update(params, PreprocessParams{});
  State x = startState(0.0);
  ErrorCov P = priorCov() * 1e-4;  // improbable: vartheta 0 against the truth with a 1-sigma of a few mm/s
  P(ErrIdx::kTd, ErrIdx::kTd) = 0.002 * 0.002;     // s^2
  P(ErrIdx::kRo, ErrIdx::kRo) = 0.003 * 0.003;     // s^2
  P(ErrIdx::kFs, ErrIdx::kFs) = 0.01 * 0.01;       // unitless
  for (int k = 0; k < 3; ++k) {
    const int t = ErrIdx::kTd + k, v = ErrIdx::kVartheta + k;
    P(t, v) = P(v, t) = 0.6 * std::sqrt(P(t, t) * P(v, v));  // correlation 0.6
  }
  ASSERT_GT(P.ldlt().vectorD().minCoeff(), 0.0);
  const State x0 = x;
  const ErrorCov P0 = P;
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P, 0.0,
                                       timing);
  ASSERT_TRUE(st.applied);
  ASSERT_GT(st.nis, 15.507);
  EXPECT_EQ(x.t_d_s, x0.t_d_s);
  EXPECT_EQ(x.readout_s, x0.readout_s);
  EXPECT_EQ(x.focal_scale, x0.focal_scale);
  const auto time_block = [](const ErrorCov& M) { return M.block<3, 3>(ErrIdx::kTd, ErrIdx::kTd); };
  EXPECT_EQ((time_block(P) - time_block(P0)).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_GT((x.vartheta - x0.vartheta).norm(), 0.0) << "the frame still updates the state";
  EXPECT_GT((P.block<3, 3>(ErrIdx::kTd, ErrIdx::kVartheta) - P0.block<3, 3>(ErrIdx::kTd, ErrIdx::kVartheta))
                .cwiseAbs()
                .maxCoeff(),
            0.0)
      << "the cross-covariance follows vartheta's update";
  EXPECT_GT(P.ldlt().vectorD().minCoeff(), 0.0) << "the covariance stays positive definite";
}

TEST_F(PhotometricScene, AConsideredOffsetWidensTheUpdateWithoutMoving) {
  // Before the offset is estimated (docs/algorithm.md section 3.6) it is a consider state: its column is in the
  // update, its estimate and variance are held. For the other states that is the Kalman update with the offset
  // estimated (Schmidt): the same mean, covariance and cross-covariance; and it is more cautious than the update
  // without the column, whose cross-covariance with the offset stays zero.
  ImageTiming timing;
  timing.rates_valid = true;
  timing.gravity_mps2 = 9.81;
  timing.accel_C = Vec3(0.8, -0.5, -9.81);      // m/s^2
  timing.rate_change_C = Vec3(0.3, -0.2, 0.1);  // rad/s between the images: the offset is seen
  expectConsideredStateHeld(timing, &ImageTiming::estimate_offset, &ImageTiming::consider_offset, ErrIdx::kTd,
                            &State::t_d_s, "td");
}

TEST_F(PhotometricScene, AConsideredReadoutWidensTheUpdateWithoutMoving) {
  // Before the rolling shutter's readout is estimated (docs/algorithm.md section 3.7: with the offset, or once the
  // offset is known to readout_start_sigma_time_offset_s) it is a consider state from the filter's convergence, as
  // the offset is above: an unmodelled readout of 16 ms in a fast dash put the velocity 11 sigma off (docs/results.md
  // "The readout as a consider state").
  std::vector<float> row_weight;
  const ImageTiming timing = rollingTiming(Vec3(0.8, -0.5, -9.81), Vec3(0.3, -0.2, 0.1), &row_weight);
  expectConsideredStateHeld(timing, &ImageTiming::estimate_readout, &ImageTiming::consider_readout, ErrIdx::kRo,
                            &State::readout_s, "ro");
}

TEST_F(PhotometricScene, TheRowsAllowForAlphasUncertainty) {
  // A configured 16 ms readout: each row is warped with the motion at its own time, vartheta's rate taking alpha
  // times the acceleration (docs/algorithm.md section 3.7). With alpha 2.5 times too large (a filter started at
  // 0.33 m over ground at 0.84 m) the rows mispredict the flow; alpha's variance tells how much. Marginalised with
  // it, the rows' misprediction is allowed for: the innovation is no longer improbable, vartheta is not pulled by
  // it, and alpha is not moved by the rows. With alpha known (its variance tiny) the same rows are taken as exact.
  std::vector<float> row_weight;
  // 2.7 m/s^2 once gravity g0 g = (0, 0, 9.81) is added.
  const ImageTiming timing = rollingTiming(Vec3(2.0, -1.5, -9.81 + 1.0), Vec3::Zero(), &row_weight);
  PhotometricParams params;
  params.max_passes = 1;
  const double alpha_wrong = 2.5 / scene_->truth.d_m;  // 1/m
  double nis[2], err_vartheta[2];
  for (int v = 0; v < 2; ++v) {
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(1.0);
    x.alpha = alpha_wrong;
    x.readout_s = 0.016;
    ErrorCov P = priorCov();
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = v == 0 ? 1e-8 : 9.0;  // (1/m)^2: known; or the default initial 3 / m
    const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P, 0.0,
                                         timing);
    ASSERT_TRUE(st.applied);
    EXPECT_EQ(x.alpha, alpha_wrong) << "the rows do not move alpha";
    nis[v] = st.nis;
    err_vartheta[v] = (x.vartheta - scene_->truth.vartheta_inv_s).norm();
  }
  std::printf("alpha 2.5x too large, the rows from it: NIS %.1f with alpha taken as known, %.1f with its variance; "
              "vartheta error %.4f / %.4f 1/s\n",
              nis[0], nis[1], err_vartheta[0], err_vartheta[1]);
  EXPECT_LT(nis[1], 0.5 * nis[0]);
  EXPECT_LT(err_vartheta[1], err_vartheta[0]);
}

TEST_F(PhotometricScene, RotationModelErrorDiscountsTheGyroRotation) {
  // The gyro's interval rotation off by 0.1 rad/s about the camera's x and y axes (a scale-factor, focal length
  // or timing error of the rotation, far outside the b_w prior). Without the rotation model error the image must
  // explain the extra rotation with the states it has: b_w, held by its prior, and through the translation-
  // rotation ambiguity vartheta and mu. With it (docs/noise_model.md, section 6: here a relative 1-sigma of 50 %
  // of the interval rotation), the rotation-like part of the flow is discounted: the innovation is consistent,
  // vartheta and mu stay near the truth and the image tells less about b_w.
  const Vec3 gyro_bad = scene_->w_C + Vec3(0.1, -0.1, 0.0);
  struct Result {
    double nis, var_bw, vartheta_err, mu_err;
  };
  auto run = [&](double scale_sigma, const Vec3& gyro) {
    PhotometricParams params;
    params.rotation_scale_sigma = scale_sigma;
    params.time_offset_sigma_s = 0.0;
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(1.0);
    x.mu = UnitVector(scene_->truth.mu);
    ErrorCov P = priorCov();
    const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, gyro, scene_->dt_s, &x, &P);
    EXPECT_TRUE(st.applied);
    return Result{st.nis, P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw).trace(),
                  (x.vartheta - scene_->truth.vartheta_inv_s).norm(), angleBetween(x.mu.vector(), scene_->truth.mu)};
  };
  const Result good = run(0.0, scene_->w_C), off = run(0.0, gyro_bad), on = run(0.5, gyro_bad);
  std::printf("vartheta error, 1/s: right gyro %.4f; wrong gyro %.4f, with the rotation model error %.4f\n"
              "mu error, rad: %.4f; %.4f, %.4f; NIS %.1f; %.1f, %.1f; tr P_bw %.3g; %.3g, %.3g\n",
              good.vartheta_err, off.vartheta_err, on.vartheta_err, good.mu_err, off.mu_err, on.mu_err, good.nis,
              off.nis, on.nis, good.var_bw, off.var_bw, on.var_bw);
  EXPECT_LT(on.nis, 0.5 * off.nis);
  EXPECT_LT(on.vartheta_err, 0.5 * off.vartheta_err);
  EXPECT_LT(on.mu_err, 0.5 * off.mu_err);
  EXPECT_GT(on.var_bw, off.var_bw);

  // No rotation, no change of rate: the model error vanishes and the update is the plain one, bit for bit.
  PhotometricParams plain;
  plain.rotation_scale_sigma = 0.0;
  plain.time_offset_sigma_s = 0.0;
  PhotometricUpdate with_model(PhotometricParams{}, PreprocessParams{}), without_model(plain, PreprocessParams{});
  State xa = startState(0.5), xb = xa;
  ErrorCov Pa = priorCov(), Pb = Pa;
  with_model.update(scene_->ref, scene_->cur, scene_->K, Vec3::Zero(), scene_->dt_s, &xa, &Pa);
  without_model.update(scene_->ref, scene_->cur, scene_->K, Vec3::Zero(), scene_->dt_s, &xb, &Pb);
  EXPECT_EQ(xa.vartheta, xb.vartheta);
  EXPECT_EQ(Pa, Pb);
}

TEST_F(PhotometricScene, GyroNoiseBoundsWhatOneImageSaysOfTheGyroBias) {
  // The interval's rotation comes from the gyro, whose white noise of density s makes its angle uncertain by
  // s^2 dt (docs/noise_model.md section 6). However sharp the image, one pair can then not pin the gyro bias
  // better than a measurement of it with the variance s^2 / dt: the posterior variance of each b_w axis is at
  // least 1 / (1 / P0 + dt / s^2). Here s^2 / dt equals the prior P0, so at least half of P0 is left; without the
  // noise term the image takes most of it.
  PhotometricParams params;
  params.rotation_scale_sigma = 0.0;
  params.time_offset_sigma_s = 0.0;
  auto posterior_bw = [&](double density_sq) {
    PhotometricUpdate update(params, PreprocessParams{});
    State x = startState(1.0);
    ErrorCov P = priorCov();
    ImageTiming timing;
    timing.gyro_noise_density_sq = density_sq;
    const UpdateStats st =
        update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P, 0.0, timing);
    EXPECT_TRUE(st.applied);
    return Vec3(P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw).diagonal());
  };
  const double P0 = priorCov()(ErrIdx::kBw, ErrIdx::kBw);
  const Vec3 with_noise = posterior_bw(P0 * scene_->dt_s), without = posterior_bw(0.0);
  std::printf("posterior b_w variance / prior: with the gyro noise %.3f %.3f %.3f, without %.3f %.3f %.3f\n",
              with_noise.x() / P0, with_noise.y() / P0, with_noise.z() / P0, without.x() / P0, without.y() / P0,
              without.z() / P0);
  for (int i = 0; i < 3; ++i) {
    EXPECT_GE(with_noise(i), 0.5 * P0 * (1.0 - 1e-9)) << "axis " << i;
    EXPECT_LT(without(i), 0.5 * P0) << "axis " << i;
  }
}

TEST(PhotometricOutliers, AnObjectMovingOnItsOwnIsDownWeighted) {
  // The two-view scene of PhotometricScene, three images, with an object of another texture (a rectangle covering
  // 12 % of the image) moving on its own: 6 cm sideways between two images, against the camera's 1 cm. Its pixels
  // obey no plane motion. The update of the second pair weights the pixels of its reference (the first pair's
  // current image) by how badly their neighbourhood fitted in the first update (docs/noise_model.md, section 10),
  // sampled where the warp lands: the object's blob is down-weighted and the estimate returns close to the one
  // without the object; without the weights it is pulled away.
  const int W = 180, H = 116;
  const double dt = 1.0 / 30.0;
  const PinholeK K = test_util::makeK(W, H);
  const Vec3 v_W(0.30, -0.20, 0.05), w_C(0.10, -0.05, 0.20);
  const test_util::Plane ground;
  const test_util::CameraPose cur = test_util::lookDownPose(Vec3(0.1, -0.2, 1.0), 0.3, 0.15);
  const test_util::PlaneTruth truth = test_util::planeTruth(ground, cur, v_W);
  const test_util::PlaneTexture ground_texture(7), object_texture(99);
  const cv::Rect box(70, 35, 50, 50);
  // Image j (0, 1, 2) at t = (j - 2) dt, with and without the object.
  std::vector<PreprocessedFrame> clean, cluttered;
  for (int j = 0; j < 3; ++j) {
    const double t = (j - 2) * dt;
    cv::Mat img = test_util::renderPlane(ground_texture, ground, K, test_util::propagate(cur, v_W, w_C, t), 3);
    clean.push_back(test_util::makeFrame(test_util::toGray8(img), t));
    const cv::Mat obj = test_util::renderPlane(object_texture, ground, K,
                                               test_util::propagate(cur, Vec3(1.8, 0.6, 0.0), Vec3::Zero(), t), 3);
    obj(box).copyTo(img(box));
    cluttered.push_back(test_util::makeFrame(test_util::toGray8(img), t));
  }

  auto start = [&]() {
    State x;
    x.alpha = 1.0 / truth.d_m;
    x.vartheta = 0.5 * truth.vartheta_inv_s;
    x.mu = UnitVector(truth.mu).boxplus(Vec2(0.04, -0.03));
    x.g = UnitVector(Vec3(0.0, 0.0, 1.0));
    return x;
  };
  // Error of the second pair's update (the first builds the weights; both start from the same prior).
  // With `between` the filter restarts between the two updates (Estimator: the noise model reset, the weights
  // kept; or forgotten too).
  enum class Between { kNothing, kNoiseReset, kWeightsForgotten };
  auto second_update_error = [&](const std::vector<PreprocessedFrame>& f, double k, UpdateStats* st,
                                 Between between = Between::kNothing) {
    PhotometricParams params;
    params.outlier_threshold_sigma = k;
    params.noise_time_constant_s = 0.0;  // each update's noise scale its own
    PhotometricUpdate update(params, PreprocessParams{});
    for (int i = 0; i < 2; ++i) {
      State x = start();
      ErrorCov P = priorCov();
      *st = update.update(f[i], f[i + 1], K, w_C, dt, &x, &P);
      EXPECT_TRUE(st->applied);
      if (i == 1) return (x.vartheta - truth.vartheta_inv_s).norm();
      if (between != Between::kNothing) update.resetNoiseModel();
      if (between == Between::kWeightsForgotten) update.forgetWeights();
    }
    return 0.0;
  };
  UpdateStats st_clean, st_plain, st_robust, st_clean_robust, st_reset, st_forgotten;
  const double e_clean = second_update_error(clean, 0.0, &st_clean);
  const double e_clean_robust = second_update_error(clean, 3.0, &st_clean_robust);
  const double e_plain = second_update_error(cluttered, 0.0, &st_plain);
  const double e_robust = second_update_error(cluttered, 3.0, &st_robust);
  const double e_reset = second_update_error(cluttered, 3.0, &st_reset, Between::kNoiseReset);
  const double e_forgotten = second_update_error(cluttered, 3.0, &st_forgotten, Between::kWeightsForgotten);
  std::printf("vartheta error, 1/s: no object %.4f (with weights %.4f, %.1f %% removed); object %.4f, with the "
              "outlier weights %.4f (%.1f %% of the weight removed); after a restart of the noise model %.4f "
              "(%.1f %%), with the weights forgotten too %.4f\n",
              e_clean, e_clean_robust, 100.0 * st_clean_robust.outlier_fraction, e_plain, e_robust,
              100.0 * st_robust.outlier_fraction, e_reset, 100.0 * st_reset.outlier_fraction, e_forgotten);
  EXPECT_GT(e_plain, 3.0 * e_clean) << "the object must matter without the weights";
  EXPECT_LT(e_robust, 0.5 * e_plain);
  EXPECT_GT(st_robust.outlier_fraction, 0.05);
  EXPECT_LT(st_robust.outlier_fraction, 0.4);
  EXPECT_EQ(st_plain.outlier_fraction, 0.0);
  // The weights describe the image, not the state: a restart of the filter keeps them for the next pair.
  // (Not bit for bit: the reset also forgets the last gyro rate of the rotation model.)
  EXPECT_NEAR(e_reset, e_robust, 0.05 * e_robust);
  EXPECT_NEAR(st_reset.outlier_fraction, st_robust.outlier_fraction, 1e-3);
  EXPECT_NEAR(e_forgotten, e_plain, 0.05 * e_plain);
  // No object: the weights change little.
  EXPECT_LT(st_clean_robust.outlier_fraction, 0.05);
  EXPECT_LT(e_clean_robust, e_clean + 0.01);
}

TEST(PhotometricConfidence, APatchFixedInTheImageIsDownWeightedWhereTheWarpLandsToo) {
  // Smooth patches fixed in the image on both images of the pair (projector dots filled from their surroundings,
  // docs/noise_model.md section 11): 84 small discs of a flat grey, 11 % of the image, at the same pixels in both
  // images.
  // The current image's confidence (0 on the discs and a pixel around them) removes the residuals whose current
  // sample is a patch; those whose warped reference sample lands on a patch stay, and vote for "no motion" (the
  // patch does not move with the ground). The same confidence given for the reference too
  // (setReferenceConfidence, sampled where the warp lands) removes them as well.
  const int W = 180, H = 116;
  const double dt = 1.0 / 30.0;
  const PinholeK K = test_util::makeK(W, H);
  const Vec3 v_W(0.45, -0.25, 0.05), w_C(0.05, -0.03, 0.10);
  const test_util::Plane ground;
  const test_util::CameraPose cur = test_util::lookDownPose(Vec3(0.1, -0.2, 1.0), 0.2, 0.1);
  const test_util::PlaneTruth truth = test_util::planeTruth(ground, cur, v_W);
  const test_util::PlaneTexture texture(7);
  cv::Mat patches(H, W, CV_8UC1, cv::Scalar(0));
  for (int i = 0; i < 84; ++i) {
    const int cx = 8 + (i % 12) * 14 + (i / 12) * 2, cy = 9 + (i / 12) * 16;
    cv::circle(patches, cv::Point(cx, cy), 3, cv::Scalar(255), cv::FILLED);
  }
  cv::Mat grown;  // (the preprocessing's blur and gradients spread a patch by a pixel)
  cv::dilate(patches, grown, cv::Mat::ones(3, 3, CV_8UC1));
  cv::Mat confidence(H, W, CV_32FC1, cv::Scalar(1.0f));
  confidence.setTo(0.0f, grown);
  std::vector<PreprocessedFrame> clean, patched;
  for (int j = 0; j < 2; ++j) {
    const double t = (j - 1) * dt;
    const cv::Mat img = test_util::renderPlane(texture, ground, K, test_util::propagate(cur, v_W, w_C, t), 3);
    cv::Mat grey = test_util::toGray8(img);
    clean.push_back(test_util::makeFrame(grey, t));
    grey.setTo(cv::mean(grey)[0], patches);
    patched.push_back(test_util::makeFrame(grey, t));
  }
  const double share = cv::countNonZero(patches) / static_cast<double>(W * H);
  auto error = [&](const std::vector<PreprocessedFrame>& f, const cv::Mat* cur_conf, const cv::Mat* ref_conf) {
    PhotometricParams params;
    params.outlier_threshold_sigma = 0.0;  // the confidence alone
    PhotometricUpdate update(params, PreprocessParams{});
    update.setPixelConfidence(cur_conf);
    update.setReferenceConfidence(ref_conf);
    State x;
    x.alpha = 1.0 / truth.d_m;
    x.vartheta = 0.5 * truth.vartheta_inv_s;
    x.mu = UnitVector(truth.mu).boxplus(Vec2(0.04, -0.03));
    x.g = UnitVector(Vec3(0.0, 0.0, 1.0));
    ErrorCov P = priorCov();
    const UpdateStats st = update.update(f[0], f[1], K, w_C, dt, &x, &P);
    EXPECT_TRUE(st.applied);
    return (x.vartheta - truth.vartheta_inv_s).norm() / truth.vartheta_inv_s.norm();
  };
  const double e_clean = error(clean, nullptr, nullptr);
  const double e_clean_both = error(clean, &confidence, &confidence);
  const double e_none = error(patched, nullptr, nullptr);
  const double e_current = error(patched, &confidence, nullptr);
  const double e_both = error(patched, &confidence, &confidence);
  std::printf("patches on %.1f %% of the image; relative vartheta error: no patches %.4f (both confidences %.4f); "
              "patches %.4f, current confidence %.4f, both %.4f\n",
              100.0 * share, e_clean, e_clean_both, e_none, e_current, e_both);
  EXPECT_GT(share, 0.10);
  EXPECT_GT(e_none, 4.0 * e_clean) << "the patches must matter";
  EXPECT_LT(e_current, e_none);
  EXPECT_GT(e_current, 1.3 * e_clean_both) << "the reference's patches pull when only the current's are weighted";
  EXPECT_LT(e_both, 1.1 * e_clean_both) << "the reference's patches must be down-weighted too";
  // Without the reference's confidence nothing changes (bit for bit: the same sweep as before it existed).
  EXPECT_EQ(error(patched, &confidence, nullptr), e_current);
}

/// The ground (z = 0) with a box standing on it: its top at `box_top_m`, footprint |X - c| <= half (x, y), m.
/// Textures at world (X, Y); the box's sides are not drawn (the top hides the ground behind it).
cv::Mat renderGroundWithBox(const test_util::PlaneTexture& ground_tex, const test_util::PlaneTexture& box_tex,
                            const Vec2& centre, const Vec2& half, double box_top_m, const PinholeK& K,
                            const test_util::CameraPose& pose) {
  constexpr int ss = 3;
  cv::Mat img(K.height, K.width, CV_32FC1);
  for (int y = 0; y < K.height; ++y) {
    for (int x = 0; x < K.width; ++x) {
      double sum = 0.0;
      for (int sy = 0; sy < ss; ++sy) {
        for (int sx = 0; sx < ss; ++sx) {
          const double u = x - 0.5 + (sx + 0.5) / ss, v = y - 0.5 + (sy + 0.5) / ss;
          const Vec3 ray = pose.R_WC * Vec3((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
          const Vec3 top = pose.p_WC + ((box_top_m - pose.p_WC.z()) / ray.z()) * ray;
          if (std::abs(top.x() - centre.x()) <= half.x() && std::abs(top.y() - centre.y()) <= half.y()) {
            sum += box_tex(top.x(), top.y());
          } else {
            const Vec3 g = pose.p_WC + (-pose.p_WC.z() / ray.z()) * ray;
            sum += ground_tex(g.x(), g.y());
          }
        }
      }
      img.ptr<float>(y)[x] = static_cast<float>(sum / (ss * ss));
    }
  }
  return img;
}

/// The box flight of the parallax tests: 180 x 116 px at 30 Hz, 1 m above the ground at 0.1 m/s, frame j of
/// `frames` at (j - (frames - 1)) dt (the last at 0); the box top 0.15 m high, 0.5 x 0.4 m (12 % of the image).
struct BoxFlight {
  static constexpr int W = 180, H = 116;
  const double dt = 1.0 / 30.0;
  const PinholeK K = test_util::makeK(W, H);
  const Vec3 v_W{0.10, 0.02, 0.0}, w_C{0.0, 0.0, 0.0};
  const test_util::Plane ground;
  const test_util::PlaneTexture ground_texture{7};
  const test_util::CameraPose last = test_util::lookDownPose(Vec3(0.25, 0.0, 1.0), 0.2, 0.0);
  int frames;
  explicit BoxFlight(int n) : frames(n) {}
  double time(int j) const { return (j - (frames - 1)) * dt; }
  test_util::CameraPose pose(int j) const { return test_util::propagate(last, v_W, w_C, time(j)); }
  PreprocessedFrame frame(int j, bool box, double t_shift_s = 0.0) const {
    const cv::Mat img = box ? renderGroundWithBox(ground_texture, ground_texture, Vec2(0.05, 0.0), Vec2(0.25, 0.2),
                                                  0.15, K, pose(j))
                            : test_util::renderPlane(ground_texture, ground, K, pose(j), 3);
    return test_util::makeFrame(test_util::toGray8(img), time(j) + t_shift_s);
  }
  /// The prior of the parallax tests for the update onto frame j: the truth with vartheta 20 % low and the normal
  /// of a converged filter (1-sigma 0.01 rad, 0.6 mrad off).
  void prior(int j, State* x, ErrorCov* P) const {
    const test_util::PlaneTruth tj = test_util::planeTruth(ground, pose(j), v_W);
    *x = State();
    x->alpha = 1.0 / tj.d_m;
    x->vartheta = 0.8 * tj.vartheta_inv_s;
    x->mu = UnitVector(tj.mu).boxplus(Vec2(0.0005, -0.0003));
    *P = priorCov();
    P->block<2, 2>(ErrIdx::kMu, ErrIdx::kMu) = 1e-4 * Mat2::Identity();
  }
};

TEST(PhotometricOutliers, ARaisedBoxIsFoundOverTheImagesAndDownWeighted) {
  // A camera 1 m above the ground flies at 0.6 m/s over a box whose top stands 0.2 m high (12 % of the image): its
  // pixels move 25 % faster than the ground's, a third of a pixel per image, too little for one image's residual
  // to stand out, and they pull the velocity over distance up. The parallax test (docs/noise_model.md,
  // section 10) measures each neighbourhood's inverse depth over the images, carried along the warp: the box is
  // down-weighted and the estimate returns to the one without it.
  const BoxFlight flight(24);
  const int W = BoxFlight::W, H = BoxFlight::H, frames = flight.frames;
  const PinholeK& K = flight.K;
  const test_util::CameraPose& last = flight.last;
  std::vector<PreprocessedFrame> with_box, without_box;
  for (int j = 0; j < frames; ++j) {
    with_box.push_back(flight.frame(j, true));
    without_box.push_back(flight.frame(j, false));
  }
  // The box top's pixels in the last image (2 px inside its edges: the weights there come from the edges' own
  // residual, the occlusion), and the mean outlier weight in and outside it.
  cv::Mat box_mask(H, W, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Vec3 ray = last.R_WC * Vec3((x - K.cx) / K.fx, (y - K.cy) / K.fy, 1.0);
      const Vec3 top = last.p_WC + ((0.15 - last.p_WC.z()) / ray.z()) * ray;
      const double m = 2.0 * last.p_WC.z() / K.fx;
      if (std::abs(top.x() - 0.05) <= 0.25 - m && std::abs(top.y()) <= 0.2 - m) box_mask.at<uint8_t>(y, x) = 255;
    }
  ASSERT_GT(cv::countNonZero(box_mask), W * H / 12);
  struct Run {
    double err = 0.0;           // relative error of |vartheta| of the last update
    double removed = 0.0;       // its outlier_fraction
    double box_weight = 1.0;    // mean outlier weight over the box top, for the next image
    double ground_weight = 1.0; // ... and elsewhere
    double relief = 0.0;        // sqrt(relief_var) of the last update
  };
  // Each update from the same kind of prior: the truth with vartheta 20 % low and the normal of a converged
  // filter (1-sigma 0.01 rad, 0.6 mrad off): the test compares inverse depths with the plane's, which must be known.
  auto run = [&](const std::vector<PreprocessedFrame>& f, double tolerance) {
    PhotometricParams params;
    params.parallax_tolerance = tolerance;
    PhotometricUpdate update(params, PreprocessParams{});
    Run out;
    for (int j = 0; j + 1 < frames; ++j) {
      State x;
      ErrorCov P;
      flight.prior(j + 1, &x, &P);
      const double true_speed = x.vartheta.norm() / 0.8;  // (the prior's vartheta is 20 % low)
      const UpdateStats st = update.update(f[j], f[j + 1], K, flight.w_C, flight.dt, &x, &P);
      EXPECT_TRUE(st.applied);
      out.err = x.vartheta.norm() / true_speed - 1.0;
      out.removed = st.outlier_fraction;
      out.relief = std::sqrt(st.relief_var);
    }
    const cv::Mat& w = update.outlierWeights();
    if (!w.empty()) {
      out.box_weight = cv::mean(w, box_mask)[0];
      cv::Mat outside;
      cv::bitwise_not(box_mask, outside);
      out.ground_weight = cv::mean(w, outside)[0];
    }
    return out;
  };
  const double tolerance = PhotometricParams{}.parallax_tolerance;
  const Run clean = run(without_box, 0.0), clean_parallax = run(without_box, tolerance);
  const Run plain = run(with_box, 0.0), parallax = run(with_box, tolerance);
  std::printf("relative |vartheta| error (removed; weight on the box top / elsewhere):\n"
              "  no box %+.4f (%.1f %%), with the parallax test %+.4f (%.1f %%)\n"
              "  box %+.4f (%.1f %%; %.2f / %.2f), with the parallax test %+.4f (%.1f %%; %.2f / %.2f)\n",
              clean.err, 100.0 * clean.removed, clean_parallax.err, 100.0 * clean_parallax.removed, plain.err,
              100.0 * plain.removed, plain.box_weight, plain.ground_weight, parallax.err, 100.0 * parallax.removed,
              parallax.box_weight, parallax.ground_weight);
  // With a tolerance so wide that the box keeps its weight, its inverse depth stays in the image's estimate of the
  // plane, and the relief (docs/noise_model.md section 13) says by how much the scene is not one plane.
  const Run kept = run(with_box, 10.0), clean_kept = run(without_box, 10.0);
  std::printf("relief 1-sigma (relative): no box %.4f, box %.4f; with a tolerance of 10: no box %.4f, box %.4f "
              "(weight on the box top %.2f)\n",
              clean_parallax.relief, parallax.relief, clean_kept.relief, kept.relief, kept.box_weight);
  // Two layers, the box top (inverse depth 1 / 0.85 - 1 = 0.176 above the ground's, share f of the image) and the
  // ground: a spread of 0.176 sqrt(f (1 - f)), 0.057 for f = 0.12.
  EXPECT_GT(kept.relief, 0.04);
  EXPECT_LT(kept.relief, 0.08);
  EXPECT_LT(clean_kept.relief, 0.01);  // one plane: the spread of e is noise
  EXPECT_LT(parallax.relief, 0.01);    // the box down-weighted: what the estimate leans on is one plane again
  EXPECT_GT(plain.err - clean.err, 0.003) << "the box must pull the speed up without the parallax test";
  EXPECT_LT(std::abs(parallax.err - clean.err), 0.5 * (plain.err - clean.err));
  EXPECT_GT(plain.box_weight, 0.8) << "one image's residual must not show the box";
  EXPECT_LT(parallax.box_weight, 0.3);
  EXPECT_GT(parallax.ground_weight, 0.85);
  // No box: the test changes little (measured: 7.4 % more of the weight removed, in blobs where this synthetic
  // texture's inverse depth is measured poorly; |vartheta| 0.5 % higher, against the box's 5.4 % without the test).
  EXPECT_LT(std::abs(clean_parallax.err - clean.err), 0.01);
  EXPECT_LT(clean_parallax.removed, clean.removed + 0.1);
}

TEST(PhotometricOutliers, ForgottenReliefRestartsFromTheNextUpdate) {
  // The smoothed relief (UpdateStats::relief_var) follows each update's own value slowly (noise_time_constant_s).
  // ImageUpdate calls forgetRelief() after every update until the filter has converged, because before that the
  // parallax statistics measure the state's error rather than the scene (docs/noise_model.md section 13; a start
  // from d0 = 0.33 m at 0.94 m carried a relief of 480 % into the converged frames, decaying for 10 s). Here a
  // scene with relief (a box kept in the estimate by a wide tolerance: 0.057) is followed by one plane (a later,
  // unrelated stretch of images: nothing carried over along the warp): remembered, the box's relief is still
  // reported over the plane; forgotten, the plane's first update reports its own.
  const BoxFlight flight(12);
  std::vector<PreprocessedFrame> box, plane;
  for (int j = 0; j < flight.frames; ++j) {
    box.push_back(flight.frame(j, true));
    plane.push_back(flight.frame(j, false, 100.0));
  }
  auto run = [&](bool forget) {
    PhotometricParams params;
    params.parallax_tolerance = 10.0;
    PhotometricUpdate update(params, PreprocessParams{});
    double box_relief = 0.0, plane_relief = 0.0;
    for (int scene = 0; scene < 2; ++scene) {
      const std::vector<PreprocessedFrame>& f = scene == 0 ? box : plane;
      for (int j = 0; j + 1 < flight.frames; ++j) {
        State x;
        ErrorCov P;
        flight.prior(j + 1, &x, &P);
        const UpdateStats st = update.update(f[j], f[j + 1], flight.K, flight.w_C, flight.dt, &x, &P);
        EXPECT_TRUE(st.applied);
        if (scene == 0) box_relief = std::sqrt(st.relief_var);
        if (scene == 1 && j == 0) plane_relief = std::sqrt(st.relief_var);
      }
      if (scene == 0 && forget) update.forgetRelief();
    }
    return std::make_pair(box_relief, plane_relief);
  };
  const auto remembered = run(false), forgotten = run(true);
  std::printf("relief (relative 1-sigma) over the box / at the plane's first update: remembered %.4f / %.4f, "
              "forgotten %.4f / %.4f\n", remembered.first, remembered.second, forgotten.first, forgotten.second);
  EXPECT_GT(remembered.first, 0.04);
  EXPECT_EQ(remembered.first, forgotten.first);
  EXPECT_GT(remembered.second, 0.04);  // the box's relief, decaying over noise_time_constant_s
  EXPECT_LT(forgotten.second, 0.01);   // one plane
}

TEST(OutlierWindowSums, EqualTheTruncatedWindowsAtEveryWidth) {
  // The running window sum of the outlier weights' neighbourhoods (internal::windowSumRow) against the direct sum
  // over [i - half, i + half] truncated at the edges, including windows wider than the row.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> value(-2.0f, 3.0f);
  for (int n : {1, 2, 3, 5, 8, 37, 90}) {
    for (int half : {0, 1, 2, 3, 4, 17, 60, 100}) {
      std::vector<float> in(static_cast<size_t>(n)), out(static_cast<size_t>(n), -999.0f);
      for (float& v : in) v = value(rng);
      internal::windowSumRow(in.data(), n, half, out.data());
      for (int i = 0; i < n; ++i) {
        double direct = 0.0;
        for (int k = std::max(0, i - half); k <= std::min(n - 1, i + half); ++k) direct += in[static_cast<size_t>(k)];
        EXPECT_NEAR(out[static_cast<size_t>(i)], direct, 1e-4 * (1.0 + std::abs(direct)))
            << "n " << n << " half " << half << " i " << i;
      }
    }
  }
}

TEST(OutlierWindowSums, FourRowsAsLanesGiveEachRowsSumsBitForBit) {
  // updateWeightMap runs the window sums on four rows at once (internal::rowsToLanes, windowSum over vectors,
  // lanesToRows): every row must get exactly what windowSumRow gives it alone.
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> value(-2.0f, 3.0f);
  for (int n : {4, 8, 36, 92}) {
    for (int half : {0, 1, 2, 5, 50}) {
      std::vector<float> rows(static_cast<size_t>(4 * n)), lanes(static_cast<size_t>(4 * n)),
          sums(static_cast<size_t>(4 * n)), back(static_cast<size_t>(4 * n));
      for (float& v : rows) v = value(rng);
      const float* in[4] = {&rows[0], &rows[n], &rows[2 * n], &rows[3 * n]};
      float* out[4] = {&back[0], &back[n], &back[2 * n], &back[3 * n]};
      internal::rowsToLanes(in, n, lanes.data());
      internal::windowSum(
          n, half, [&](int k) { return cv::v_load(lanes.data() + 4 * k); },
          [&](int i, const cv::v_float32x4& v) { cv::v_store(sums.data() + 4 * i, v); }, cv::v_setzero_f32());
      internal::lanesToRows(sums.data(), n, out);
      for (int l = 0; l < 4; ++l) {
        std::vector<float> alone(static_cast<size_t>(n));
        internal::windowSumRow(in[l], n, half, alone.data());
        for (int i = 0; i < n; ++i)
          EXPECT_EQ(out[l][i], alone[static_cast<size_t>(i)]) << "n " << n << " half " << half << " row " << l;
      }
    }
  }
}

TEST(OutlierMedians, KthSmallestEqualsNthElement) {
  // updateWeightMap's image medians select through a histogram of the values' top bits (internal::kthSmallest):
  // the value of every rank must be std::nth_element's, for sizes on both sides of its small-set fallback and
  // for values spread over many octaves, packed into one bin, repeated, signed, zero of either sign, subnormal or
  // infinite.
  std::mt19937 rng(11);
  std::array<uint32_t, 2048> counts{};
  const std::vector<std::function<float()>> kinds = {
      [&] { return std::uniform_real_distribution<float>(0.0f, 1.0f)(rng); },
      [&] { return std::exp(std::uniform_real_distribution<float>(-40.0f, 40.0f)(rng)); },
      [&] { return 1.0f + std::uniform_real_distribution<float>(0.0f, 1e-3f)(rng); },  // one bin
      [&] { return std::normal_distribution<float>(0.0f, 1e-3f)(rng); },
      [&] { return static_cast<float>(std::uniform_int_distribution<int>(-3, 3)(rng)); },  // repeated values
      [&] {
        const float special[] = {0.0f, -0.0f, 1e-40f, -1e-40f, INFINITY, -INFINITY, 2.5f, -2.5f};
        return special[std::uniform_int_distribution<int>(0, 7)(rng)];
      }};
  for (size_t kind = 0; kind < kinds.size(); ++kind) {
    for (size_t n : {1u, 2u, 64u, 65u, 66u, 1305u, 5000u}) {
      std::vector<float> values(n);
      for (float& v : values) v = kinds[kind]();
      for (size_t k : {size_t{0}, n / 3, n / 2, n - 1}) {
        std::vector<float> a = values, b = values;
        std::nth_element(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(k), b.end());
        const float got = internal::kthSmallest(a.data(), n, k, &counts);
        EXPECT_EQ(got, b[k]) << "kind " << kind << " n " << n << " k " << k;  // (-0 == +0)
      }
    }
  }
}

}  // namespace
}  // namespace diekf
