// Whole-sequence simulation: trajectory + IMU + rendered images + ground truth -> bag and calibration files.
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "diekf/sim/camera_patterns.h"
#include "diekf/sim/clutter.h"
#include "diekf/sim/imu_sim.h"
#include "diekf/sim/realism.h"
#include "diekf/sim/renderer.h"
#include "diekf/sim/sequence_io.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {

struct SimulationOptions {
  std::string preset = "flight1";
  double duration_s = 60.0;
  std::uint64_t seed = 1;
  std::string texture;              ///< "" = the preset's; checkerboard, natural, grass, leaves, dirt or an image path
  double texture_size_m = 1.0;      ///< physical width of one tile of an image texture (m)
  double square_m = 0.05;           ///< checkerboard square (m)
  double incline_deg = 0.0;         ///< plane tilt about a horizontal axis (deg, 0..30 validated by the CLI)
  double incline_azimuth_deg = 0.0; ///< azimuth of that axis in W (deg)
  double height_m = -1.0;           ///< mean IMU height above the plane; < 0 = the preset's
  double height_amplitude_m = -1.0; ///< amplitude of the slow height changes (m); < 0 = the preset's
  double takeoff_from_m = -1.0;     ///< start at rest at this IMU height and climb to the flight (m); < 0 = no
  double fps = 30.0;                ///< image rate (Hz)
  double exposure_ms = 4.0;         ///< exposure time (ms); motion blur integrates over it
  int max_subframes = 8;            ///< cap on sub-frame renders per image
  double blur_step_px = 1.0;        ///< image motion between two sub-frames (px)
  double scale = 1.0;               ///< resolution/intrinsics scale of the 752x480 camera
  int threads = 2;
  double gain_ramp = 0.0;           ///< slow brightness change: relative amplitude (e.g. 0.2 = +-20 %)
  double gain_ramp_period_s = 20.0;
  double flicker_prob = 0.0;        ///< probability per frame of an abrupt brightness jump
  double flicker_amplitude = 0.25;  ///< relative size of such a jump
  double drop_prob = 0.0;           ///< probability per frame of a dropped image
  /// Image stamps taken at arrival on a host (USB cameras): each stamp is delayed by |N(0, J)| more, ms (0: the
  /// capture time plus the time offset exactly). The stamps stay in order, at least 0.5 ms apart.
  double stamp_jitter_ms = 0.0;
  /// IMU stamps taken at arrival on a host (an IMU read over USB or a serial link): each stamp is delayed by
  /// |N(0, J)| more, ms (0: the sample times exactly). In order, at least 0.05 ms apart.
  double imu_stamp_jitter_ms = 0.0;
  /// Mains-powered lighting whose brightness is modulated at this frequency (twice the mains frequency: 100 or
  /// 120 Hz); with a rolling shutter each row integrates its own part of the cycle: horizontal bands that move
  /// from one image to the next. 0: steady light.
  double mains_flicker_hz = 0.0;
  double mains_flicker_depth = 0.2;  ///< modulation depth of that light: 1 + depth sin(2 pi f t)
  /// Images compressed as JPEG at this quality (1-100) and decoded again, as MJPEG webcams deliver them (8x8
  /// blocks fixed in the image, fine texture quantised away). 0: uncompressed.
  double jpeg_quality = 0.0;
  double pose_rate_hz = 200.0;      ///< /mocap/pose rate
  bool vibration = true;            ///< propeller vibration (on for flight presets)
  bool imu_errors = true;           ///< IMU noise, biases and vibration
  SensorOptions sensor;             ///< vignetting and image noise
  bool camera_info = true;          ///< also write /mynteye/left/camera_info
  bool lens_distortion = true;      ///< the MYNT EYE's radial-tangential distortion (false: a pinhole camera)
  bool lz4 = false;                 ///< LZ4-compress the bag chunks
  double start_stamp_s = 1600000000.0;  ///< stamp of t = 0 on the bag clock
  ImuNoiseParams imu_noise;
  RealismOptions realism;               ///< realistic-camera effects (all off by default)
  std::string realism_preset = "clean"; ///< name written to realism.yaml ("custom" if flags changed a preset)
  ClutterOptions clutter;               ///< moving objects and boxes on the ground (none by default)
  CameraPatternOptions patterns;        ///< the drone's shadow, projector dots, lens dirt (none by default)
  bool write_flat_field = false;        ///< also write DIR/flat_field.yaml: vignetting x the fixed pattern gain
  std::string output_dir;
};

struct SimulationSummary {
  SpeedStats speed;
  int frames_written = 0;
  int frames_dropped = 0;
  double mean_subframes = 0.0;
  std::size_t imu_samples = 0;
  std::size_t poses = 0;
  Vec3 accel_bias0 = Vec3::Zero(), gyro_bias0 = Vec3::Zero();
  double wall_s = 0.0;
  std::string bag_path;
  int clutter_objects = 0;                  ///< movers' crossings + boxes
  double mover_coverage_mean = 0.0, mover_coverage_max = 0.0;  ///< fraction of the image, over the frames
  double box_coverage_mean = 0.0, box_coverage_max = 0.0;
  double pattern_coverage_mean = 0.0;       ///< image share with a camera-fixed gain off 1 by over 10 %
  double shadow_coverage_mean = 0.0, shadow_coverage_max = 0.0;  ///< image share in the drone's shadow
};

/// Result of command-line parsing.
enum class ParseResult { kOk, kHelp, kListPresets, kError };

/// Parses diekf_simulate's arguments (without argv[0]); on kError `error` holds a one-line reason.
ParseResult parseSimulateArgs(const std::vector<std::string>& args, SimulationOptions* opt, std::string* error);
std::string simulateUsage();

/// Builds the trajectory for the options (preset, duration, seed, incline, height).
Trajectory makeTrajectory(const SimulationOptions& opt);

/// Builds the camera pose of the IMU state with the camera's extrinsics.
CameraPose cameraPose(const KinematicState& k, const CameraModel& cam);

/// The ground point the camera's optical axis hits at time t (the camera pose from the trajectory).
Eigen::Vector3d lookAtPoint(const Trajectory& traj, const CameraModel& cam, double t_s);

/// The movers and boxes of the options for this trajectory (empty without --movers/--boxes). Throws when a box
/// would come within 0.1 m of the camera's lowest height above the ground.
Clutter makeSimulationClutter(const SimulationOptions& opt, const Trajectory& traj, const CameraModel& cam);

/// Runs the simulation; writes output_dir/{sequence.bag, camchain.yaml, imu.yaml, realism.yaml} and, with
/// movers or boxes, occlusion.csv (per image: covered fractions) and clutter.yaml (objects and summary).
/// Progress goes to `progress` (may be null). Throws std::runtime_error with a one-line reason.
SimulationSummary runSimulation(const SimulationOptions& opt, std::ostream* progress);

}  // namespace sim
}  // namespace diekf
