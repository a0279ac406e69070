#include "diekf/prediction.h"

#include <cmath>

namespace diekf {
namespace {

/// Unit quaternion of the rotation exp([phi]x).
Eigen::Quaterniond quaternionExp(const Vec3& phi) {
  const double angle = phi.norm();
  if (angle < 1e-12) {
    // First order: q = (1, phi/2), normalised.
    return Eigen::Quaterniond(1.0, 0.5 * phi.x(), 0.5 * phi.y(), 0.5 * phi.z()).normalized();
  }
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, phi / angle));
}

/// One step of a world-fixed direction n seen from a camera rotating at w (rad/s):
/// n' = exp(dm) n with dm = -dt (I - n n^T) w. The element is moved by rotating its quaternion, so its tangent
/// basis is transported with it (N(n') = R N(n)).
/// J_n = d(n'(n [+] d) [-] n')/d d (2x2), J_w = d(n'(w + e) [-] n')/d e (2x3).
void stepS2(const UnitVector& n, const Vec3& w, double dt, UnitVector* out, Mat2* J_n, Mat23* J_w) {
  const Vec3 nv = n.vector();
  const Mat3 P_perp = Mat3::Identity() - nv * nv.transpose();
  const Vec3 dm = -dt * (P_perp * w);
  *out = UnitVector::fromQuaternion(quaternionExp(dm) * n.quaternion());
  if (J_n == nullptr && J_w == nullptr) return;
  // d(exp(dm + e) n) = -[R n]x Gamma(dm) e to first order; M(n')^T maps an ambient change of n' to its tangent.
  const Vec3 Rn = out->vector();
  const Eigen::Matrix<double, 2, 3> Mt_skew_Gamma = out->M().transpose() * skew(Rn) * leftJacobianSO3(dm);
  if (J_n != nullptr) {
    const Mat3 R = expSO3(dm);
    // d dm / d n = dt ((n . w) I + n w^T).
    const Mat3 ddm_dn = dt * (nv.dot(w) * Mat3::Identity() + nv * w.transpose());
    *J_n = out->M().transpose() * R * n.M() - Mt_skew_Gamma * ddm_dn * n.M();
  }
  if (J_w != nullptr) {
    // d dm / d w = -dt P_perp.
    *J_w = dt * Mt_skew_Gamma * P_perp;
  }
}

/// Mean and (optionally) Jacobians of one step. F and G are fully overwritten when given.
void propagate(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt, double g0, State* out,
               ErrorCov* F, NoiseJacobian* G) {
  const Vec3 a = accel_C - x.b_a;  // m/s^2
  const Vec3 w = gyro_C - x.b_w;   // rad/s
  const Vec3 mu = x.mu.vector();
  const Vec3 gv = x.g.vector();
  const Vec3& th = x.vartheta;
  const double s = mu.dot(th);  // 1/s

  const Vec3 acc_term = a + g0 * gv;  // m/s^2
  out->alpha = x.alpha * (1.0 + s * dt);
  out->vartheta = th + dt * (x.alpha * acc_term - w.cross(th) + s * th);
  out->b_a = x.b_a;
  out->b_w = x.b_w;

  const bool jac = (F != nullptr) || (G != nullptr);
  Mat2 J_mu_mu, J_g_g;
  Mat23 J_mu_w, J_g_w;
  stepS2(x.mu, w, dt, &out->mu, jac ? &J_mu_mu : nullptr, jac ? &J_mu_w : nullptr);
  stepS2(x.g, w, dt, &out->g, jac ? &J_g_g : nullptr, jac ? &J_g_w : nullptr);
  if (!jac) return;

  const Mat32 M_mu = x.mu.M();
  const Mat32 M_g = x.g.M();
  // d vartheta' / d w (w enters as w x vartheta): dt [vartheta]x.
  const Mat3 dth_dw = dt * skew(th);

  if (F != nullptr) {
    using I = ErrIdx;
    F->setZero();
    // alpha' = alpha + dt alpha (mu . vartheta)
    (*F)(I::kAlpha, I::kAlpha) = 1.0 + s * dt;
    F->block<1, 3>(I::kAlpha, I::kVartheta) = (dt * x.alpha) * mu.transpose();
    F->block<1, 2>(I::kAlpha, I::kMu) = (dt * x.alpha) * th.transpose() * M_mu;
    // vartheta'
    F->block<3, 1>(I::kVartheta, I::kAlpha) = dt * acc_term;
    F->block<3, 3>(I::kVartheta, I::kVartheta) =
        Mat3::Identity() + dt * (-skew(w) + s * Mat3::Identity() + th * mu.transpose());
    F->block<3, 2>(I::kVartheta, I::kMu) = dt * th * (th.transpose() * M_mu);
    F->block<3, 2>(I::kVartheta, I::kG) = (dt * x.alpha * g0) * M_g;
    F->block<3, 3>(I::kVartheta, I::kBa) = -(dt * x.alpha) * Mat3::Identity();
    F->block<3, 3>(I::kVartheta, I::kBw) = -dth_dw;
    // mu', g' (b_w enters as -w)
    F->block<2, 2>(I::kMu, I::kMu) = J_mu_mu;
    F->block<2, 3>(I::kMu, I::kBw) = -J_mu_w;
    F->block<2, 2>(I::kG, I::kG) = J_g_g;
    F->block<2, 3>(I::kG, I::kBw) = -J_g_w;
    // biases: random walks
    F->block<3, 3>(I::kBa, I::kBa).setIdentity();
    F->block<3, 3>(I::kBw, I::kBw).setIdentity();
  }
  if (G != nullptr) {
    using I = ErrIdx;
    using Nz = NoiseIdx;
    G->setZero();
    G->block<3, 3>(I::kVartheta, Nz::kAccel) = (dt * x.alpha) * Mat3::Identity();
    G->block<3, 3>(I::kVartheta, Nz::kGyro) = dth_dw;
    G->block<2, 3>(I::kMu, Nz::kGyro) = J_mu_w;
    G->block<2, 3>(I::kG, Nz::kGyro) = J_g_w;
    G->block<3, 3>(I::kBa, Nz::kBaWalk).setIdentity();
    G->block<3, 3>(I::kBw, Nz::kBwWalk).setIdentity();
    (*G)(I::kAlpha, Nz::kAlpha) = 1.0;
    G->block<3, 3>(I::kVartheta, Nz::kVartheta).setIdentity();
    G->block<2, 2>(I::kMu, Nz::kMu).setIdentity();
    G->block<2, 2>(I::kG, Nz::kG).setIdentity();
  }
}

}  // namespace

