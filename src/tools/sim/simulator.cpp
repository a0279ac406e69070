// Sequence simulation driver and diekf_simulate's argument parsing.
#include "diekf/sim/simulator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <memory>
#include <ostream>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>

#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>

namespace diekf {
namespace sim {
namespace {

bool parseDouble(const std::string& s, double* v) {
  try {
    std::size_t pos = 0;
    *v = std::stod(s, &pos);
    return pos == s.size() && std::isfinite(*v);
  } catch (...) {
    return false;
  }
}

bool parseUint(const std::string& s, std::uint64_t* v) {
  if (s.empty() || s.find_first_not_of("0123456789") != std::string::npos) return false;
  try {
    *v = std::stoull(s);
    return true;
  } catch (...) {
    return false;
  }
}

}  // namespace

std::string simulateUsage() {
  std::ostringstream os;
  os << "usage: diekf_simulate [--preset NAME] [--duration S] [--seed N]\n"
        "                      [--texture checkerboard|natural|grass|leaves|dirt|IMAGE]\n"
        "                      [--incline-deg A] [options] --output DIR\n"
        "  -> DIR/sequence.bag, DIR/camchain.yaml, DIR/imu.yaml\n"
        "Renders a downward MYNT EYE S-like camera (752x480 @ 30 Hz, radtan) over a textured plane, with a 500 Hz\n"
        "IMU and ground truth (/mocap/pose = T_W_I, /ground_truth/plane).\n"
        "Scenario:\n"
        "  --preset NAME            flight1..flight7 (paper's flights), incline, hover   [flight1]\n"
        "  --list-presets           print presets with measured RMS/max speeds and exit\n"
        "  --duration S             sequence length (s)                                 [60]\n"
        "  --seed N                 random seed (trajectory, texture, noise)            [1]\n"
        "  --height M               mean IMU height above the plane (m)                [preset]\n"
        "  --height-amplitude M     amplitude of the slow height changes (m)            [preset]\n"
        "  --takeoff-from M         rest at this IMU height for 2 s, climb in 3 s, then fly [off]\n"
        "  --incline-deg A          plane tilt about a horizontal axis, 0..45 (deg)     [0]\n"
        "  --incline-azimuth-deg A  direction of that axis in W (deg)                   [0]\n"
        "Texture:\n"
        "  --texture T              checkerboard | natural | grass | leaves | dirt |    [preset]\n"
        "                           image file (tiled)\n"
        "  --texture-size M         physical width of one image tile (m)                [1.0]\n"
        "  --square M               checkerboard square size (m)                        [0.05]\n"
        "Camera:\n"
        "  --fps HZ                 image rate                                          [30]\n"
        "  --exposure-ms MS         exposure time, motion blur over it                  [4]\n"
        "  --max-subframes N        sub-frame renders per image (motion blur)           [8]\n"
        "  --scale F                resolution/intrinsics scale (e.g. 0.25)             [1]\n"
        "  --vignetting V           brightness loss at the corners (0..1)               [0.35]\n"
        "  --read-noise DN          image read noise, 1-sigma grey levels               [1.5]\n"
        "  --black-level DN         pedestal added after the gain (an exposure step then changes the image\n"
        "                           affinely, not by a factor)                          [0]\n"
        "  --no-image-noise         noise-free images\n"
        "  --gain-ramp R            slow brightness change, relative amplitude          [0]\n"
        "  --gain-ramp-period S     its period (s)                                      [20]\n"
        "  --flicker-prob P         per-frame probability of an abrupt brightness jump  [0]\n"
        "  --flicker-amplitude R    relative size of a jump                             [0.25]\n"
        "  --drop-prob P            per-frame probability of a dropped image            [0]\n"
        "  --stamp-jitter-ms J      image stamps taken on arrival: each delayed by      [0]\n"
        "                           |N(0, J)| ms more (in order; the mean is an offset)\n"
        "  --mains-flicker-hz F     lighting modulated at F (100 or 120 Hz: twice the    [0]\n"
        "                           mains); each row integrates its part of the cycle\n"
        "                           (bands that move between images with a rolling shutter)\n"
        "  --mains-flicker-depth A  its modulation depth, 1 + A sin(2 pi F t), 0..1     [0.2]\n"
        "  --gamma G                camera response: grey = 255 (signal / 255)^(1/G)     [1]\n"
        "                           (webcams' image processors encode with about 2.2)\n"
        "  --jpeg-quality Q         images JPEG-compressed at quality Q, 1..100, as      [0]\n"
        "                           MJPEG webcams deliver them (0: uncompressed)\n"
        "  --no-camera-info         do not write /mynteye/left/camera_info\n"
        "Realistic camera (written to DIR/realism.yaml; rendering and IMU use the true camera):\n"
        "  --realism clean|realistic  preset of the options below (explicit ones win)   [clean]\n"
        "                           clean: all off (perfect camera); realistic: rolling\n"
        "                           shutter 16 ms, time offset 5 ms, intrinsics error 1.5 %,\n"
        "                           extrinsic rotation error 1 deg, defocus 1.0 px,\n"
        "                           exposure steps, non-Lambertian 0.3\n"
        "  --rolling-shutter-ms MS  readout top row -> bottom row, 0..100 (ms); rows    [0]\n"
        "                           rendered at their own times, stamp = middle row\n"
        "  --time-offset-ms MS      image stamp = true capture time + MS, -100..100;    [0]\n"
        "                           camchain keeps timeshift_cam_imu 0 (truth: -MS)\n"
        "  --intrinsics-error PCT   written fu, fv x (1 + PCT/100), pu + PCT/100 * w/2, [0]\n"
        "                           pv - PCT/100 * h/2; -10..10\n"
        "  --extrinsic-rot-error-deg DEG  written T_cam_imu rotated by DEG about        [0]\n"
        "                           camera axis (1, 1, 0)/sqrt(2), centre kept; -10..10\n"
        "  --defocus-px PX          Gaussian defocus sigma at full resolution, 0..10    [0]\n"
        "  --exposure-steps         auto-exposure gain steps +-10..25 % every 1-3 s     [off]\n"
        "  --no-exposure-steps      turns them off (e.g. after --realism realistic)\n"
        "  --non-lambertian F       glossy patches (~20 % of the ground): specular      [0]\n"
        "                           amplitude relative to the texture mean, 0..1\n"
        "Moving objects and clutter (outliers of the plane; ground truth stays the ground plane;\n"
        "  DIR/occlusion.csv: covered fraction per image, DIR/clutter.yaml: objects and summary):\n"
        "  --movers N               flat textured objects moving over the ground, 0..64 [0]\n"
        "                           each crosses the view once per --mover-interval-s\n"
        "  --mover-size-m M         length along the motion (m)                         [0.8]\n"
        "  --mover-aspect A         width / length                                      [0.6]\n"
        "  --mover-speed-mps V      mean speed over the ground (0.8-1.2 x V each)       [0.5]\n"
        "  --mover-interval-s S     time between two crossings of one mover (s)         [6]\n"
        "  --mover-texture T        leaves | grass | dirt | natural | checkerboard |    [leaves]\n"
        "                           image file (1 m wide)\n"
        "  --boxes N                static boxes along the flight's ground track, 0..500 [0]\n"
        "  --box-size-m M           mean side of a box footprint (0.75-1.25 x M)        [0.25]\n"
        "  --box-height-m M         height of the box tops above the ground (m)         [0.15]\n"
        "  --box-texture T          texture of tops and sides (as --mover-texture)      [grass]\n"
        "Camera-fixed patterns (docs/simulator.md; DIR/patterns.yaml: settings and coverage):\n"
        "  --shadow                 the drone's shadow on the ground (sun fixed in W)\n"
        "  --shadow-fixed           the shadow as if the camera stayed level (fixed in the image but for its size)\n"
        "  --sun-elevation-deg A    sun above the horizon, 0..90 (deg)                  [65]\n"
        "  --sun-azimuth-deg A      sun's azimuth in W (deg)                            [30]\n"
        "  --shadow-size-m M        quadrotor span, rotor tip to rotor tip (m)          [0.6]\n"
        "  --shadow-darkness F      brightness lost in the body's full shadow, 0..1     [0.55]\n"
        "  --shadow-softness-m M    edge width beyond the sun's penumbra (m)            [0.02]\n"
        "  --projector-dots N       IR projector dots fixed in the image, 0..100000     [0]\n"
        "  --projector-strength F   dot peak irradiance over the ambient light          [1.5]\n"
        "  --projector-dot-px PX    dot Gaussian sigma at 752x480 (px)                  [1.2]\n"
        "  --lens-dirt N            out-of-focus dirt blobs on the lens, 0..100         [0]\n"
        "  --write-flat-field       also write DIR/flat_field.yaml, the true relative response per pixel\n"
        "                           (vignetting x dots x dirt; not the shadow), for fixed_pattern/vignetting_file\n"
        "  --lens-dirt-opacity F    light a blob's centre blocks, 0..1                  [0.5]\n"
        "IMU:\n"
        "  --no-vibration           no propeller vibration (on by default)\n"
        "  --no-distortion          a pinhole camera (the MYNT EYE's lens distortion off)\n"
        "  --no-imu-noise           exact IMU readings (no noise, bias, vibration)\n"
        "  --imu-rate HZ            IMU sample rate (imu.yaml's update_rate)             [500]\n"
        "  --imu-stamp-jitter-ms J  IMU stamps taken on arrival at a host: each delayed [0]\n"
        "                           by |N(0, J)| ms more (in order, 0.05 ms apart at least)\n"
        "  --accel-noise-density X  m/s^2/sqrt(Hz)                                      [2e-3]\n"
        "  --accel-random-walk X    m/s^3/sqrt(Hz)                                      [4e-4]\n"
        "  --gyro-noise-density X   rad/s/sqrt(Hz)                                      [1.7e-4]\n"
        "  --gyro-random-walk X     rad/s^2/sqrt(Hz)                                    [2e-5]\n"
        "Output:\n"
        "  --pose-rate HZ           /mocap/pose rate (>= 100)                           [200]\n"
        "  --start-stamp S          bag stamp of t = 0 (s)                              [1600000000]\n"
        "  --threads N              render threads                                      [2]\n"
        "  --lz4                    LZ4-compress the bag\n"
        "  --output DIR             output directory (created)\n"
        "  --help                   this text\n";
  return os.str();
}

ParseResult parseSimulateArgs(const std::vector<std::string>& args_in, SimulationOptions* opt, std::string* error) {
  // Split --key=value into two tokens.
  std::vector<std::string> args;
  for (const std::string& a : args_in) {
    const std::size_t eq = a.find('=');
    if (a.rfind("--", 0) == 0 && eq != std::string::npos) {
      args.push_back(a.substr(0, eq));
      args.push_back(a.substr(eq + 1));
    } else {
      args.push_back(a);
    }
  }
  struct NumOpt {
    double* d;
    double lo, hi;
  };
  std::map<std::string, NumOpt> nums = {
      {"--duration", {&opt->duration_s, 0.5, 3600}},
      {"--height", {&opt->height_m, 0.1, 20}},
      {"--height-amplitude", {&opt->height_amplitude_m, 0, 10}},
      {"--takeoff-from", {&opt->takeoff_from_m, 0.02, 5}},
      {"--incline-deg", {&opt->incline_deg, 0, 45}},
      {"--incline-azimuth-deg", {&opt->incline_azimuth_deg, -360, 360}},
      {"--texture-size", {&opt->texture_size_m, 1e-3, 1000}},
      {"--square", {&opt->square_m, 1e-3, 10}},
      {"--fps", {&opt->fps, 1, 1000}},
      {"--exposure-ms", {&opt->exposure_ms, 0, 30}},
      {"--scale", {&opt->scale, 0.05, 4}},
      {"--vignetting", {&opt->sensor.vignetting, 0, 1}},
      {"--read-noise", {&opt->sensor.read_noise_dn, 0, 100}},
      {"--black-level", {&opt->sensor.black_level_dn, 0, 128}},
      {"--gain-ramp", {&opt->gain_ramp, 0, 0.9}},
      {"--gain-ramp-period", {&opt->gain_ramp_period_s, 0.1, 1e6}},
      {"--flicker-prob", {&opt->flicker_prob, 0, 1}},
      {"--flicker-amplitude", {&opt->flicker_amplitude, 0, 0.9}},
      {"--drop-prob", {&opt->drop_prob, 0, 0.9}},
      {"--stamp-jitter-ms", {&opt->stamp_jitter_ms, 0, 50}},
      {"--mains-flicker-hz", {&opt->mains_flicker_hz, 0, 1000}},
      {"--mains-flicker-depth", {&opt->mains_flicker_depth, 0, 1}},
      {"--gamma", {&opt->sensor.gamma, 0.2, 5}},
      {"--jpeg-quality", {&opt->jpeg_quality, 0, 100}},
      {"--pose-rate", {&opt->pose_rate_hz, 100, 10000}},
      {"--start-stamp", {&opt->start_stamp_s, 1, 4e9}},
      {"--accel-noise-density", {&opt->imu_noise.accel_noise_density, 0, 10}},
      {"--accel-random-walk", {&opt->imu_noise.accel_random_walk, 0, 10}},
      {"--gyro-noise-density", {&opt->imu_noise.gyro_noise_density, 0, 10}},
      {"--gyro-random-walk", {&opt->imu_noise.gyro_random_walk, 0, 10}},
      {"--imu-rate", {&opt->imu_noise.rate_hz, 50, 2000}},
      {"--imu-stamp-jitter-ms", {&opt->imu_stamp_jitter_ms, 0, 20}},
      {"--rolling-shutter-ms", {&opt->realism.rolling_shutter_ms, 0, 100}},
      {"--time-offset-ms", {&opt->realism.time_offset_ms, -100, 100}},
      {"--intrinsics-error", {&opt->realism.intrinsics_error_pct, -10, 10}},
      {"--extrinsic-rot-error-deg", {&opt->realism.extrinsic_rot_error_deg, -10, 10}},
      {"--defocus-px", {&opt->realism.defocus_px, 0, 10}},
      {"--non-lambertian", {&opt->realism.non_lambertian, 0, 1}},
      {"--mover-size-m", {&opt->clutter.mover_size_m, 0.02, 10}},
      {"--mover-aspect", {&opt->clutter.mover_aspect, 0.05, 20}},
      {"--mover-speed-mps", {&opt->clutter.mover_speed_mps, 0, 20}},
      {"--mover-interval-s", {&opt->clutter.mover_interval_s, 0.5, 3600}},
      {"--box-size-m", {&opt->clutter.box_size_m, 0.02, 10}},
      {"--box-height-m", {&opt->clutter.box_height_m, 0.005, 5}},
      {"--sun-elevation-deg", {&opt->patterns.sun_elevation_deg, 0, 90}},
      {"--sun-azimuth-deg", {&opt->patterns.sun_azimuth_deg, -360, 360}},
      {"--shadow-size-m", {&opt->patterns.shadow_size_m, 0.01, 10}},
      {"--shadow-darkness", {&opt->patterns.shadow_darkness, 0, 1}},
      {"--shadow-softness-m", {&opt->patterns.shadow_softness_m, 0, 1}},
      {"--projector-strength", {&opt->patterns.projector_strength, 0, 100}},
      {"--projector-dot-px", {&opt->patterns.projector_dot_px, 0.1, 20}},
      {"--lens-dirt-opacity", {&opt->patterns.lens_dirt_opacity, 0, 1}},
  };
  // Realism options given explicitly: they win over a --realism preset wherever they appear.
  const std::map<std::string, double RealismOptions::*> realism_fields = {
      {"--rolling-shutter-ms", &RealismOptions::rolling_shutter_ms},
      {"--time-offset-ms", &RealismOptions::time_offset_ms},
      {"--intrinsics-error", &RealismOptions::intrinsics_error_pct},
      {"--extrinsic-rot-error-deg", &RealismOptions::extrinsic_rot_error_deg},
      {"--defocus-px", &RealismOptions::defocus_px},
      {"--non-lambertian", &RealismOptions::non_lambertian},
  };
  std::set<std::string> explicit_realism;
  std::string realism_name;
  bool list = false;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    const auto value = [&](std::string* v) {
      if (i + 1 >= args.size()) {
        *error = "missing value after " + a;
        return false;
      }
      *v = args[++i];
      return true;
    };
    std::string v;
    if (a == "--help" || a == "-h") return ParseResult::kHelp;
    if (a == "--list-presets") list = true;
    else     if (a == "--no-vibration") {
      opt->vibration = false;
    } else if (a == "--vibration") {
      opt->vibration = true;
    } else if (a == "--no-imu-noise") {
      opt->imu_errors = false;
    } else if (a == "--no-image-noise") {
      opt->sensor.noise = false;
    } else if (a == "--write-flat-field") {
      opt->write_flat_field = true;
    } else if (a == "--no-distortion") {
      opt->lens_distortion = false;
    } else if (a == "--no-camera-info") {
      opt->camera_info = false;
    } else if (a == "--lz4") {
      opt->lz4 = true;
    } else if (a == "--exposure-steps" || a == "--no-exposure-steps") {
      opt->realism.exposure_steps = a == "--exposure-steps";
      explicit_realism.insert("--exposure-steps");
    } else if (a == "--realism") {
      if (!value(&v)) return ParseResult::kError;
      RealismOptions r;
      if (!realismPreset(v, &r)) {
        *error = "unknown --realism '" + v + "' (clean, realistic)";
        return ParseResult::kError;
      }
      realism_name = v;
    } else if (a == "--preset") {
      if (!value(&v)) return ParseResult::kError;
      PresetSpec spec;
      if (!findPreset(v, &spec)) {
        *error = "unknown preset '" + v + "' (flight1..flight7, incline, hover)";
        return ParseResult::kError;
      }
      opt->preset = v;
    } else if (a == "--texture") {
      if (!value(&v)) return ParseResult::kError;
      if (v.empty()) {
        *error = "empty --texture";
        return ParseResult::kError;
      }
      opt->texture = v;
    } else if (a == "--output") {
      if (!value(&v)) return ParseResult::kError;
      opt->output_dir = v;
    } else if (a == "--seed") {
      if (!value(&v)) return ParseResult::kError;
      if (!parseUint(v, &opt->seed)) {
        *error = "--seed needs a non-negative integer, got '" + v + "'";
        return ParseResult::kError;
      }
    } else if (a == "--mover-texture" || a == "--box-texture") {
      if (!value(&v)) return ParseResult::kError;
      if (v.empty()) {
        *error = "empty " + a;
        return ParseResult::kError;
      }
      (a == "--mover-texture" ? opt->clutter.mover_texture : opt->clutter.box_texture) = v;
    } else if (a == "--shadow") {
      opt->patterns.shadow = true;
    } else if (a == "--shadow-fixed") {
      opt->patterns.shadow = true;
      opt->patterns.shadow_fixed = true;
    } else if (a == "--projector-dots" || a == "--lens-dirt") {
      if (!value(&v)) return ParseResult::kError;
      std::uint64_t n = 0;
      const std::uint64_t hi = a == "--projector-dots" ? 100000 : 100;
      if (!parseUint(v, &n) || n > hi) {
        *error = a + " needs an integer in [0, " + std::to_string(hi) + "], got '" + v + "'";
        return ParseResult::kError;
      }
      (a == "--projector-dots" ? opt->patterns.projector_dots : opt->patterns.lens_dirt) = static_cast<int>(n);
    } else if (a == "--movers" || a == "--boxes") {
      if (!value(&v)) return ParseResult::kError;
      std::uint64_t n = 0;
      const std::uint64_t hi = a == "--movers" ? 64 : 500;
      if (!parseUint(v, &n) || n > hi) {
        *error = a + " needs an integer in [0, " + std::to_string(hi) + "], got '" + v + "'";
        return ParseResult::kError;
      }
      (a == "--movers" ? opt->clutter.movers : opt->clutter.boxes) = static_cast<int>(n);
    } else if (a == "--threads" || a == "--max-subframes") {
      if (!value(&v)) return ParseResult::kError;
      std::uint64_t n = 0;
      if (!parseUint(v, &n) || n < 1 || n > 64) {
        *error = a + " needs an integer in [1, 64], got '" + v + "'";
        return ParseResult::kError;
      }
      (a == "--threads" ? opt->threads : opt->max_subframes) = static_cast<int>(n);
    } else if (nums.count(a)) {
      if (!value(&v)) return ParseResult::kError;
      const NumOpt& n = nums.at(a);
      double d = 0;
      if (!parseDouble(v, &d) || d < n.lo || d > n.hi) {
        std::ostringstream os;
        os << a << " needs a number in [" << n.lo << ", " << n.hi << "], got '" << v << "'";
        *error = os.str();
        return ParseResult::kError;
      }
      *n.d = d;
      if (realism_fields.count(a)) explicit_realism.insert(a);
    } else {
      *error = "unknown argument '" + a + "' (see --help)";
      return ParseResult::kError;
    }
  }
  if (!realism_name.empty()) {
    const RealismOptions given = opt->realism;
    realismPreset(realism_name, &opt->realism);
    for (const auto& kv : realism_fields)
      if (explicit_realism.count(kv.first)) opt->realism.*kv.second = given.*kv.second;
    if (explicit_realism.count("--exposure-steps")) opt->realism.exposure_steps = given.exposure_steps;
    opt->realism_preset = explicit_realism.empty() ? realism_name : realism_name + " (with explicit options)";
  } else if (!explicit_realism.empty()) {
    opt->realism_preset = "custom";
  }
  if (list) return ParseResult::kListPresets;
  if (opt->output_dir.empty()) {
    *error = "--output DIR is required";
    return ParseResult::kError;
  }
  return ParseResult::kOk;
}

Trajectory makeTrajectory(const SimulationOptions& opt) {
  PresetSpec spec;
  if (!findPreset(opt.preset, &spec)) throw std::runtime_error("unknown preset '" + opt.preset + "'");
  if (opt.height_m > 0.0) spec.height_m = opt.height_m;
  if (opt.height_amplitude_m >= 0.0) spec.height_amplitude_m = opt.height_amplitude_m;
  const Plane plane = Plane::inclined(opt.incline_deg, opt.incline_azimuth_deg);
  TrajectoryParams P = makePresetTrajectory(spec, opt.duration_s, opt.seed, plane);
  if (opt.takeoff_from_m >= 0.0) {
    // Rest, climb, then the preset's flight (its hover, fade-in and dashes shifted after the climb).
    P.takeoff_from_m = opt.takeoff_from_m;
    const double shift_s = P.takeoff_start_s + P.climb_s;
    P.hover_s += shift_s;
    for (DashTerm& d : P.dashes) d.t_center_s += shift_s;
  }
  return Trajectory(P);
}

CameraPose cameraPose(const KinematicState& k, const CameraModel& cam) {
  const Eigen::Isometry3d T_IC = cam.T_cam_imu.inverse();
  CameraPose P;
  P.R_WC = k.R_WI * T_IC.linear();
  P.p_WC = k.p_W + k.R_WI * T_IC.translation();
  return P;
}

Eigen::Vector3d lookAtPoint(const Trajectory& traj, const CameraModel& cam, double t_s) {
  const CameraPose P = cameraPose(traj.evaluate(t_s), cam);
  const Plane& plane = traj.params().plane;
  const Eigen::Vector3d axis = P.R_WC.col(2);
  const double dn = plane.n.dot(axis), dist = plane.n.dot(P.p_WC) + plane.e_m;
  // The optical axis points at the ground in every preset; else the point below the camera.
  const double lambda = dn < -0.05 ? -dist / dn : 0.0;
  const Eigen::Vector3d X = P.p_WC + lambda * axis;
  return X - (plane.n.dot(X) + plane.e_m) * plane.n;
}

Clutter makeSimulationClutter(const SimulationOptions& opt, const Trajectory& traj, const CameraModel& cam) {
  if (!opt.clutter.any()) return Clutter();
  const Plane& plane = traj.params().plane;
  if (opt.clutter.boxes > 0) {
    double min_h = 1e9;
    for (double t = 0.0; t <= opt.duration_s; t += 0.02)
      min_h = std::min(min_h, plane.n.dot(cameraPose(traj.evaluate(t), cam).p_WC) + plane.e_m);
    if (opt.clutter.box_height_m > min_h - 0.1) {
      std::ostringstream os;
      os << "--box-height-m " << opt.clutter.box_height_m << ": the camera comes down to " << std::setprecision(3)
         << min_h << " m above the ground; boxes must stay at least 0.1 m below it";
      throw std::runtime_error(os.str());
    }
  }
  return makeClutter(opt.clutter, plane, [&](double t) { return lookAtPoint(traj, cam, t); }, opt.duration_s,
                     opt.seed);
}

namespace {

/// Image motion (px over the exposure) of the movers in view at time t, against the ground's `ground_px`.
double moverBlurPixels(const Clutter& clutter, const CameraPose& P, const CameraModel& cam, double t,
                       double exposure_s, double ground_px) {
  double worst = 0.0;
  for (const SceneObject& o : clutter.objects()) {
    if (!o.mover) continue;
    const Eigen::Vector3d X_C = P.R_WC.transpose() * (o.positionAt(t) + o.z1 * o.R_WO.col(2) - P.p_WC);
    Vec2 px;
    if (X_C.z() <= 1e-3 || !cam.project(X_C, &px)) continue;
    const double r = 0.5 * std::hypot(o.hx, o.hy) * cam.K.fx / X_C.z();  // image radius of the object (px)
    if (px.x() < -r || px.y() < -r || px.x() > cam.K.width + r || px.y() > cam.K.height + r) continue;
    worst = std::max(worst, ground_px + o.v_W.norm() * exposure_s * cam.K.fx / X_C.z());
  }
  return worst;
}

void writeClutterYaml(const std::string& path, const ClutterOptions& c, const Clutter& clutter,
                      const SimulationSummary& s, int frames_mover, double mean_mover_when_seen) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
  int movers = 0, boxes = 0;
  for (const SceneObject& o : clutter.objects()) (o.mover ? movers : boxes)++;
  f << "# Moving objects and boxes on the ground (diekf_simulate, docs/simulator.md). Ground truth: the ground plane.\n";
  f << "movers: " << c.movers << "\nmover_crossings: " << movers << "\nmover_size_m: " << yamlNumber(c.mover_size_m)
    << "\nmover_aspect: " << yamlNumber(c.mover_aspect) << "\nmover_speed_mps: " << yamlNumber(c.mover_speed_mps)
    << "\nmover_interval_s: " << yamlNumber(c.mover_interval_s) << "\nmover_texture: \"" << c.mover_texture << "\"\n";
  f << "boxes: " << c.boxes << "\nboxes_placed: " << boxes << "\nbox_size_m: " << yamlNumber(c.box_size_m)
    << "\nbox_height_m: " << yamlNumber(c.box_height_m) << "\nbox_texture: \"" << c.box_texture << "\"\n";
  f << "# Fractions of the image (pixels x motion-blur sub-frames) whose nearest hit is a mover / a box.\n";
  f << "frames: " << s.frames_written << "\n";
  f << "mover_coverage_mean: " << yamlNumber(s.mover_coverage_mean) << "\n";
  f << "mover_coverage_max: " << yamlNumber(s.mover_coverage_max) << "\n";
  f << "mover_frames_fraction: " << yamlNumber(s.frames_written ? static_cast<double>(frames_mover) / s.frames_written : 0.0)
    << "  # images with more than 1 % covered by movers\n";
  f << "mover_coverage_mean_when_present: " << yamlNumber(mean_mover_when_seen) << "  # over those images\n";
  f << "box_coverage_mean: " << yamlNumber(s.box_coverage_mean) << "\n";
  f << "box_coverage_max: " << yamlNumber(s.box_coverage_max) << "\n";
  f << "objects:  # [mover, t0_s, p0_W x y z, v_W x y z, half length, half width, bottom, top]\n";
  for (const SceneObject& o : clutter.objects())
    f << "  - [" << (o.mover ? 1 : 0) << ", " << yamlNumber(o.t0_s) << ", " << yamlNumber(o.p0_W.x()) << ", "
      << yamlNumber(o.p0_W.y()) << ", " << yamlNumber(o.p0_W.z()) << ", " << yamlNumber(o.v_W.x()) << ", "
      << yamlNumber(o.v_W.y()) << ", " << yamlNumber(o.v_W.z()) << ", " << yamlNumber(o.hx) << ", "
      << yamlNumber(o.hy) << ", " << yamlNumber(o.z0) << ", " << yamlNumber(o.z1) << "]\n";
  if (!f) throw std::runtime_error("error writing '" + path + "'");
}

}  // namespace

