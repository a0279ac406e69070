// Analytic trajectories: position, derivatives up to jerk, attitude from thrust direction and yaw.
#include "diekf/sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace diekf {
namespace sim {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// C3 ramp from 0 to 1 on [0, 1] (degree-7 smoothstep) and its first three derivatives w.r.t. x.
void smoothRamp(double x, double s[4]) {
  if (x <= 0.0) {
    s[0] = s[1] = s[2] = s[3] = 0.0;
    return;
  }
  if (x >= 1.0) {
    s[0] = 1.0;
    s[1] = s[2] = s[3] = 0.0;
    return;
  }
  const double x2 = x * x, x3 = x2 * x, x4 = x3 * x, x5 = x4 * x, x6 = x5 * x, x7 = x6 * x;
  s[0] = 35 * x4 - 84 * x5 + 70 * x6 - 20 * x7;
  s[1] = 140 * x3 - 420 * x4 + 420 * x5 - 140 * x6;
  s[2] = 420 * x2 - 1680 * x3 + 2100 * x4 - 840 * x5;
  s[3] = 840 * x - 5040 * x2 + 8400 * x3 - 4200 * x4;
}

/// Derivative of the normalised vector u/|u| given du/dt.
Eigen::Vector3d dNormalized(const Eigen::Vector3d& u, const Eigen::Vector3d& du) {
  const double nu = u.norm();
  const Eigen::Vector3d n = u / nu;
  return (du - n * n.dot(du)) / nu;
}

/// Motion (relative to hover) and its derivatives 0..3 (m, m/s, m/s^2, m/s^3), ramp applied.
void motion(const TrajectoryParams& p, double t, Eigen::Vector3d m[4]) {
  Eigen::Vector3d raw[4];
  for (auto& r : raw) r.setZero();
  for (const SineTerm& s : p.sines) {
    const double ph = s.omega_radps * t + s.phase_rad;
    const double w = s.omega_radps, sn = std::sin(ph), cs = std::cos(ph);
    raw[0] += s.amplitude_m * sn;
    raw[1] += s.amplitude_m * (w * cs);
    raw[2] += s.amplitude_m * (-w * w * sn);
    raw[3] += s.amplitude_m * (-w * w * w * cs);
  }
  for (const DashTerm& d : p.dashes) {
    const double u = (t - d.t_center_s) / d.tau_s;
    if (std::abs(u) > 12.0) continue;
    const double g = std::exp(-0.5 * u * u), it = 1.0 / d.tau_s;
    raw[0] += d.amplitude_m * g;
    raw[1] += d.amplitude_m * (-u * g * it);
    raw[2] += d.amplitude_m * ((u * u - 1.0) * g * it * it);
    raw[3] += d.amplitude_m * ((3.0 * u - u * u * u) * g * it * it * it);
  }
  double s[4];
  const double T = std::max(p.ramp_s, 1e-6);
  smoothRamp((t - p.hover_s) / T, s);
  const double s1 = s[1] / T, s2 = s[2] / (T * T), s3 = s[3] / (T * T * T);
  m[0] = s[0] * raw[0];
  m[1] = s1 * raw[0] + s[0] * raw[1];
  m[2] = s2 * raw[0] + 2 * s1 * raw[1] + s[0] * raw[2];
  m[3] = s3 * raw[0] + 3 * s2 * raw[1] + 3 * s1 * raw[2] + s[0] * raw[3];
}

/// Peak acceleration of a dash with peak speed v (m/s^2): faster dashes are also more aggressive.
double dashAccelLimit(double v_mps) { return 2.0 + 1.5 * v_mps; }

}  // namespace

Plane Plane::inclined(double incline_deg, double axis_azimuth_deg) {
  const double a = incline_deg * kPi / 180.0, az = axis_azimuth_deg * kPi / 180.0;
  const Eigen::Vector3d axis(std::cos(az), std::sin(az), 0.0);
  Plane pl;
  pl.n = Eigen::AngleAxisd(a, axis) * Eigen::Vector3d::UnitZ();
  pl.e_m = 0.0;
  return pl;
}

