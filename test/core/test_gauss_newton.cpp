// The shared information-form solver against the textbook Kalman update on a linear measurement.
#include <random>

#include <gtest/gtest.h>

#include "../../src/core/gauss_newton.h"

namespace diekf {
namespace {

TEST(InformationForm, OnePassEqualsKalmanUpdateForLinearMeasurement) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, 1.0);
  // Random SPD prior with correlations between observed and unobserved blocks.
  ErrorCov B;
  for (int r = 0; r < kErrorDim; ++r)
    for (int c = 0; c < kErrorDim; ++c) B(r, c) = 0.2 * n(rng);
  const ErrorCov P0 = B * B.transpose() + 0.05 * ErrorCov::Identity();

  // Linear measurement z = H delta + noise on the observed columns only: 5 rows.
  constexpr int kRows = 5;
  Eigen::Matrix<double, kRows, internal::kObsDim> S;
  for (int r = 0; r < kRows; ++r)
    for (int c = 0; c < internal::kObsDim; ++c) S(r, c) = n(rng);
  Eigen::Matrix<double, kRows, 1> z;
  for (int r = 0; r < kRows; ++r) z(r) = 0.3 * n(rng);
  const double sigma = 0.2;
  const Eigen::Matrix<double, kRows, kRows> R = sigma * sigma * Eigen::Matrix<double, kRows, kRows>::Identity();
  Eigen::Matrix<double, kRows, kErrorDim> H = Eigen::Matrix<double, kRows, kErrorDim>::Zero();
  for (int c = 0; c < internal::kObsDim; ++c) H.col(internal::kObsToErr[c]) = S.col(c);

  auto linearize = [&](const State&, internal::ObsMat* A, internal::ObsVec* b) {
    A->noalias() += S.transpose() * R.inverse() * S;
    b->noalias() += S.transpose() * R.inverse() * z;
    return true;
  };
  State x;
  x.alpha = 2.0;
  x.vartheta = Vec3(0.1, -0.2, 0.3);
  x.mu = UnitVector(Vec3(0.1, 0.2, 1.0));
  const State x0 = x;
  ErrorCov P = P0;
  const internal::IterationResult res = internal::iterateInformationForm(1, 0.0, linearize, &x, &P);
  ASSERT_TRUE(res.ok);
  EXPECT_EQ(res.passes, 1);

  const Eigen::Matrix<double, kErrorDim, kRows> K = P0 * H.transpose() * (H * P0 * H.transpose() + R).inverse();
  const ErrorVec delta_kf = K * z;
  const ErrorCov P_kf = (ErrorCov::Identity() - K * H) * P0;
  EXPECT_LT((x.boxminus(x0) - delta_kf).norm(), 1e-9 * (1.0 + delta_kf.norm()));
  EXPECT_LT((P - P_kf).norm(), 1e-9 * P_kf.norm());
  EXPECT_NEAR(res.last_step_norm, delta_kf.norm(), 1e-9);
}

// The time offset's column S m and the readout's column K S m (per-row weights K) that the photometric update
// passes through the callback (docs/algorithm.md sections 3.6, 3.7) give exactly the Kalman update with the dense
// measurement matrix [S | S m | K S m] over (observed, t_d, readout).
TEST(InformationForm, TimeOffsetAndReadoutColumnsEqualTheDenseKalmanUpdate) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  ErrorCov B;
  for (int r = 0; r < kErrorDim; ++r)
    for (int c = 0; c < kErrorDim; ++c) B(r, c) = 0.2 * n(rng);
  const ErrorCov P0 = B * B.transpose() + 0.05 * ErrorCov::Identity();
  constexpr int kRows = 12;
  Eigen::Matrix<double, kRows, internal::kObsDim> S;
  Eigen::Matrix<double, kRows, 1> z, w;  // measurements and their rows' readout weights
  for (int r = 0; r < kRows; ++r) {
    for (int c = 0; c < internal::kObsDim; ++c) S(r, c) = n(rng);
    z(r) = 0.3 * n(rng);
    w(r) = -0.5 + r / (kRows - 1.0);
  }
  internal::ObsVec m;
  for (int c = 0; c < internal::kObsDim; ++c) m(c) = n(rng);
  const double sigma = 0.2, inv_var = 1.0 / (sigma * sigma);
  Eigen::Matrix<double, kRows, kErrorDim> H = Eigen::Matrix<double, kRows, kErrorDim>::Zero();
  for (int c = 0; c < internal::kObsDim; ++c) H.col(internal::kObsToErr[c]) = S.col(c);
  H.col(ErrIdx::kTd) = S * m;
  H.col(ErrIdx::kRo) = w.asDiagonal() * (S * m);

  auto linearize = [&](const State&, internal::ObsMat* A, internal::ObsVec* b, internal::ObsVec* m_out,
                       internal::ExtraColumn* readout) {
    *A = inv_var * S.transpose() * S;
    *b = inv_var * S.transpose() * z;
    *m_out = m;
    // The row moments of the sweep: sum w S^T S, sum w^2 S^T S, sum w S^T r.
    const internal::ObsMat A1 = inv_var * S.transpose() * w.asDiagonal() * S;
    const internal::ObsMat A2 = inv_var * S.transpose() * w.cwiseAbs2().asDiagonal() * S;
    const internal::ObsVec b1 = inv_var * S.transpose() * w.asDiagonal() * z;
    readout->active = true;
    readout->cross = A1 * m;
    readout->diag = m.dot(A2 * m);
    readout->rhs = m.dot(b1);
    return true;
  };
  State x;
  x.alpha = 2.0;
  x.mu = UnitVector(Vec3(0.1, 0.2, 1.0));
  const State x0 = x;
  ErrorCov P = P0;
  const internal::IterationResult res = internal::iterateInformationForm(1, 0.0, linearize, &x, &P);
  ASSERT_TRUE(res.ok);
  const Eigen::Matrix<double, kRows, kRows> R = sigma * sigma * Eigen::Matrix<double, kRows, kRows>::Identity();
  const Eigen::Matrix<double, kErrorDim, kRows> K = P0 * H.transpose() * (H * P0 * H.transpose() + R).inverse();
  const ErrorVec delta_kf = K * z;
  const ErrorCov P_kf = (ErrorCov::Identity() - K * H) * P0;
  EXPECT_LT((x.boxminus(x0) - delta_kf).norm(), 1e-9 * (1.0 + delta_kf.norm()));
  EXPECT_LT((P - P_kf).norm(), 1e-9 * P_kf.norm());
  EXPECT_NE(x.t_d_s, 0.0);
  EXPECT_NE(x.readout_s, 0.0);
}

