// Smooth analytic quadrotor-like trajectories over a (possibly inclined) plane, with exact derivatives.
//
// Position: hover point + (sum of sinusoids + Gaussian "dash" bumps), faded in from hover with a C3 ramp.
// Attitude: the body z axis (IMU z, up) follows the thrust direction a_W - g_W, yaw is a slow sinusoid.
// Angular rate and specific force are computed analytically from jerk and yaw rate (no finite differences).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace diekf {
namespace sim {

constexpr double kGravityMps2 = 9.81;  ///< magnitude of gravity; g_W = (0, 0, -kGravityMps2)

/// Infinite plane {X : n.X + e = 0} with unit normal n pointing to the camera side (docs/conventions.md §2).
struct Plane {
  Eigen::Vector3d n = Eigen::Vector3d::UnitZ();  ///< unit normal in W
  double e_m = 0.0;                              ///< offset (m)
  /// Plane rotated by `incline_deg` about the horizontal axis at azimuth `axis_azimuth_deg` (through the origin).
  static Plane inclined(double incline_deg, double axis_azimuth_deg);
  /// Orthonormal in-plane basis (t1, t2) with t1 x t2 = n; texture u runs along t1, v along t2.
  void basis(Eigen::Vector3d* t1, Eigen::Vector3d* t2) const;
  /// Height of the plane above the world xy point along W z: z such that (x, y, z) is on the plane.
  double zAt(double x_m, double y_m) const;
};

/// Kinematic state of the IMU (body) frame at one instant.
struct KinematicState {
  double t_s = 0.0;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();   ///< position of I in W (m)
  Eigen::Vector3d v_W = Eigen::Vector3d::Zero();   ///< velocity (m/s)
  Eigen::Vector3d a_W = Eigen::Vector3d::Zero();   ///< acceleration (m/s^2)
  Eigen::Matrix3d R_WI = Eigen::Matrix3d::Identity();
  Eigen::Vector3d w_I = Eigen::Vector3d::Zero();   ///< body angular rate in I (rad/s)
  Eigen::Vector3d f_I = Eigen::Vector3d::Zero();   ///< specific force R_WI^T (a_W - g_W) (m/s^2)
};

/// One sinusoidal position component A sin(omega t + phi) along a W direction.
struct SineTerm {
  Eigen::Vector3d amplitude_m = Eigen::Vector3d::Zero();
  double omega_radps = 0.0;
  double phase_rad = 0.0;
};

/// Gaussian bump D exp(-((t - tc)/tau)^2 / 2) along a horizontal direction: a quick out-and-back "dash".
struct DashTerm {
  Eigen::Vector3d amplitude_m = Eigen::Vector3d::Zero();
  double t_center_s = 0.0;
  double tau_s = 1.0;
};

struct TrajectoryParams {
  double duration_s = 60.0;
  double hover_s = 1.0;            ///< initial hover before the motion fades in
  double ramp_s = 3.0;             ///< duration of the C3 fade-in
  double height_m = 0.8;           ///< mean IMU height above the plane, along W z
  double height_amplitude_m = 0.2; ///< peak height variation (sum of vertical sinusoids)
  double yaw0_rad = 0.0;
  double yaw_amplitude_rad = 0.5;
  double yaw_omega_radps = 0.1;
  double yaw_phase_rad = 0.0;
  std::vector<SineTerm> sines;     ///< horizontal and vertical motion (zero-mean)
  std::vector<DashTerm> dashes;    ///< fast out-and-back manoeuvres (horizontal)
  /// Take-off: the IMU rests at this height above the plane until takeoff_start_s, then climbs (C3 ramp over
  /// climb_s) to height_m; < 0: no take-off (the flight starts at height_m).
  double takeoff_from_m = -1.0;
  double takeoff_start_s = 2.0;
  double climb_s = 3.0;
  Plane plane;                     ///< the ground
};

/// Speed statistics sampled over a trajectory.
struct SpeedStats {
  double rms_mps = 0.0;
  double max_mps = 0.0;
  double min_height_m = 0.0;       ///< minimum IMU height above the plane along W z
  double max_height_m = 0.0;
  double max_tilt_deg = 0.0;       ///< maximum angle between body z and W z
};

class Trajectory {
 public:
  explicit Trajectory(TrajectoryParams params) : params_(std::move(params)) {}
  KinematicState evaluate(double t_s) const;
  const TrajectoryParams& params() const { return params_; }
  /// Speed/height/tilt statistics sampled at `rate_hz` over [0, duration].
  SpeedStats stats(double rate_hz = 100.0) const;

 private:
  TrajectoryParams params_;
};

/// Targets of a preset (docs/algorithm.md §5 for flight1..7).
struct PresetSpec {
  std::string name;
  double rms_speed_mps = 0.24;
  double max_speed_mps = 0.83;
  double height_m = 0.8;
  double height_amplitude_m = 0.25;
  std::string texture = "checkerboard";  ///< default texture of the preset
  bool vibration = true;                 ///< propeller vibration on by default
};

/// Known preset names: flight1..flight7, hover, incline (slow flight, for inclined-plane runs).
std::vector<PresetSpec> presetSpecs();
/// Returns false if `name` is unknown.
bool findPreset(const std::string& name, PresetSpec* spec);

/// Random trajectory for a preset: draws sinusoids and dashes from `seed`, then scales them so that the RMS
/// and maximum speeds over [0, duration] match the preset's targets (a few fixed-point iterations).
TrajectoryParams makePresetTrajectory(const PresetSpec& spec, double duration_s, std::uint64_t seed,
                                      const Plane& plane);

}  // namespace sim
}  // namespace diekf