void Plane::basis(Eigen::Vector3d* t1, Eigen::Vector3d* t2) const {
  // t1: the W x axis projected into the plane (falls back to W y for a vertical-x normal).
  Eigen::Vector3d ref = Eigen::Vector3d::UnitX();
  if (std::abs(n.dot(ref)) > 0.9) ref = Eigen::Vector3d::UnitY();
  *t1 = (ref - n * n.dot(ref)).normalized();
  *t2 = n.cross(*t1);
}

double Plane::zAt(double x_m, double y_m) const { return -(n.x() * x_m + n.y() * y_m + e_m) / n.z(); }

KinematicState Trajectory::evaluate(double t_s) const {
  const TrajectoryParams& P = params_;
  Eigen::Vector3d m[4];
  motion(P, t_s, m);
  // Horizontal motion is m.xy; vertical = plane slope under the horizontal position + height + m.z.
  Eigen::Vector3d d[4];
  const Eigen::Vector3d& n = P.plane.n;
  for (int k = 0; k < 4; ++k) {
    d[k] = m[k];
    d[k].z() = m[k].z() - (n.x() * m[k].x() + n.y() * m[k].y()) / n.z();
  }
  d[0].z() += P.height_m - P.plane.e_m / n.z();
  if (P.takeoff_from_m >= 0.0) {
    // Climb from the resting height to height_m: offset (from - height) (1 - ramp) along W z.
    double c[4];
    const double Tc = std::max(P.climb_s, 1e-6);
    smoothRamp((t_s - P.takeoff_start_s) / Tc, c);
    const double dh = P.takeoff_from_m - P.height_m;
    d[0].z() += dh * (1.0 - c[0]);
    d[1].z() -= dh * c[1] / Tc;
    d[2].z() -= dh * c[2] / (Tc * Tc);
    d[3].z() -= dh * c[3] / (Tc * Tc * Tc);
  }

  double s[4];
  const double T = std::max(P.ramp_s, 1e-6);
  smoothRamp((t_s - P.hover_s) / T, s);
  const double ph = P.yaw_omega_radps * t_s + P.yaw_phase_rad;
  const double yaw = P.yaw0_rad + s[0] * P.yaw_amplitude_rad * std::sin(ph);
  const double dyaw = s[1] / T * P.yaw_amplitude_rad * std::sin(ph) +
                      s[0] * P.yaw_amplitude_rad * P.yaw_omega_radps * std::cos(ph);

  KinematicState k;
  k.t_s = t_s;
  k.p_W = d[0];
  k.v_W = d[1];
  k.a_W = d[2];
  const Eigen::Vector3d g_W(0.0, 0.0, -kGravityMps2);
  // Body z along the thrust a - g; body x as close to the yaw heading as the tilt allows.
  const Eigen::Vector3d f = d[2] - g_W, df = d[3];
  const Eigen::Vector3d z = f.normalized(), dz = dNormalized(f, df);
  const Eigen::Vector3d xc(std::cos(yaw), std::sin(yaw), 0.0), dxc(-std::sin(yaw) * dyaw, std::cos(yaw) * dyaw, 0.0);
  const Eigen::Vector3d u = z.cross(xc), du = dz.cross(xc) + z.cross(dxc);
  const Eigen::Vector3d y = u.normalized(), dy = dNormalized(u, du);
  const Eigen::Vector3d x = y.cross(z), dx = dy.cross(z) + y.cross(dz);
  k.R_WI.col(0) = x;
  k.R_WI.col(1) = y;
  k.R_WI.col(2) = z;
  Eigen::Matrix3d dR;
  dR.col(0) = dx;
  dR.col(1) = dy;
  dR.col(2) = dz;
  const Eigen::Matrix3d W = k.R_WI.transpose() * dR;  // skew([w_I]) up to round-off
  k.w_I = Eigen::Vector3d(W(2, 1) - W(1, 2), W(0, 2) - W(2, 0), W(1, 0) - W(0, 1)) * 0.5;
  k.f_I = k.R_WI.transpose() * f;
  return k;
}

