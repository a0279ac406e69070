// Internal (not installed): the iterated Gauss-Newton update in information form shared by the photometric
// and the feature-based update (docs/algorithm.md §3.4). The measurement model only enters through a callback that
// linearises it at the current iterate and returns the 8x8 observed block of the information matrix and the
// matching 8-vector, so both updates run exactly the same solve, stopping rule and covariance update.
#pragma once

#include <type_traits>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "diekf/state.h"
#include "diekf/types.h"

namespace diekf {
namespace internal {

/// Number of error-state columns a camera measurement observes: vartheta (3), mu (2), b_w (3).
constexpr int kObsDim = 8;
using ObsMat = Eigen::Matrix<double, kObsDim, kObsDim>;
using ObsVec = Eigen::Matrix<double, kObsDim, 1>;

/// Index in the 14-D error state of observed column k (k = 0..7).
constexpr int kObsToErr[kObsDim] = {ErrIdx::kVartheta,     ErrIdx::kVartheta + 1, ErrIdx::kVartheta + 2,
                                    ErrIdx::kMu,           ErrIdx::kMu + 1,       ErrIdx::kBw,
                                    ErrIdx::kBw + 1,       ErrIdx::kBw + 2};

/// A further error-state column that is not a fixed combination of the observed ones (the rolling-shutter
/// readout: w_y S m, weighted per image row): its cross information with the observed columns, its own
/// information and its right-hand side (docs/algorithm.md section 3.7).
struct ExtraColumn {
  bool active = false;
  ObsVec cross = ObsVec::Zero();
  double diag = 0.0;
  double rhs = 0.0;
};

/// Further error-state columns that are fixed combinations S m_k of the observed ones, like the time offset's: the
/// camera's calibration states (docs/algorithm.md section 3.8). m[k] = 0: column k is not estimated.
struct CalibrationColumns {
  static constexpr int kCount = 1;
  static constexpr int kErr[kCount] = {ErrIdx::kFs};  ///< the focal-length scale
  ObsVec m[kCount] = {ObsVec::Zero()};
  void setZero() {
    for (ObsVec& v : m) v.setZero();
  }
  bool allFinite() const {
    for (const ObsVec& v : m)
      if (!v.allFinite()) return false;
    return true;
  }
};

/// Outcome of an iterated update.
struct IterationResult {
  bool ok = false;              ///< false: nothing was changed (linearisation refused or non-finite system)
  int passes = 0;               ///< linearisations performed
  double last_step_norm = 0.0;  ///< |delta| of the last pass
};

/// Iterated information-form update.
///
/// `linearize(const State& x_j, ObsMat* A, ObsVec* b) -> bool` must fill the UPPER triangle of
/// A = sum w S^T S and b = sum w S^T r (r = z - h(x_j), dr/d delta = -S) at x_j, and return false to abort
/// (too few measurements); it may leave the strictly lower triangle of A undefined.
/// A callback with a fourth argument `ObsVec* m` (zeroed before the call) may also say how the time offset
/// enters: its Jacobian column is S m (a combination of the observed columns, docs/algorithm.md section 3.6),
/// so the measurement rows over the error state are S H with H = [selection of the observed columns | m].
/// A callback with a fifth argument `ExtraColumn* readout` may add the rolling-shutter readout's column, and one
/// with a sixth `CalibrationColumns* calib` (zeroed before the call) the calibration states' columns S m_k
/// (section 3.8).
///
/// Per pass: Lambda = L^T P^-1 L, delta = (A + Lambda)^-1 (b - L^T P^-1 e), e = x_j [-] x^-,
/// x_{j+1} = x_j [+] delta; stop at |delta| < stop_threshold or after max_passes.
/// P+ = (A + Lambda)^-1 of the last pass, symmetrised. `x` and `P` are written only on success.
///
/// All storage is fixed-size: no heap allocation.
template <typename LinearizeFn>
IterationResult iterateInformationForm(int max_passes, double stop_threshold, LinearizeFn&& linearize,
                                       State* x, ErrorCov* P) {
  IterationResult result;
  const State x_prior = *x;

  // P^-1 once per update (LDLT of the prior, solved against the identity).
  const Eigen::LDLT<ErrorCov> prior_ldlt(*P);
  if (prior_ldlt.info() != Eigen::Success || !prior_ldlt.isPositive()) return result;
  ErrorCov P_inv = prior_ldlt.solve(ErrorCov::Identity());
  P_inv = 0.5 * (P_inv + P_inv.transpose()).eval();
  if (!P_inv.allFinite()) return result;

  State x_j = x_prior;
  ObsMat A;
  ObsVec b;
  ObsVec m;
  CalibrationColumns calib;
  ExtraColumn readout;
  ErrorCov info;
  ErrorVec rhs;
  Eigen::LDLT<ErrorCov> info_ldlt(kErrorDim);
  const int passes = max_passes < 1 ? 1 : max_passes;

  for (int pass = 0; pass < passes; ++pass) {
    A.setZero();
    b.setZero();
    m.setZero();
    calib.setZero();
    readout = ExtraColumn();
    if constexpr (std::is_invocable_v<LinearizeFn&, const State&, ObsMat*, ObsVec*, ObsVec*, ExtraColumn*,
                                      CalibrationColumns*>) {
      if (!linearize(static_cast<const State&>(x_j), &A, &b, &m, &readout, &calib)) return result;
    } else if constexpr (std::is_invocable_v<LinearizeFn&, const State&, ObsMat*, ObsVec*, ObsVec*,
                                             ExtraColumn*>) {
      if (!linearize(static_cast<const State&>(x_j), &A, &b, &m, &readout)) return result;
    } else if constexpr (std::is_invocable_v<LinearizeFn&, const State&, ObsMat*, ObsVec*, ObsVec*>) {
      if (!linearize(static_cast<const State&>(x_j), &A, &b, &m)) return result;
    } else {
      if (!linearize(static_cast<const State&>(x_j), &A, &b)) return result;
    }
    A.template triangularView<Eigen::StrictlyLower>() = A.transpose();
    if (!A.allFinite() || !b.allFinite() || !m.allFinite() || !calib.allFinite()) return result;

    // Prior term. On the first pass e = 0 and L = I.
    if (pass == 0) {
      info = P_inv;
      rhs.setZero();
    } else {
      const ErrorCov L = x_j.boxminusJacobian(x_prior);
      const ErrorVec e = x_j.boxminus(x_prior);
      const ErrorCov LtPinv = L.transpose() * P_inv;
      info.noalias() = LtPinv * L;
      rhs.noalias() = -(LtPinv * e);
    }
    // Measurement term: only the 8 observed rows/columns.
    for (int r = 0; r < kObsDim; ++r) {
      rhs(kObsToErr[r]) += b(r);
      for (int c = 0; c < kObsDim; ++c) info(kObsToErr[r], kObsToErr[c]) += A(r, c);
    }
    // The time-offset column S m: H^T A H adds A m to its cross terms and m^T A m to its diagonal.
    if (!m.isZero(0.0)) {
      const ObsVec Am = A * m;
      for (int r = 0; r < kObsDim; ++r) {
        info(kObsToErr[r], ErrIdx::kTd) += Am(r);
        info(ErrIdx::kTd, kObsToErr[r]) += Am(r);
      }
      info(ErrIdx::kTd, ErrIdx::kTd) += m.dot(Am);
      rhs(ErrIdx::kTd) += m.dot(b);
    }
    // The calibration columns S m_k: like the time offset's, with their cross terms m_k^T A m_l and m^T A m_k.
    for (int k = 0; k < CalibrationColumns::kCount; ++k) {
      if (calib.m[k].isZero(0.0)) continue;
      const int ek = CalibrationColumns::kErr[k];
      const ObsVec Amk = A * calib.m[k];
      for (int r = 0; r < kObsDim; ++r) {
        info(kObsToErr[r], ek) += Amk(r);
        info(ek, kObsToErr[r]) += Amk(r);
      }
      const double td_k = m.dot(Amk);
      info(ErrIdx::kTd, ek) += td_k;
      info(ek, ErrIdx::kTd) += td_k;
      for (int l = 0; l < CalibrationColumns::kCount; ++l) {
        if (l == k || calib.m[l].isZero(0.0)) continue;
        info(CalibrationColumns::kErr[l], ek) += calib.m[l].dot(Amk);
      }
      info(ek, ek) += calib.m[k].dot(Amk);
      rhs(ek) += calib.m[k].dot(b);
    }
    // The readout's column (ExtraColumn): with the observed columns, with the time offset's S m, and its own.
    if (readout.active && readout.cross.allFinite() && std::isfinite(readout.diag) && std::isfinite(readout.rhs)) {
      for (int r = 0; r < kObsDim; ++r) {
        info(kObsToErr[r], ErrIdx::kRo) += readout.cross(r);
        info(ErrIdx::kRo, kObsToErr[r]) += readout.cross(r);
      }
      const double td_ro = m.dot(readout.cross);
      info(ErrIdx::kTd, ErrIdx::kRo) += td_ro;
      info(ErrIdx::kRo, ErrIdx::kTd) += td_ro;
      for (int k = 0; k < CalibrationColumns::kCount; ++k) {
        const double k_ro = calib.m[k].dot(readout.cross);
        info(CalibrationColumns::kErr[k], ErrIdx::kRo) += k_ro;
        info(ErrIdx::kRo, CalibrationColumns::kErr[k]) += k_ro;
      }
      info(ErrIdx::kRo, ErrIdx::kRo) += readout.diag;
      rhs(ErrIdx::kRo) += readout.rhs;
    }

    info_ldlt.compute(info);
    if (info_ldlt.info() != Eigen::Success || !info_ldlt.isPositive()) return result;
    const ErrorVec delta = info_ldlt.solve(rhs);
    if (!delta.allFinite()) return result;

    x_j = x_j.boxplus(delta);
    if (!x_j.allFinite()) return result;
    result.passes = pass + 1;
    result.last_step_norm = delta.norm();
    if (result.last_step_norm < stop_threshold) break;
  }

  // Covariance from the last pass's information matrix (its factorisation is reused).
  ErrorCov P_post = info_ldlt.solve(ErrorCov::Identity());
  P_post = 0.5 * (P_post + P_post.transpose()).eval();
  if (!P_post.allFinite() || (P_post.diagonal().array() <= 0.0).any()) return result;

  *x = x_j;
  *P = P_post;
  result.ok = true;
  return result;
}

}  // namespace internal
}  // namespace diekf