SimulationSummary runSimulation(const SimulationOptions& opt, std::ostream* progress) {
  namespace fs = std::filesystem;
  using Clock = std::chrono::steady_clock;
  const auto t_start = Clock::now();
  SimulationSummary sum;

  std::error_code ec;
  fs::create_directories(opt.output_dir, ec);
  if (ec || !fs::is_directory(opt.output_dir))
    throw std::runtime_error("cannot create output directory '" + opt.output_dir + "'");

  PresetSpec spec;
  if (!findPreset(opt.preset, &spec)) throw std::runtime_error("unknown preset '" + opt.preset + "'");
  const Trajectory traj = makeTrajectory(opt);
  const Plane& plane = traj.params().plane;
  sum.speed = traj.stats(100.0);

  // Texture.
  const std::string tex_name = opt.texture.empty() ? spec.texture : opt.texture;
  if (progress) *progress << "[diekf_simulate] preparing texture '" << tex_name << "'\n";
  const Texture tex = Texture::byName(tex_name, opt.seed, opt.square_m, opt.texture_size_m);

  CameraModel cam = myntEyeSimCamera(opt.scale);  // the true camera: rendering and extrinsics
  if (!opt.lens_distortion) cam.distortion_coeffs = Vec4::Zero();
  const Renderer renderer(cam, opt.threads);
  // Movers and boxes (their textures are built here, seeded apart from the ground's).
  if (progress && opt.clutter.any()) *progress << "[diekf_simulate] placing movers and boxes\n";
  const Clutter clutter = makeSimulationClutter(opt, traj, cam);
  sum.clutter_objects = static_cast<int>(clutter.objects().size());
  // Realistic camera: what the estimator is told (camchain.yaml, camera_info) may differ from the truth.
  const RealismOptions& real = opt.realism;
  const CameraModel written = writtenCalibration(cam, real);
  const ExposureSteps exposure_steps =
      real.exposure_steps ? ExposureSteps(opt.seed, opt.duration_s + 1.0) : ExposureSteps();
  std::unique_ptr<SpecularPatches> specular;
  if (real.non_lambertian > 0.0) specular.reset(new SpecularPatches(opt.seed, real.non_lambertian));
  RenderEffects effects;
  effects.specular = specular.get();
  effects.defocus_sigma_px = real.defocus_px * opt.scale;
  const double readout_s = real.rolling_shutter_ms * 1e-3;
  const bool with_clutter = opt.clutter.any();
  ClutterMask mask;
  if (with_clutter) {
    effects.clutter = &clutter;
    effects.mask = &mask;
  }
  const bool effects_render = readout_s > 0.0 || specular || effects.defocus_sigma_px > 0.0 || with_clutter;
  std::ofstream occlusion;
  if (with_clutter) {
    const std::string path = (fs::path(opt.output_dir) / "occlusion.csv").string();
    occlusion.open(path);
    if (!occlusion) throw std::runtime_error("cannot write '" + path + "'");
    occlusion << "frame,t_s,stamp_ns,mover_fraction,box_fraction,total_fraction\n";
  }
  int frames_mover = 0;
  double mover_when_seen = 0.0;
  const std::int64_t stamp_offset_ns = std::llround(real.time_offset_ms * 1e6);
  const double stamp_offset_s = static_cast<double>(stamp_offset_ns) * 1e-9;
  TopicNames topics;
  writeCamchainYaml((fs::path(opt.output_dir) / "camchain.yaml").string(), written, topics.image);
  writeImuYaml((fs::path(opt.output_dir) / "imu.yaml").string(), opt.imu_noise, topics.imu);
  writeRealismYaml((fs::path(opt.output_dir) / "realism.yaml").string(), opt.realism_preset, real, opt.scale, cam,
                   written, &exposure_steps, specular.get());

  ImuSimOptions imu_opt;
  imu_opt.noise = opt.imu_noise;
  imu_opt.errors = opt.imu_errors;
  imu_opt.vibration.enabled = opt.vibration && spec.vibration;
  const ImuSimResult imu = simulateImu(traj, opt.duration_s, imu_opt, opt.seed);
  sum.accel_bias0 = imu.accel_bias0;
  sum.gyro_bias0 = imu.gyro_bias0;
  sum.imu_samples = imu.samples.size();

  BagClock clock;
  clock.start_ns = static_cast<std::int64_t>(std::llround(opt.start_stamp_s * 1e9));
  sum.bag_path = (fs::path(opt.output_dir) / "sequence.bag").string();
  SequenceBagWriter bag(sum.bag_path, topics, opt.lz4);
  bag.writePlane(clock.toNs(0.0), plane);

  std::mt19937_64 rng(opt.seed ^ 0x1234567887654321ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double exposure_s = opt.exposure_ms * 1e-3;
  const double frame_dt = 1.0 / opt.fps;
  // Last frame: its last row's exposure and its stamp within the sequence.
  const double jitter_s = opt.stamp_jitter_ms * 1e-3;  // 1-sigma of the arrival delay, s
  const double frame_tail_s = 0.5 * exposure_s + 0.5 * readout_s + std::max(0.0, stamp_offset_s) + 5.0 * jitter_s;
  const int n_frames = std::max(0, static_cast<int>(std::floor((opt.duration_s - frame_tail_s) / frame_dt)));
  const double pose_dt = 1.0 / opt.pose_rate_hz;
  std::size_t next_imu = 0, next_pose_idx = 0;
  std::uint32_t imu_seq = 0;
  // Arrival delays of the IMU stamps: their own generator (the other draws stay as they were).
  const double imu_jitter_s = opt.imu_stamp_jitter_ms * 1e-3;  // 1-sigma of the arrival delay, s
  std::mt19937_64 imu_jitter_rng(opt.seed * 40503ull + 7877ull);
  std::normal_distribution<double> imu_jitter_normal(0.0, 1.0);
  std::int64_t last_imu_stamp_ns = std::numeric_limits<std::int64_t>::min();
  // Writes IMU and pose messages with t <= t_until, in stamp order.
  const auto flushUntil = [&](double t_until) {
    while (true) {
      const double t_imu = next_imu < imu.samples.size() ? imu.samples[next_imu].t_s : 1e300;
      const double t_pose = next_pose_idx * pose_dt;
      const double t_next = std::min(t_imu, t_pose <= opt.duration_s + 1e-9 ? t_pose : 1e300);
      if (t_next > t_until + 1e-12 || t_next >= 1e300) break;
      if (t_imu <= t_pose) {
        const ImuSample& s = imu.samples[next_imu++];
        std::int64_t stamp_ns = clock.toNs(s.t_s);
        if (imu_jitter_s > 0.0) {
          stamp_ns += std::llround(imu_jitter_s * std::abs(imu_jitter_normal(imu_jitter_rng)) * 1e9);
          if (last_imu_stamp_ns != std::numeric_limits<std::int64_t>::min())
            stamp_ns = std::max(stamp_ns, last_imu_stamp_ns + 50000);
          last_imu_stamp_ns = stamp_ns;
        }
        bag.writeImu(stamp_ns, s.accel_mps2, s.gyro_radps, imu_seq++);
      } else {
        const KinematicState k = traj.evaluate(t_pose);
        bag.writePose(clock.toNs(t_pose), k.R_WI, k.p_W, static_cast<std::uint32_t>(next_pose_idx));
        ++next_pose_idx;
      }
    }
  };

  std::vector<CameraPose> subposes;
  long subframes_total = 0;
  // Camera-fixed patterns: a gain and an offset per pixel, the shadow's from each frame's pose.
  CameraPatternOptions pat_opt = opt.patterns;
  pat_opt.seed = opt.seed;
  std::unique_ptr<CameraPatterns> patterns;
  if (pat_opt.any()) patterns.reset(new CameraPatterns(pat_opt, renderer, opt.scale));
  double mean_radiance = 100.0;  // grey levels at gain 1 (the last image's), scales the dirt's glare
  // Mains flicker: the light's phase at t = 0 from the seed (its own generator: the other draws stay as they were).
  std::vector<float> row_gain;
  const double flicker_w = 2.0 * M_PI * opt.mains_flicker_hz;  // rad/s
  std::mt19937 flicker_rng(static_cast<std::uint32_t>(opt.seed * 104729u + 17u));
  const double flicker_phase = 2.0 * M_PI * std::uniform_real_distribution<double>(0.0, 1.0)(flicker_rng);
  // Arrival delays of the stamps: their own generator, drawn for every frame (the other draws stay as they were).
  std::mt19937_64 jitter_rng(opt.seed * 2654435761ull + 99991ull);
  std::normal_distribution<double> jitter_normal(0.0, 1.0);
  std::int64_t last_stamp_ns = std::numeric_limits<std::int64_t>::min();
  std::vector<unsigned char> jpeg_bytes;
  for (int f = 0; f < n_frames; ++f) {
    const double t = (f + 1) * frame_dt;  // true mid-exposure time of the middle row (s)
    const double delay_s = jitter_s > 0.0 ? jitter_s * std::abs(jitter_normal(jitter_rng)) : 0.0;
    // The image's stamp: capture time, offset and arrival delay, kept in order (a host stamps in arrival order).
    std::int64_t stamp = clock.toNs(t) + stamp_offset_ns + std::llround(delay_s * 1e9);
    if (jitter_s > 0.0 && last_stamp_ns != std::numeric_limits<std::int64_t>::min())
      stamp = std::max(stamp, last_stamp_ns + 500000);
    last_stamp_ns = stamp;
    flushUntil(jitter_s > 0.0 ? static_cast<double>(stamp - clock.start_ns) * 1e-9 : t + stamp_offset_s);
    // Brightness for this frame (draws happen for every frame so dropping does not change the others).
    double gain = 1.0 + opt.gain_ramp * std::sin(2.0 * M_PI * t / opt.gain_ramp_period_s);
    const bool flicker = uni(rng) < opt.flicker_prob;
    const double flicker_draw = uni(rng);
    const bool drop = uni(rng) < opt.drop_prob;
    if (flicker) gain *= 1.0 + opt.flicker_amplitude * (flicker_draw < 0.5 ? -1.0 : 1.0) * (0.5 + flicker_draw);
    if (real.exposure_steps) gain *= exposure_steps.gain(t);
    if (drop) {
      ++sum.frames_dropped;
      continue;
    }
    const CameraPose p0 = cameraPose(traj.evaluate(t - 0.5 * exposure_s), cam);
    const CameraPose p1 = cameraPose(traj.evaluate(t + 0.5 * exposure_s), cam);
    int n_sub = 1;
    if (exposure_s > 0.0) {
      double blur_px = renderer.motionPixels(p0, p1, plane);
      if (clutter.hasMovers())  // a mover in view blurs by its own motion too
        blur_px = std::max(blur_px, moverBlurPixels(clutter, cameraPose(traj.evaluate(t), cam), cam, t, exposure_s,
                                                    blur_px));
      n_sub = std::clamp(static_cast<int>(std::ceil(blur_px / opt.blur_step_px)), 1, opt.max_subframes);
    }
    subframes_total += n_sub;
    const std::uint64_t noise_seed = opt.seed * 7919ull + static_cast<std::uint64_t>(f);
    cv::Mat img;
    SensorOptions sensor = opt.sensor;
    if (patterns) {
      patterns->update(cameraPose(traj.evaluate(t), cam), plane, mean_radiance);
      sensor.fixed_gain = patterns->gain().data();
      sensor.fixed_add = patterns->offset().data();
      sum.pattern_coverage_mean += patterns->coverage();
      sum.shadow_coverage_mean += patterns->shadowCoverage();
      sum.shadow_coverage_max = std::max(sum.shadow_coverage_max, patterns->shadowCoverage());
    }
    if (flicker_w > 0.0) {
      // Row v is exposed over [t_v - e/2, t_v + e/2], t_v = t + readout (v / (H - 1) - 1/2); the light's mean
      // over that window.
      const int H = renderer.height();
      row_gain.resize(static_cast<std::size_t>(H));
      const double A = opt.mains_flicker_depth;
      for (int v = 0; v < H; ++v) {
        const double tv = t + readout_s * (H > 1 ? static_cast<double>(v) / (H - 1) - 0.5 : 0.0);
        const double mean =
            exposure_s > 0.0
                ? 1.0 + A * (std::cos(flicker_w * (tv - 0.5 * exposure_s) + flicker_phase) -
                             std::cos(flicker_w * (tv + 0.5 * exposure_s) + flicker_phase)) /
                            (flicker_w * exposure_s)
                : 1.0 + A * std::sin(flicker_w * tv + flicker_phase);
        row_gain[static_cast<std::size_t>(v)] = static_cast<float>(mean);
      }
      sensor.row_gain = row_gain.data();
    }
    if (!effects_render) {
      subposes.clear();
      for (int j = 0; j < n_sub; ++j) {
        const double ts = n_sub == 1 ? t : t + exposure_s * ((j + 0.5) / n_sub - 0.5);
        subposes.push_back(cameraPose(traj.evaluate(ts), cam));
      }
      img = renderer.renderImage(subposes, plane, tex, gain, sensor, noise_seed);
    } else {
      // Rolling shutter: every row its own exposure (same sub-frame count), centred readout * (v/(H-1) - 1/2)
      // after t; then the optional glossy patches and defocus.
      const std::vector<RowBand> bands = rollingShutterBands(
          [&](double ts) { return cameraPose(traj.evaluate(ts), cam); }, t, renderer.height(), readout_s, exposure_s,
          n_sub, 1);
      img = renderer.renderBands(bands, plane, tex, gain, sensor, noise_seed, effects);
    }
    if (opt.jpeg_quality > 0.0) {
      const std::vector<int> jpeg_params{cv::IMWRITE_JPEG_QUALITY, static_cast<int>(std::lround(opt.jpeg_quality))};
      if (!cv::imencode(".jpg", img, jpeg_bytes, jpeg_params)) throw std::runtime_error("JPEG encoding failed");
      img = cv::imdecode(jpeg_bytes, cv::IMREAD_GRAYSCALE);
    }
    if (patterns && gain > 0.0) mean_radiance = cv::mean(img)[0] / gain;
    if (opt.camera_info) bag.writeCameraInfo(stamp, written, static_cast<std::uint32_t>(f));
    bag.writeImage(stamp, img, static_cast<std::uint32_t>(f));
    ++sum.frames_written;
    if (with_clutter) {
      const double fm = mask.moverFraction(), fb = mask.boxFraction();
      occlusion << f << "," << yamlNumber(t) << "," << stamp << "," << yamlNumber(fm) << "," << yamlNumber(fb) << ","
                << yamlNumber(fm + fb) << "\n";
      sum.mover_coverage_mean += fm;
      sum.box_coverage_mean += fb;
      sum.mover_coverage_max = std::max(sum.mover_coverage_max, fm);
      sum.box_coverage_max = std::max(sum.box_coverage_max, fb);
      if (fm > 0.01) {
        ++frames_mover;
        mover_when_seen += fm;
      }
    }
    if (progress && (f % 30 == 29 || f + 1 == n_frames)) {
      const double el = std::chrono::duration<double>(Clock::now() - t_start).count();
      *progress << "\r[diekf_simulate] frame " << (f + 1) << "/" << n_frames << " (" << (100 * (f + 1) / n_frames)
                << " %), " << std::fixed << std::setprecision(1) << el << " s elapsed, ETA "
                << el / (f + 1) * (n_frames - f - 1) << " s   " << std::defaultfloat << std::flush;
    }
  }
  flushUntil(opt.duration_s);
  bag.close();
  if (progress && n_frames > 0) *progress << "\n";
  sum.poses = next_pose_idx;
  sum.mean_subframes = sum.frames_written > 0 ? static_cast<double>(subframes_total) / sum.frames_written : 0.0;
  if (with_clutter) {
    if (sum.frames_written > 0) {
      sum.mover_coverage_mean /= sum.frames_written;
      sum.box_coverage_mean /= sum.frames_written;
    }
    occlusion.close();
    if (!occlusion) throw std::runtime_error("error writing occlusion.csv");
    writeClutterYaml((fs::path(opt.output_dir) / "clutter.yaml").string(), opt.clutter, clutter, sum, frames_mover,
                     frames_mover ? mover_when_seen / frames_mover : 0.0);
    if (progress)
      *progress << "[diekf_simulate] covered by movers: mean " << std::setprecision(3) << sum.mover_coverage_mean
                << ", max " << sum.mover_coverage_max << ", " << frames_mover << " images over 1 % (mean "
                << (frames_mover ? mover_when_seen / frames_mover : 0.0) << "); by boxes: mean "
                << sum.box_coverage_mean << ", max " << sum.box_coverage_max << std::defaultfloat << "\n";
  }
  if (patterns) {
    if (sum.frames_written > 0) {
      sum.pattern_coverage_mean /= sum.frames_written;
      sum.shadow_coverage_mean /= sum.frames_written;
    }
    const std::string path = (fs::path(opt.output_dir) / "patterns.yaml").string();
    std::ofstream f(path);
    const CameraPatternOptions& p = opt.patterns;
    f << "# Camera-fixed patterns (diekf_simulate, docs/simulator.md).\n";
    f << "shadow: " << (p.shadow ? "true" : "false") << "\nshadow_fixed: " << (p.shadow_fixed ? "true" : "false")
      << "\nsun_elevation_deg: " << yamlNumber(p.sun_elevation_deg)
      << "\nsun_azimuth_deg: " << yamlNumber(p.sun_azimuth_deg) << "\nshadow_size_m: " << yamlNumber(p.shadow_size_m)
      << "\nshadow_darkness: " << yamlNumber(p.shadow_darkness)
      << "\nshadow_softness_m: " << yamlNumber(p.shadow_softness_m) << "\nprojector_dots: " << p.projector_dots
      << "\nprojector_strength: " << yamlNumber(p.projector_strength)
      << "\nprojector_dot_px: " << yamlNumber(p.projector_dot_px) << "\nlens_dirt: " << p.lens_dirt
      << "\nlens_dirt_opacity: " << yamlNumber(p.lens_dirt_opacity) << "\n";
    f << "# Image shares, mean over the images: a fixed gain off 1 by more than 10 %; in the shadow (gain < 0.9).\n";
    f << "pattern_coverage_mean: " << yamlNumber(sum.pattern_coverage_mean) << "\n";
    f << "shadow_coverage_mean: " << yamlNumber(sum.shadow_coverage_mean) << "\n";
    f << "shadow_coverage_max: " << yamlNumber(sum.shadow_coverage_max) << "\n";
    if (!f) throw std::runtime_error("cannot write '" + path + "'");
    if (progress)
      *progress << "[diekf_simulate] camera-fixed patterns cover " << std::setprecision(3)
                << sum.pattern_coverage_mean << " of the image (shadow: mean " << sum.shadow_coverage_mean << ", max "
                << sum.shadow_coverage_max << ")" << std::defaultfloat << "\n";
  }
  if (opt.write_flat_field) {
    // The oracle for the estimator's fixed_pattern/vignetting_file: what the sensor multiplies every radiance by,
    // apart from the frame's exposure gain and the moving shadow.
    cv::Mat flat(renderer.height(), renderer.width(), CV_32FC1);
    for (int v = 0; v < flat.rows; ++v)
      for (int u = 0; u < flat.cols; ++u) {
        const float g = patterns ? patterns->staticGain()[static_cast<std::size_t>(v) * flat.cols + u] : 1.f;
        flat.at<float>(v, u) = renderer.vignetteGain(u, v, opt.sensor.vignetting) * g;
      }
    const std::string path = (fs::path(opt.output_dir) / "flat_field.yaml").string();
    cv::FileStorage out(path, cv::FileStorage::WRITE);
    if (!out.isOpened()) throw std::runtime_error("cannot write '" + path + "'");
    out << "gain" << flat;
  }
  sum.wall_s = std::chrono::duration<double>(Clock::now() - t_start).count();
  return sum;
}

}  // namespace sim
}  // namespace diekf