SpeedStats Trajectory::stats(double rate_hz) const {
  SpeedStats st;
  const int n = std::max(2, static_cast<int>(std::floor(params_.duration_s * rate_hz)) + 1);
  double sum2 = 0.0;
  st.min_height_m = 1e9;
  st.max_height_m = -1e9;
  for (int i = 0; i < n; ++i) {
    const KinematicState k = evaluate(i / rate_hz);
    const double sp = k.v_W.norm();
    sum2 += sp * sp;
    st.max_mps = std::max(st.max_mps, sp);
    const double h = k.p_W.z() - params_.plane.zAt(k.p_W.x(), k.p_W.y());
    st.min_height_m = std::min(st.min_height_m, h);
    st.max_height_m = std::max(st.max_height_m, h);
    const double tilt = std::acos(std::clamp(k.R_WI(2, 2), -1.0, 1.0)) * 180.0 / kPi;
    st.max_tilt_deg = std::max(st.max_tilt_deg, tilt);
  }
  st.rms_mps = std::sqrt(sum2 / n);
  return st;
}

std::vector<PresetSpec> presetSpecs() {
  // flight1..7: docs/algorithm.md §5 (RMS / max speed); heights within the paper's ~0.4-1.3 m.
  std::vector<PresetSpec> v;
  v.push_back({"flight1", 0.24, 0.83, 0.75, 0.25, "checkerboard", true});
  v.push_back({"flight2", 0.21, 1.13, 0.85, 0.30, "checkerboard", true});
  v.push_back({"flight3", 0.24, 0.94, 0.90, 0.35, "checkerboard", true});
  v.push_back({"flight4", 0.21, 0.64, 0.80, 0.25, "natural", true});
  v.push_back({"flight5", 0.22, 0.86, 0.85, 0.30, "natural", true});
  v.push_back({"flight6", 0.44, 1.94, 0.90, 0.35, "natural", true});
  v.push_back({"flight7", 0.57, 2.75, 0.95, 0.35, "natural", true});
  v.push_back({"incline", 0.20, 0.60, 0.80, 0.20, "natural", true});
  v.push_back({"hover", 0.0, 0.0, 0.70, 0.0, "checkerboard", true});
  return v;
}

bool findPreset(const std::string& name, PresetSpec* spec) {
  for (const PresetSpec& p : presetSpecs()) {
    if (p.name == name) {
      *spec = p;
      return true;
    }
  }
  return false;
}

