#include "diekf/eval/runner_options.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>

namespace diekf {
namespace eval {

namespace {

double toDouble(const std::string& option, const std::string& text) {
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || errno == ERANGE || !std::isfinite(v)) {
    throw UsageError(option + " expects a number, got '" + text + "'");
  }
  return v;
}

int toInt(const std::string& option, const std::string& text) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0' || errno == ERANGE || v < -100000000L || v > 100000000L) {
    throw UsageError(option + " expects an integer, got '" + text + "'");
  }
  return static_cast<int>(v);
}

}  // namespace

std::string runnerUsage() {
  return R"(Usage: diekf_bag_runner --bag FLIGHT.bag --camchain camchain.yaml --output DIR [options]

Runs a recorded bag through the diekf estimator offline (serially, as fast as the CPU allows, deterministic)
and writes DIR/estimates.csv; when the bag holds /mocap/pose also DIR/groundtruth.csv and DIR/evaluation.json.

Required:
  --bag FILE               input bag (sensor_msgs/Image + sensor_msgs/Imu [+ ground truth])
  --camchain FILE          Kalibr camchain YAML (cam0 intrinsics, distortion, T_cam_imu, timeshift)
  --output DIR             output directory (created if needed)
Options:
  --imu FILE               Kalibr IMU YAML (noise densities, rate); overrides the config's IMU keys
  --config FILE            estimator YAML (default: the package's config/estimator.yaml when present)
  --mode iekf|ekf|lk       update: iterated EKF, one-pass EKF, or the feature (LK) baseline
  --image-topic T          image topic (default: the camchain's rostopic, else /mynteye/left/image_raw)
  --imu-topic T            IMU topic (default: the IMU YAML's rostopic, else /mynteye/imu/data_raw)
  --pose-topic T           ground-truth pose topic (default /mocap/pose)
  --plane-topic T          ground-truth plane topic (default /ground_truth/plane; absent: level ground)
  --width PX               working image width, px (photometric update; the feature tracker for --mode lk)
  --set KEY=VALUE          override one estimator parameter (config-file key, e.g. a/b=1; repeatable;
                           applied last)
  --sequence NAME          sequence name in evaluation.json (default: from the bag's file name)
  --gt-velocity-window S   base of the true velocity's central difference, s (default 0: adjacent poses)
  --eval-start S           evaluation starts S seconds after the first image update (default 3)
  --max-duration S         process only the first S seconds of the bag (default: all)
  --repeat N               soak test: play the bag N times back to back, stamps shifted so that time runs on;
                           only the first pass is kept for the evaluation; RSS printed to stderr after each pass
  --frames-csv             also write DIR/frames.csv: per image the update's photometric residual RMS, valid
                           pixel ratio, passes, whether it was applied, status and message (diagnostics)
  --export-sequence DIR    also write the IMU samples and 8-bit images as the estimator is fed them (first pass)
                           to DIR: events.csv, images/*.pgm, camchain.yaml; diekf_replay runs them without ROS
  --quiet                  no progress output on stderr
  --help                   this text
Exit status: 0 on success, 1 on a bad command line, unreadable input or a processing error.
)";
}

RunnerOptions parseRunnerOptions(int argc, const char* const* argv) {
  RunnerOptions o;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    std::string value;
    bool has_inline_value = false;
    if (arg.rfind("--", 0) == 0) {
      const std::size_t eq = arg.find('=');
      if (eq != std::string::npos && arg != "--set") {
        value = arg.substr(eq + 1);
        arg = arg.substr(0, eq);
        has_inline_value = true;
      }
    }
    auto next = [&]() -> std::string {
      if (has_inline_value) return value;
      if (i + 1 >= argc) throw UsageError(arg + " needs a value");
      return argv[++i];
    };
    if (arg == "--help" || arg == "-h") {
      o.help = true;
    } else if (arg == "--quiet") {
      o.quiet = true;
    } else if (arg == "--frames-csv") {
      o.frames_csv = true;
    } else if (arg == "--bag") {
      o.bag = next();
    } else if (arg == "--camchain") {
      o.camchain = next();
    } else if (arg == "--imu") {
      o.imu = next();
    } else if (arg == "--config") {
      o.config = next();
    } else if (arg == "--mode") {
      o.mode = next();
      if (o.mode != "iekf" && o.mode != "ekf" && o.mode != "lk") {
        throw UsageError("--mode expects iekf, ekf or lk, got '" + o.mode + "'");
      }
    } else if (arg == "--image-topic") {
      o.image_topic = next();
    } else if (arg == "--imu-topic") {
      o.imu_topic = next();
    } else if (arg == "--pose-topic") {
      o.pose_topic = next();
    } else if (arg == "--plane-topic") {
      o.plane_topic = next();
    } else if (arg == "--width") {
      o.width_px = toInt(arg, next());
      if (o.width_px < 8) throw UsageError("--width expects a width of at least 8 px");
    } else if (arg == "--set") {
      const std::string kv = next();
      if (kv.find('=') == std::string::npos || kv.front() == '=') {
        throw UsageError("--set expects KEY=VALUE, got '" + kv + "'");
      }
      o.sets.push_back(kv);
    } else if (arg == "--output") {
      o.output = next();
    } else if (arg == "--export-sequence") {
      o.export_sequence = next();
    } else if (arg == "--sequence") {
      o.sequence = next();
    } else if (arg == "--gt-velocity-window") {
      o.gt_velocity_window_s = toDouble(arg, next());
      if (o.gt_velocity_window_s < 0.0) throw UsageError("--gt-velocity-window must not be negative");
    } else if (arg == "--eval-start") {
      o.eval_start_delay_s = toDouble(arg, next());
      if (o.eval_start_delay_s < 0.0) throw UsageError("--eval-start must not be negative");
    } else if (arg == "--repeat") {
      const double n = toDouble(arg, next());
      if (!(n >= 1.0) || n != std::floor(n) || n > 1e6) throw UsageError("--repeat must be a positive integer");
      o.repeat = static_cast<int>(n);
    } else if (arg == "--max-duration") {
      o.max_duration_s = toDouble(arg, next());
      if (o.max_duration_s < 0.0) throw UsageError("--max-duration must not be negative");
    } else {
      throw UsageError("unknown argument '" + std::string(argv[i]) + "' (see --help)");
    }
  }
  if (o.help) return o;
  if (o.bag.empty()) throw UsageError("--bag is required (see --help)");
  if (o.camchain.empty()) throw UsageError("--camchain is required (see --help)");
  if (o.output.empty()) throw UsageError("--output is required (see --help)");
  return o;
}

std::string sequenceNameFromBag(const std::string& bag_path) {
  const std::filesystem::path p(bag_path);
  std::string stem = p.stem().string();
  if (stem == "sequence" || stem.empty()) {
    const std::string parent = std::filesystem::absolute(p).parent_path().filename().string();
    if (!parent.empty()) return parent;
  }
  return stem;
}

}  // namespace eval
}  // namespace diekf
