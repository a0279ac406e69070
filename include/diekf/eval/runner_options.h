// Command line of diekf_bag_runner (docs/conventions.md section 6), parsed without ROS so that it is unit-testable.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace diekf {
namespace eval {

struct RunnerOptions {
  std::string bag;                        ///< input bag
  std::string camchain;                   ///< Kalibr camchain YAML
  std::string imu;                        ///< Kalibr IMU YAML (optional)
  std::string config;                     ///< estimator YAML (empty: the package's config/estimator.yaml if any)
  std::string mode;                       ///< iekf | ekf | lk (empty: the config's choice)
  std::string image_topic;                ///< empty: camchain rostopic if in the bag, else the MYNT EYE default
  std::string imu_topic;                  ///< empty: IMU YAML rostopic if in the bag, else the MYNT EYE default
  std::string pose_topic = "/mocap/pose";
  std::string plane_topic = "/ground_truth/plane";
  int width_px = 0;                       ///< working width override, px (0: from the config)
  std::vector<std::string> sets;          ///< "key=value" tuning overrides, applied last
  std::string output;                     ///< output directory (created)
  std::string sequence;                   ///< name in evaluation.json (empty: from the bag's file name)
  double gt_velocity_window_s = 0.0;      ///< base of the true velocity's central difference, s (0: adjacent)
  double eval_start_delay_s = 3.0;        ///< evaluation starts this long after the first update, s
  double max_duration_s = 0.0;            ///< stop after this much sensor time, s (0: whole bag)
  int repeat = 1;                         ///< soak test: play the bag this many times back to back, stamps shifted
  bool quiet = false;                     ///< no progress on stderr
  bool frames_csv = false;                ///< also write output/frames.csv (per-image update diagnostics)
  std::string export_sequence;            ///< also write what the estimator is fed to this folder (diekf_replay)
  bool help = false;
};

/// Thrown on a bad command line; what() is the one-line reason.
class UsageError : public std::runtime_error {
 public:
  explicit UsageError(const std::string& what) : std::runtime_error(what) {}
};

/// Parses argv (argv[0] is skipped). Throws UsageError on unknown options, missing values, bad numbers, or missing
/// required options (--bag, --camchain, --output) unless --help is given.
RunnerOptions parseRunnerOptions(int argc, const char* const* argv);

/// The usage text printed by --help.
std::string runnerUsage();

/// Name for evaluation.json from a bag path: the file stem, or the parent folder's name when the stem is the
/// simulator's generic "sequence".
std::string sequenceNameFromBag(const std::string& bag_path);

}  // namespace eval
}  // namespace diekf