TrajectoryParams makePresetTrajectory(const PresetSpec& spec, double duration_s, std::uint64_t seed,
                                      const Plane& plane) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  TrajectoryParams P;
  P.duration_s = duration_s;
  P.plane = plane;
  P.height_m = spec.height_m;
  P.hover_s = std::min(1.0, 0.1 * duration_s);
  P.ramp_s = std::min(3.0, 0.2 * duration_s);
  P.yaw0_rad = 2.0 * kPi * uni(rng);
  P.yaw_amplitude_rad = spec.rms_speed_mps > 0.0 ? 0.3 + 0.5 * uni(rng) : 0.0;
  P.yaw_omega_radps = 2.0 * kPi / (25.0 + 20.0 * uni(rng));
  P.yaw_phase_rad = 2.0 * kPi * uni(rng);

  // Vertical: two slow sinusoids, amplitudes summing to height_amplitude (fixed, not scaled by the fit).
  if (spec.height_amplitude_m > 0.0) {
    const double split = 0.5 + 0.3 * uni(rng);
    const double amps[2] = {split * spec.height_amplitude_m, (1.0 - split) * spec.height_amplitude_m};
    for (double a : amps) {
      SineTerm s;
      s.amplitude_m = Eigen::Vector3d(0.0, 0.0, a);
      s.omega_radps = 2.0 * kPi * (0.03 + 0.1 * uni(rng));
      s.phase_rad = 2.0 * kPi * uni(rng);
      P.sines.push_back(s);
    }
  }
  if (spec.rms_speed_mps <= 0.0) {
    P.sines.clear();
    return P;
  }
  const std::size_t n_vertical = P.sines.size();
  // Horizontal: four sinusoids per axis, 0.04-0.4 Hz, amplitudes ~ 1/omega (equal velocity weight).
  for (int axis = 0; axis < 2; ++axis) {
    for (int i = 0; i < 4; ++i) {
      SineTerm s;
      s.omega_radps = 2.0 * kPi * (0.04 + 0.36 * uni(rng));
      s.amplitude_m.setZero();
      s.amplitude_m[axis] = (0.5 + uni(rng)) / s.omega_radps;
      s.phase_rad = 2.0 * kPi * uni(rng);
      P.sines.push_back(s);
    }
  }
  // Dashes: about one per 20 s, spread over the flight after the fade-in, random horizontal directions.
  const double t_start = P.hover_s + P.ramp_s + 3.0;
  const double t_end = duration_s - 3.0;
  // A Gaussian dash of peak speed v and width tau adds about 2.41 v^2 tau (m^2/s) to the integral of speed^2:
  // keep the dashes below ~half of the target mean-square speed, at most one per 20 s.
  const double v_d = spec.max_speed_mps, tau_d = v_d / (std::exp(-0.5) * dashAccelLimit(v_d));
  const double dash_energy = 2.41 * v_d * v_d * tau_d;
  const int n_by_energy = static_cast<int>(0.5 * spec.rms_speed_mps * spec.rms_speed_mps * duration_s / dash_energy);
  const int n_dash = t_end > t_start ? std::clamp(n_by_energy, 1, std::max(1, static_cast<int>(duration_s / 20.0))) : 0;
  std::vector<Eigen::Vector3d> dash_dirs;
  for (int i = 0; i < n_dash; ++i) {
    DashTerm d;
    const double slot = (t_end - t_start) / n_dash;
    d.t_center_s = t_start + slot * (i + 0.3 + 0.4 * uni(rng));
    const double az = 2.0 * kPi * uni(rng);
    dash_dirs.emplace_back(std::cos(az), std::sin(az), 0.0);
    P.dashes.push_back(d);
  }

  // Fit: scale the horizontal sinusoids to the RMS speed and the dash peak speed to the max speed.
  double sine_scale = 1.0;
  double dash_speed = spec.max_speed_mps;
  std::vector<SineTerm> base(P.sines.begin(), P.sines.end());
  for (int iter = 0; iter < 40; ++iter) {
    for (std::size_t i = n_vertical; i < P.sines.size(); ++i) P.sines[i].amplitude_m = base[i].amplitude_m * sine_scale;
    const double a_lim = dashAccelLimit(dash_speed);
    for (std::size_t i = 0; i < P.dashes.size(); ++i) {
      DashTerm& d = P.dashes[i];
      d.tau_s = std::max(0.2, dash_speed / (std::exp(-0.5) * a_lim));
      d.amplitude_m = dash_dirs[i] * (dash_speed * d.tau_s / std::exp(-0.5));
    }
    const SpeedStats st = Trajectory(P).stats(50.0);
    if (st.rms_mps <= 0.0 || st.max_mps <= 0.0) break;
    const double er = spec.rms_speed_mps / st.rms_mps, em = spec.max_speed_mps / st.max_mps;
    if (std::abs(er - 1.0) < 0.003 && std::abs(em - 1.0) < 0.003) break;
    sine_scale *= std::pow(er, 1.2);
    dash_speed *= em;
  }
  return P;
}

}  // namespace sim
}  // namespace diekf