State predictState(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s, double gravity_mps2) {
  State out;
  propagate(x, accel_C, gyro_C, dt_s, gravity_mps2, &out, nullptr, nullptr);
  return out;
}

void predictionJacobians(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s,
                         double gravity_mps2, ErrorCov* F, NoiseJacobian* G) {
  State out;
  propagate(x, accel_C, gyro_C, dt_s, gravity_mps2, &out, F, G);
}

NoiseVec discreteNoiseSigmas(const ImuParams& imu, const ProcessNoiseParams& process, double dt_s) {
  NoiseVec sigma = NoiseVec::Zero();
  if (!(dt_s > 0.0)) return sigma;
  const double sqrt_dt = std::sqrt(dt_s);
  using Nz = NoiseIdx;
  sigma.segment<3>(Nz::kAccel).setConstant(imu.accel_noise_density / sqrt_dt);   // m/s^2
  sigma.segment<3>(Nz::kGyro).setConstant(imu.gyro_noise_density / sqrt_dt);     // rad/s
  sigma.segment<3>(Nz::kBaWalk).setConstant(imu.accel_random_walk * sqrt_dt);    // m/s^2
  sigma.segment<3>(Nz::kBwWalk).setConstant(imu.gyro_random_walk * sqrt_dt);     // rad/s
  sigma(Nz::kAlpha) = process.alpha_inv_m_per_sqrt_s * sqrt_dt;                   // 1/m
  sigma.segment<3>(Nz::kVartheta).setConstant(process.vartheta_inv_s_per_sqrt_s * sqrt_dt);  // 1/s
  sigma.segment<2>(Nz::kMu).setConstant(process.mu_rad_per_sqrt_s * sqrt_dt);    // rad
  sigma.segment<2>(Nz::kG).setConstant(process.g_rad_per_sqrt_s * sqrt_dt);      // rad
  return sigma;
}

void predict(const Vec3& accel_C, const Vec3& gyro_C, double dt_s, const ImuParams& imu,
             const ProcessNoiseParams& process, State* x, ErrorCov* P) {
  if (!(dt_s > 0.0)) return;
  ErrorCov F;
  NoiseJacobian G;
  State out;
  propagate(*x, accel_C, gyro_C, dt_s, imu.gravity_mps2, &out, &F, &G);

  NoiseVec sigma = discreteNoiseSigmas(imu, process, dt_s);
  // Model error of the distance dynamics alpha' = alpha (1 + s dt), s = mu . vartheta: a relative random walk
  // that grows with the relative vertical rate |s| (take-off, landing, fast climbs), where the linearisation
  // of the bilinear terms is worst. Without it, a prior far from the truth (a take-off from the ground with a
  // prior of 0.25 m) is locked in with an overconfident sigma (docs/results.md).
  const double rate_sigma = process.alpha_rate_noise_sqrt_s * x->alpha *
                            std::abs(x->mu.vector().dot(x->vartheta)) * std::sqrt(dt_s);  // 1/m
  sigma(NoiseIdx::kAlpha) = std::hypot(sigma(NoiseIdx::kAlpha), rate_sigma);
  *x = out;
  // Exploit the structure: the bias rows of F are [0 I] and the bias rows of G only hold the random-walk
  // identities (whose columns are zero in the other rows). With F_top the first 8 rows of F and X = F_top P:
  //   P'_top,top = X F_top^T + G_top Q G_top^T,  P'_top,bias = X_bias,  P'_bias,bias = P_bias,bias + Q_walk.
  constexpr int kTop = ErrIdx::kBa;  // alpha, vartheta, mu, g
  constexpr int kBias = kErrorDim - kTop;
  const Eigen::Matrix<double, kTop, kErrorDim> F_top = F.topRows<kTop>();
  const Eigen::Matrix<double, kTop, kNoiseDim> Gs_top = G.topRows<kTop>() * sigma.asDiagonal();
  Eigen::Matrix<double, kTop, kErrorDim> X;
  X.noalias() = F_top * (*P);
  ErrorCov Pn;
  Pn.topLeftCorner<kTop, kTop>().noalias() = X * F_top.transpose();
  Pn.topLeftCorner<kTop, kTop>().noalias() += Gs_top * Gs_top.transpose();
  Pn.topRightCorner<kTop, kBias>() = X.rightCols<kBias>();
  Pn.bottomLeftCorner<kBias, kTop>() = X.rightCols<kBias>().transpose();
  Pn.bottomRightCorner<kBias, kBias>() = P->bottomRightCorner<kBias, kBias>();
  Pn.diagonal().segment<3>(ErrIdx::kBa) += sigma.segment<3>(NoiseIdx::kBaWalk).cwiseAbs2();
  Pn.diagonal().segment<3>(ErrIdx::kBw) += sigma.segment<3>(NoiseIdx::kBwWalk).cwiseAbs2();
  *P = 0.5 * (Pn + Pn.transpose());
}

}  // namespace diekf