// With the focal-length scale's column S m_f as well (docs/algorithm.md section 3.8): the Kalman update with the
// dense measurement matrix [S | S m | K S m | S m_f] over (observed, t_d, readout, focal scale).
TEST(InformationForm, FocalScaleColumnEqualsTheDenseKalmanUpdate) {
  std::mt19937 rng(9);
  std::normal_distribution<double> n(0.0, 1.0);
  ErrorCov B;
  for (int r = 0; r < kErrorDim; ++r)
    for (int c = 0; c < kErrorDim; ++c) B(r, c) = 0.2 * n(rng);
  const ErrorCov P0 = B * B.transpose() + 0.05 * ErrorCov::Identity();
  constexpr int kRows = 14;
  Eigen::Matrix<double, kRows, internal::kObsDim> S;
  Eigen::Matrix<double, kRows, 1> z, w;
  for (int r = 0; r < kRows; ++r) {
    for (int c = 0; c < internal::kObsDim; ++c) S(r, c) = n(rng);
    z(r) = 0.3 * n(rng);
    w(r) = -0.5 + r / (kRows - 1.0);
  }
  internal::ObsVec m, m_f;
  for (int c = 0; c < internal::kObsDim; ++c) {
    m(c) = n(rng);
    m_f(c) = n(rng);
  }
  const double sigma = 0.2, inv_var = 1.0 / (sigma * sigma);
  Eigen::Matrix<double, kRows, kErrorDim> H = Eigen::Matrix<double, kRows, kErrorDim>::Zero();
  for (int c = 0; c < internal::kObsDim; ++c) H.col(internal::kObsToErr[c]) = S.col(c);
  H.col(ErrIdx::kTd) = S * m;
  H.col(ErrIdx::kRo) = w.asDiagonal() * (S * m);
  H.col(ErrIdx::kFs) = S * m_f;
  auto linearize = [&](const State&, internal::ObsMat* A, internal::ObsVec* b, internal::ObsVec* m_out,
                       internal::ExtraColumn* readout, internal::CalibrationColumns* calib) {
    *A = inv_var * S.transpose() * S;
    *b = inv_var * S.transpose() * z;
    *m_out = m;
    calib->m[0] = m_f;
    const internal::ObsMat A1 = inv_var * S.transpose() * w.asDiagonal() * S;
    const internal::ObsMat A2 = inv_var * S.transpose() * w.cwiseAbs2().asDiagonal() * S;
    const internal::ObsVec b1 = inv_var * S.transpose() * w.asDiagonal() * z;
    readout->active = true;
    readout->cross = A1 * m;
    readout->diag = m.dot(A2 * m);
    readout->rhs = m.dot(b1);
    return true;
  };
  State x;
  x.alpha = 2.0;
  x.mu = UnitVector(Vec3(0.1, 0.2, 1.0));
  const State x0 = x;
  ErrorCov P = P0;
  const internal::IterationResult res = internal::iterateInformationForm(1, 0.0, linearize, &x, &P);
  ASSERT_TRUE(res.ok);
  const Eigen::Matrix<double, kRows, kRows> R = sigma * sigma * Eigen::Matrix<double, kRows, kRows>::Identity();
  const Eigen::Matrix<double, kErrorDim, kRows> K = P0 * H.transpose() * (H * P0 * H.transpose() + R).inverse();
  const ErrorVec delta_kf = K * z;
  const ErrorCov P_kf = (ErrorCov::Identity() - K * H) * P0;
  EXPECT_LT((x.boxminus(x0) - delta_kf).norm(), 1e-9 * (1.0 + delta_kf.norm()));
  EXPECT_LT((P - P_kf).norm(), 1e-9 * P_kf.norm());
  EXPECT_NE(x.focal_scale, 0.0);
}

TEST(InformationForm, RefusalLeavesStateAndCovarianceUntouched) {
  State x;
  x.vartheta = Vec3(1.0, 2.0, 3.0);
  const State x0 = x;
  const ErrorCov P0 = 0.1 * ErrorCov::Identity();
  ErrorCov P = P0;
  int calls = 0;
  auto refuse_second = [&](const State&, internal::ObsMat* A, internal::ObsVec* b) {
    A->setIdentity();
    b->setOnes();
    return ++calls < 2;
  };
  const internal::IterationResult res = internal::iterateInformationForm(3, 0.0, refuse_second, &x, &P);
  EXPECT_FALSE(res.ok);
  EXPECT_EQ(calls, 2);
  EXPECT_EQ(x.vartheta, x0.vartheta);
  EXPECT_EQ(P, P0);
}

}  // namespace
}  // namespace diekf
