#include "diekf/prediction.h"

#include <cmath>

namespace diekf {
namespace {

/// Mean and (optionally) Jacobians of one step. F and G are fully overwritten when given.
///
/// With the rate w and specific force a held over the step (the caller passes their mean over it), the camera
/// turns by exp(dt [w]x): every world-fixed direction seen from C is turned by R = exp(-dt [w]x) (exact, no
/// projection), and the velocity over the old distance is
///   u = v(t + dt) / d(t) = R (vartheta + dt alpha g0 g) + dt alpha (I - dt/2 [w]x) a,
/// exact for the gravity term (gravity turns with the frame: its integral is dt R g0 g) and second order for the
/// specific force (the left Jacobian of -dt w to first order). The distance ratio d(t)/d(t + dt) =
/// exp(int s), s = mu . vartheta, by the trapezoid rule with the end value from an Euler guess of the new scale:
///   s0 = mu . vartheta, s1 = (1 + dt s0) (R mu) . u, kappa = exp(dt (s0 + s1) / 2),
///   alpha' = kappa alpha, vartheta' = kappa u, mu' = R mu, g' = R g (quaternions turned by R, so the tangent
///   bases are transported: d mu'/d mu = d g'/d g = I).
void propagate(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt, double g0, State* out,
               ErrorCov* F, NoiseJacobian* G, const Vec3* column_accel_C) {
  const Vec3 a = accel_C - x.b_a;  // m/s^2
  const Vec3 w = gyro_C - x.b_w;   // rad/s
  const Vec3 mu = x.mu.vector();
  const Vec3 gv = x.g.vector();
  const Vec3& th = x.vartheta;

  const Vec3 phi = -dt * w;  // rad
  const Mat3 R = expSO3(phi);
  const Eigen::Quaterniond q_R(R);
  const Vec3 z = th + (dt * x.alpha * g0) * gv;       // 1/s
  const Vec3 a_mean = a - (0.5 * dt) * w.cross(a);     // m/s^2, specific force turned to the step's end
  const Vec3 u = R * z + (dt * x.alpha) * a_mean;      // 1/s
  const Vec3 mu_R = R * mu;
  const double s0 = mu.dot(th);                        // 1/s
  const double p = mu_R.dot(u);                        // 1/s
  const double k0 = 1.0 + dt * s0;
  const double s1 = k0 * p;                            // 1/s
  const double kappa = std::exp(0.5 * dt * (s0 + s1));

  out->alpha = kappa * x.alpha;
  out->vartheta = kappa * u;
  out->mu = UnitVector::fromQuaternion(q_R * x.mu.quaternion());
  out->g = UnitVector::fromQuaternion(q_R * x.g.quaternion());
  out->b_a = x.b_a;
  out->b_w = x.b_w;
  out->t_d_s = x.t_d_s;
  out->readout_s = x.readout_s;
  out->focal_scale = x.focal_scale;
  if (F == nullptr && G == nullptr) return;

  // Derivatives with respect to z = [alpha, vartheta, mu (2), g (2), a, w] (14 columns); the biases enter as
  // -a and -w, the reading noises as +a and +w.
  constexpr int cA = 0, cT = 1, cMu = 4, cG = 6, cAcc = 8, cW = 11, kCols = 14;
  using Row = Eigen::Matrix<double, 1, kCols>;
  using Block = Eigen::Matrix<double, 3, kCols>;
  const Mat32 M_mu = x.mu.M();
  const Mat32 M_g = x.g.M();
  const Mat3 Jl = leftJacobianSO3(phi);
  // d(R v)/d w = dt [R v]x Jl(phi).
  Block du;
  // The distance's column: the acceleration over the step, g0 g + a turned to its end, or column_accel_C so
  // turned (the reading's own noise here would correlate the column with the next innovation: docs/algorithm.md
  // section 2.1, "The distance's column").
  du.col(cA) = column_accel_C != nullptr ? Vec3(dt * (R * *column_accel_C)) : Vec3(dt * (g0 * (R * gv) + a_mean));
  du.block<3, 3>(0, cT) = R;
  du.block<3, 2>(0, cMu).setZero();
  du.block<3, 2>(0, cG) = (dt * x.alpha * g0) * (R * M_g);
  du.block<3, 3>(0, cAcc) = (dt * x.alpha) * (Mat3::Identity() - (0.5 * dt) * skew(w));
  du.block<3, 3>(0, cW) = dt * skew(R * z) * Jl + (0.5 * dt * dt * x.alpha) * skew(a);
  Row ds0 = Row::Zero();
  ds0.segment<3>(cT) = mu.transpose();
  ds0.segment<2>(cMu) = th.transpose() * M_mu;
  Row dp = mu_R.transpose() * du;
  dp.segment<2>(cMu) += u.transpose() * R * M_mu;
  dp.segment<3>(cW) += u.transpose() * (dt * skew(mu_R) * Jl);
  const Row ds1 = (dt * p) * ds0 + k0 * dp;
  const Row dkappa = (0.5 * dt * kappa) * (ds0 + ds1);
  Row d_alpha = x.alpha * dkappa;
  d_alpha(cA) += kappa;
  const Block d_th = u * dkappa + kappa * du;
  // mu' = exp(phi) mu: a change e of w turns mu' by -dt Jl(phi) e (left), i.e. by -dt N(mu')^T Jl(phi) e in its
  // tangent coordinates; likewise g'.
  const Mat23 J_mu_w = -dt * out->mu.N().transpose() * Jl;
  const Mat23 J_g_w = -dt * out->g.N().transpose() * Jl;

  if (F != nullptr) {
    using I = ErrIdx;
    F->setZero();
    F->block<1, 1>(I::kAlpha, I::kAlpha) = d_alpha.segment<1>(cA);
    F->block<1, 3>(I::kAlpha, I::kVartheta) = d_alpha.segment<3>(cT);
    F->block<1, 2>(I::kAlpha, I::kMu) = d_alpha.segment<2>(cMu);
    F->block<1, 2>(I::kAlpha, I::kG) = d_alpha.segment<2>(cG);
    F->block<1, 3>(I::kAlpha, I::kBa) = -d_alpha.segment<3>(cAcc);
    F->block<1, 3>(I::kAlpha, I::kBw) = -d_alpha.segment<3>(cW);
    F->block<3, 1>(I::kVartheta, I::kAlpha) = d_th.col(cA);
    F->block<3, 3>(I::kVartheta, I::kVartheta) = d_th.block<3, 3>(0, cT);
    F->block<3, 2>(I::kVartheta, I::kMu) = d_th.block<3, 2>(0, cMu);
    F->block<3, 2>(I::kVartheta, I::kG) = d_th.block<3, 2>(0, cG);
    F->block<3, 3>(I::kVartheta, I::kBa) = -d_th.block<3, 3>(0, cAcc);
    F->block<3, 3>(I::kVartheta, I::kBw) = -d_th.block<3, 3>(0, cW);
    F->block<2, 2>(I::kMu, I::kMu).setIdentity();
    F->block<2, 3>(I::kMu, I::kBw) = -J_mu_w;
    F->block<2, 2>(I::kG, I::kG).setIdentity();
    F->block<2, 3>(I::kG, I::kBw) = -J_g_w;
    // biases: random walks
    F->block<3, 3>(I::kBa, I::kBa).setIdentity();
    F->block<3, 3>(I::kBw, I::kBw).setIdentity();
    (*F)(I::kTd, I::kTd) = 1.0;  // the time offset: a (slow) random walk
    (*F)(I::kRo, I::kRo) = 1.0;  // the readout: a (slow) random walk
    (*F)(I::kFs, I::kFs) = 1.0;  // the focal-length scale: a (very slow) random walk
  }
  if (G != nullptr) {
    using I = ErrIdx;
    using Nz = NoiseIdx;
    G->setZero();
    G->block<1, 3>(I::kAlpha, Nz::kAccel) = d_alpha.segment<3>(cAcc);
    G->block<1, 3>(I::kAlpha, Nz::kGyro) = d_alpha.segment<3>(cW);
    G->block<3, 3>(I::kVartheta, Nz::kAccel) = d_th.block<3, 3>(0, cAcc);
    G->block<3, 3>(I::kVartheta, Nz::kGyro) = d_th.block<3, 3>(0, cW);
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

ImuSample meanImuOver(const ImuSample& prev, const ImuSample& next, double t0_s, double t1_s) {
  ImuSample out;
  out.t_s = t1_s;
  const double span_s = next.t_s - prev.t_s;
  const double u = span_s > 0.0 ? (0.5 * (t0_s + t1_s) - prev.t_s) / span_s : 1.0;  // unitless
  out.accel_mps2 = prev.accel_mps2 + u * (next.accel_mps2 - prev.accel_mps2);
  out.gyro_radps = prev.gyro_radps + u * (next.gyro_radps - prev.gyro_radps);
  return out;
}

State predictState(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s, double gravity_mps2) {
  State out;
  propagate(x, accel_C, gyro_C, dt_s, gravity_mps2, &out, nullptr, nullptr, nullptr);
  return out;
}

void predictionJacobians(const State& x, const Vec3& accel_C, const Vec3& gyro_C, double dt_s,
                         double gravity_mps2, ErrorCov* F, NoiseJacobian* G) {
  State out;
  propagate(x, accel_C, gyro_C, dt_s, gravity_mps2, &out, F, G, nullptr);
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
             const ProcessNoiseParams& process, State* x, ErrorCov* P, const Vec3* column_accel_C,
             ErrorVec* sensitivity) {
  if (!(dt_s > 0.0)) return;
  ErrorCov F;
  NoiseJacobian G;
  State out;
  propagate(*x, accel_C, gyro_C, dt_s, imu.gravity_mps2, &out, &F, &G, column_accel_C);

  NoiseVec sigma = discreteNoiseSigmas(imu, process, dt_s);
  // Model error of the distance dynamics d ln(alpha)/dt = s = mu . vartheta: a relative random walk that grows
  // with the relative vertical rate |s| (take-off, landing, climbs). It stands for a relative error of the
  // images' rate s that holds over a climb: k = eps sqrt(T) for an error eps over T seconds (0.03: 2 % over 2 s;
  // docs/algorithm.md section 2, docs/results.md "The distance's rate noise").
  const double rate_sigma = process.alpha_rate_noise_sqrt_s * x->alpha *
                            std::abs(x->mu.vector().dot(x->vartheta)) * std::sqrt(dt_s);  // 1/m
  sigma(NoiseIdx::kAlpha) = std::hypot(sigma(NoiseIdx::kAlpha), rate_sigma);
  // An error of the distance dynamics (ground that is not the plane, the take-off's linearisation) changes the
  // distance, not the camera's velocity: the increment moves vartheta = alpha v by v = vartheta / alpha per unit of
  // alpha. On alpha alone it would say the velocity jumped with it.
  if (process.alpha_noise_keeps_velocity && x->alpha > 0.0)
    G.block<3, 1>(ErrIdx::kVartheta, NoiseIdx::kAlpha) = x->vartheta / x->alpha;
  Mat3 bilinear = Mat3::Zero();
  if (process.bilinear_accel_time_s > 0.0) {
    // d vartheta/dt = alpha a + ...: the linearisation keeps alpha da and a dalpha, not dalpha da, whose variance
    // var(alpha) Cov(a) matters while both are wide (a start at rest: the tilt not yet known, the distance not at
    // all). a = f - b_a + g0 g: da = g0 M_g dg - db_a, over the error states g (2) and b_a (3), adjacent.
    static_assert(ErrIdx::kBa == ErrIdx::kG + 2, "g and b_a adjacent in the error state");
    Eigen::Matrix<double, 3, 5> J;
    J.leftCols<2>() = imu.gravity_mps2 * x->g.M();
    J.rightCols<3>() = -Mat3::Identity();
    bilinear = (process.bilinear_accel_time_s * dt_s * std::max(0.0, (*P)(ErrIdx::kAlpha, ErrIdx::kAlpha))) *
               (J * P->block<5, 5>(ErrIdx::kG, ErrIdx::kG) * J.transpose());
  }
  *x = out;
  // Exploit the structure: the bias and time-offset rows of F are [0 I] and the bias rows of G only hold the random-walk
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
  Pn.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) += bilinear;
  Pn.topRightCorner<kTop, kBias>() = X.rightCols<kBias>();
  Pn.bottomLeftCorner<kBias, kTop>() = X.rightCols<kBias>().transpose();
  Pn.bottomRightCorner<kBias, kBias>() = P->bottomRightCorner<kBias, kBias>();
  Pn.diagonal().segment<3>(ErrIdx::kBa) += sigma.segment<3>(NoiseIdx::kBaWalk).cwiseAbs2();
  Pn.diagonal().segment<3>(ErrIdx::kBw) += sigma.segment<3>(NoiseIdx::kBwWalk).cwiseAbs2();
  Pn(ErrIdx::kTd, ErrIdx::kTd) += process.time_offset_s_per_sqrt_s * process.time_offset_s_per_sqrt_s * dt_s;
  Pn(ErrIdx::kRo, ErrIdx::kRo) += process.readout_s_per_sqrt_s * process.readout_s_per_sqrt_s * dt_s;
  Pn(ErrIdx::kFs, ErrIdx::kFs) += process.focal_scale_per_sqrt_s * process.focal_scale_per_sqrt_s * dt_s;
  *P = 0.5 * (Pn + Pn.transpose());
  if (sensitivity != nullptr) {  // an error direction carried by the dynamics: F s (the bias rows of F are [0 I])
    const ErrorVec s = *sensitivity;
    sensitivity->head<kTop>().noalias() = F_top * s;
  }
}

}  // namespace diekf
