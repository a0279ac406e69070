// diekf_bag_runner: runs a recorded bag through the estimator offline, serially and deterministically, and
// writes estimates.csv (+ groundtruth.csv and evaluation.json when the bag holds ground truth).
// Usage: diekf_bag_runner --help. Interface: docs/conventions.md sections 4-6.

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <opencv2/imgproc.hpp>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/image_encodings.h>
#include <shape_msgs/Plane.h>
#include <yaml-cpp/yaml.h>

#include "diekf/camera_model.h"
#include "diekf/estimator.h"
#include "diekf/eval/ground_truth.h"
#include "diekf/grey_image.h"
#include "diekf/imu_rate.h"
#include "diekf/eval/io.h"
#include "diekf/eval/metrics.h"
#include "diekf/eval/param_overlay.h"
#include "diekf/eval/runner_options.h"
#include "diekf/eval/sequence_files.h"
#include "diekf/param_source.h"
#include "diekf/params.h"
#include "diekf/photometric_update.h"
#include "estimate_row.h"

namespace {

namespace fs = std::filesystem;
using diekf::eval::RunnerOptions;

constexpr const char* kProgram = "diekf_bag_runner";
constexpr const char* kDefaultImageTopic = "/mynteye/left/image_raw";
constexpr const char* kDefaultImuTopic = "/mynteye/imu/data_raw";
// IMU rate measured over this many seconds of stamps; within kImuRateTolerance (relative) of imu/input_rate_hz the
// configuration is kept as it is (diekf::imuPreprocessingForRecording).
constexpr double kImuRateWindowS = 1.0;
constexpr double kImuRateTolerance = 0.05;

/// A field of /proc/self/status in kB (VmRSS: resident set, VmHWM: its peak); -1 where unavailable.
long procStatusKb(const std::string& key) {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.compare(0, key.size(), key) == 0) return std::atol(line.c_str() + key.size());
  }
  return -1;
}

/// A failure with a one-line reason (exit status 1).
class RunError : public std::runtime_error {
 public:
  explicit RunError(const std::string& what) : std::runtime_error(what) {}
};

void requireReadable(const std::string& what, const std::string& path) {
  std::ifstream f(path);
  if (!f) throw RunError("cannot read " + what + " '" + path + "'");
}

/// The package's default estimator config, located from the build (never a fixed path in the sources): in an
/// install space, share/diekf/config next to this executable's lib/diekf; in a devel space, the source tree's.
std::string defaultConfigPath() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const fs::path installed = self.parent_path().parent_path().parent_path() / "share" / "diekf" / "config" /
                               "estimator.yaml";
    if (fs::is_regular_file(installed, ec)) return installed.string();
  }
#ifdef DIEKF_PACKAGE_DIR
  const fs::path p = fs::path(DIEKF_PACKAGE_DIR) / "config" / "estimator.yaml";
  if (fs::is_regular_file(p, ec)) return p.string();
#endif
  return std::string();
}

/// `rostopic` of a Kalibr IMU YAML (imu0 or top level); empty when absent or unreadable.
std::string kalibrImuTopic(const std::string& path) {
  try {
    const YAML::Node root = YAML::LoadFile(path);
    const YAML::Node node = root["imu0"] ? root["imu0"] : root;
    if (node["rostopic"]) return node["rostopic"].as<std::string>();
  } catch (const std::exception&) {
  }
  return std::string();
}

struct BagTopics {
  std::map<std::string, std::string> type_of;  ///< topic -> datatype
  std::string describe() const {
    if (type_of.empty()) return "(none)";
    std::string s;
    for (const auto& kv : type_of) s += (s.empty() ? "" : ", ") + kv.first + " [" + kv.second + "]";
    return s;
  }
  bool has(const std::string& topic, const std::string& type) const {
    const auto it = type_of.find(topic);
    return it != type_of.end() && it->second == type;
  }
};

BagTopics listTopics(const rosbag::Bag& bag) {
  BagTopics topics;
  rosbag::View view(bag);
  for (const rosbag::ConnectionInfo* c : view.getConnections()) topics.type_of[c->topic] = c->datatype;
  return topics;
}

/// The topic to read: the explicit one; else the calibration file's, then the MYNT EYE default, then the bag's only
/// topic of that type. Throws naming what was looked for and listing the bag's topics when none fits.
std::string chooseTopic(const std::string& explicit_topic, const std::string& calibration_topic,
                        const char* fallback, const char* type, const char* what, const BagTopics& topics,
                        const std::string& bag_path, bool quiet) {
  std::vector<std::string> tried;
  if (!explicit_topic.empty()) {
    if (topics.has(explicit_topic, type)) return explicit_topic;
    tried.push_back(explicit_topic);
  } else {
    for (const std::string& candidate : {calibration_topic, std::string(fallback)}) {
      if (candidate.empty()) continue;
      if (topics.has(candidate, type)) return candidate;
      tried.push_back(candidate);
    }
    std::vector<std::string> of_type;
    for (const auto& kv : topics.type_of) {
      if (kv.second == type) of_type.push_back(kv.first);
    }
    if (of_type.size() == 1) {
      if (!quiet) std::cerr << kProgram << ": using the bag's only " << type << " topic " << of_type[0] << "\n";
      return of_type[0];
    }
  }
  std::string looked;
  for (const std::string& t : tried) looked += (looked.empty() ? "'" : " or '") + t + "'";
  throw RunError("bag '" + bag_path + "' has no " + what + " topic " + looked + " of type " + type +
                 "; its topics: " + topics.describe());
}

double stampOf(const ros::Time& header_stamp, const ros::Time& record_time) {
  return header_stamp.isZero() ? record_time.toSec() : header_stamp.toSec();
}

/// The image's pixels for the estimator (docs/conventions.md section 2): the message's own buffer in any supported
/// encoding (no copy; Estimator::addImage resamples it at once, converting colour to grey with diekf::toGrey8); colour in RGB order is converted
/// here, the estimator taking colour as BGR.
cv::Mat imagePixels(const sensor_msgs::ImageConstPtr& msg) {
  int type = -1;
  diekf::ChannelOrder order = diekf::ChannelOrder::kBgr;
  std::string error;
  if (!diekf::describeImageBuffer(msg->encoding, msg->width, msg->height, msg->step, msg->is_bigendian != 0,
                                  msg->data.size(), &type, &order, &error)) {
    throw RunError("cannot decode image: " + error);
  }
  cv_bridge::CvImageConstPtr cv;
  try {
    cv = cv_bridge::toCvShare(msg);
  } catch (const cv_bridge::Exception& e) {
    throw RunError(std::string("cannot decode image: ") + e.what());
  }
  if (order == diekf::ChannelOrder::kRgb && cv->image.channels() > 1) {
    cv::Mat grey;
    diekf::toGrey8(cv->image, order, &grey);
    return grey;
  }
  return cv->image;  // shares the message's buffer: the caller keeps the message
}

diekf::EstimatorParams loadParams(const RunnerOptions& o, std::string* config_used) {
  diekf::EstimatorParams params;
  *config_used = o.config.empty() ? defaultConfigPath() : o.config;
  if (!config_used->empty()) {
    requireReadable("config", *config_used);
    const diekf::YamlParamSource config(*config_used);
    diekf::loadEstimatorParams(config, &params);
  }
  if (!o.imu.empty()) {
    requireReadable("IMU calibration", o.imu);
    diekf::loadKalibrImuYaml(o.imu, &params.imu);
  }
  diekf::eval::applyCommandLine(o.sets, o.mode, o.width_px, &params);
  return params;
}

int run(const RunnerOptions& o) {
  const auto wall_start = std::chrono::steady_clock::now();
  requireReadable("bag", o.bag);
  requireReadable("camchain", o.camchain);
  const diekf::CameraModel camera = diekf::CameraModel::fromKalibrYaml(o.camchain);
  std::string config_used;
  diekf::EstimatorParams params = loadParams(o, &config_used);

  rosbag::Bag bag;
  try {
    bag.open(o.bag, rosbag::bagmode::Read);
  } catch (const rosbag::BagException& e) {
    throw RunError("cannot read bag '" + o.bag + "': " + e.what());
  }
  const BagTopics topics = listTopics(bag);
  const std::string image_topic = chooseTopic(o.image_topic, camera.rostopic, kDefaultImageTopic,
                                              "sensor_msgs/Image", "image", topics, o.bag, o.quiet);
  const std::string imu_topic = chooseTopic(o.imu_topic, o.imu.empty() ? std::string() : kalibrImuTopic(o.imu),
                                            kDefaultImuTopic, "sensor_msgs/Imu", "IMU", topics, o.bag, o.quiet);
  const bool has_poses = topics.has(o.pose_topic, "geometry_msgs/PoseStamped");
  const bool has_plane = topics.has(o.plane_topic, "shape_msgs/Plane");

  // Ground truth (small): read it completely first.
  std::optional<diekf::eval::GroundTruth> truth;
  if (has_poses) {
    std::vector<diekf::eval::PoseSample> poses;
    diekf::eval::GroundPlane plane;  // level ground unless the bag says otherwise
    bool plane_seen = false;
    std::vector<std::string> gt_topics{o.pose_topic};
    if (has_plane) gt_topics.push_back(o.plane_topic);
    rosbag::View gt_view(bag, rosbag::TopicQuery(gt_topics));
    for (const rosbag::MessageInstance& m : gt_view) {
      if (m.getTopic() == o.pose_topic) {
        const auto pose = m.instantiate<geometry_msgs::PoseStamped>();
        if (!pose) continue;
        diekf::eval::PoseSample s;
        s.t_s = stampOf(pose->header.stamp, m.getTime());
        s.p_WI_m = Eigen::Vector3d(pose->pose.position.x, pose->pose.position.y, pose->pose.position.z);
        s.q_WI = Eigen::Quaterniond(pose->pose.orientation.w, pose->pose.orientation.x, pose->pose.orientation.y,
                                    pose->pose.orientation.z);
        poses.push_back(s);
      } else if (!plane_seen) {
        const auto pl = m.instantiate<shape_msgs::Plane>();
        if (!pl) continue;
        try {
          plane = diekf::eval::GroundPlane::fromCoefficients(pl->coef[0], pl->coef[1], pl->coef[2], pl->coef[3]);
        } catch (const std::invalid_argument& e) {
          throw RunError(o.plane_topic + ": " + e.what());
        }
        plane_seen = true;
      }
    }
    diekf::eval::GroundTruthOptions gt_options;
    gt_options.velocity_window_s = o.gt_velocity_window_s;
    try {
      truth.emplace(std::move(poses), plane, camera.T_cam_imu, gt_options);
    } catch (const std::invalid_argument& e) {
      throw RunError(o.pose_topic + ": " + e.what());
    }
  }

  std::error_code ec;
  fs::create_directories(o.output, ec);
  if (!fs::is_directory(o.output)) throw RunError("cannot create output directory '" + o.output + "'");
  const fs::path out_dir(o.output);

  if (!o.quiet) {
    std::cerr << kProgram << ": " << o.bag << ": images " << image_topic << ", IMU " << imu_topic
              << (truth ? ", ground truth " + o.pose_topic + (has_plane ? " + " + o.plane_topic : "") : "")
              << "; mode " << diekf::toString(params.mode) << ", config "
              << (config_used.empty() ? std::string("(built-in defaults)") : config_used) << "\n";
  }

  // The IMU's rate from its stamps (the first second), as the nodelet measures it at start-up: a recording at
  // another rate than imu/input_rate_hz gets the low-pass and decimation designed for its rate.
  {
    diekf::RateMeter meter(kImuRateWindowS, 20);
    rosbag::View imu_view(bag, rosbag::TopicQuery(imu_topic));
    for (const rosbag::MessageInstance& m : imu_view) {
      const auto imu = m.instantiate<sensor_msgs::Imu>();
      if (imu && meter.add(stampOf(imu->header.stamp, m.getTime()))) break;
    }
    std::string summary;
    try {
      params.imu = diekf::imuPreprocessingForRecording(params.imu, meter.rateHz(), kImuRateTolerance, &summary);
    } catch (const std::invalid_argument& e) {
      throw RunError(imu_topic + ": " + e.what());
    }
    if (!o.quiet) std::cerr << kProgram << ": " << summary << "\n";
  }
  if (!o.quiet) std::cerr << kProgram << ": photometric sweep SIMD: " << diekf::photometricSweepSimd() << "\n";
  diekf::Estimator estimator(camera, params);
  diekf::eval::EstimatesCsvWriter csv((out_dir / "estimates.csv").string());
  // --export-sequence: the estimator's input of the first pass, for diekf_replay (docs/conventions.md section 7).
  std::unique_ptr<diekf::eval::SequenceWriter> exported;
  if (!o.export_sequence.empty()) {
    exported = std::make_unique<diekf::eval::SequenceWriter>(o.export_sequence, o.camchain);
  }
  // --frames-csv: per-image update diagnostics (not part of the estimates format of docs/conventions.md section 4).
  std::ofstream frames;
  if (o.frames_csv) {
    frames.open(out_dir / "frames.csv");
    if (!frames) throw RunError("cannot write " + (out_dir / "frames.csv").string());
    frames << "t,applied,passes,photometric_rms,valid_ratio,nis,noise_sigma,noise_correlation,noise_floor_sigma,nis_scale,gate_inflation,outlier_fraction,time_offset_ms,sigma_time_offset_ms,readout_ms,sigma_readout_ms,focal_scale_pct,sigma_focal_scale_pct,"
              "fixed_pattern_active,fixed_pattern_fraction,fixed_pattern_contrast_share,vignetting_corner,brightness_gain,brightness_offset,relief_pct,"
              "dot_removal_px,dot_fill_pct,dot_gain_pct,projector_dot_share,row_banding_pct,row_gains,light_change,stamp_correction_ms,stamp_jitter_ms,imu_notch1_hz,imu_notch2_hz,status,message\n";
    frames.precision(12);
  }
  std::vector<diekf::eval::EstimateRow> rows;
  bool keep_rows = true;       // --repeat: only the first pass is kept for the evaluation
  std::size_t soak_rows = 0;   // estimates of the later passes (written to the CSV only)
  auto drain = [&]() {
    diekf::FrameResult result;
    while (estimator.popResult(&result)) {
      if (frames.is_open()) {
        std::string msg = result.message;
        for (char& ch : msg)
          if (ch == ',' || ch == '\n' || ch == '"') ch = ';';
        frames << result.t_s << ',' << (result.update_applied ? 1 : 0) << ',' << result.passes << ','
               << result.photometric_rms << ',' << result.valid_ratio << ',' << result.nis << ','
               << result.noise_sigma << ',' << result.noise_correlation << ',' << result.noise_floor_sigma << ','
               << result.nis_scale << ',' << result.gate_inflation << ','
               << result.outlier_fraction << ',' << 1e3 * result.state.t_d_s << ','
               << 1e3 * std::sqrt(std::max(0.0, result.covariance(diekf::ErrIdx::kTd, diekf::ErrIdx::kTd))) << ','
               << 1e3 * result.state.readout_s << ','
               << 1e3 * std::sqrt(std::max(0.0, result.covariance(diekf::ErrIdx::kRo, diekf::ErrIdx::kRo))) << ','
               << 1e2 * result.state.focal_scale << ','
               << 1e2 * std::sqrt(std::max(0.0, result.covariance(diekf::ErrIdx::kFs, diekf::ErrIdx::kFs))) << ','
               << (result.fixed_pattern_active ? 1 : 0) << ',' << result.fixed_pattern_fraction << ','
               << result.fixed_pattern_contrast_share << ',' << result.vignetting_corner << ','
               << result.brightness_gain << ','
               << result.brightness_offset << ',' << 1e2 * result.relief_sigma << ','
               << result.dot_removal_px << ',' << result.dot_fill_pct << ',' << result.dot_gain_pct << ','
               << result.projector_dot_share << ','
               << 1e2 * result.row_banding << ',' << (result.row_gains ? 1 : 0) << ','
               << (result.light_change ? 1 : 0) << ',' << 1e3 * result.stamp_correction_s << ','
               << 1e3 * result.stamp_jitter_s << ',' << result.imu_notch_hz[0] << ',' << result.imu_notch_hz[1] << ','
               << diekf::toString(result.status) << ',' << msg << '\n';
      }
      if (keep_rows) {
        rows.push_back(diekf::tools::toEstimateRow(result));
        csv.write(rows.back());
      } else {
        csv.write(diekf::tools::toEstimateRow(result));
        ++soak_rows;
      }
    }
    if (!o.quiet) {
      const std::string warning = estimator.takeWarning();
      if (!warning.empty()) std::cerr << kProgram << ": warning: " << warning << "\n";
    }
  };

  rosbag::View view(bag, rosbag::TopicQuery(std::vector<std::string>{image_topic, imu_topic}));
  const double bag_start_s = view.getBeginTime().toSec();
  const double bag_span_s = std::max(0.0, view.getEndTime().toSec() - bag_start_s);
  const double limit_s = o.max_duration_s > 0.0 ? std::min(o.max_duration_s, bag_span_s) : bag_span_s;
  auto last_progress = std::chrono::steady_clock::now();
  std::size_t images = 0;
  for (int pass = 0; pass < o.repeat; ++pass) {
  // --repeat: later passes shift every stamp so that sensor time runs on (one IMU period after the end).
  const double shift_s = pass * (bag_span_s + 0.002);
  keep_rows = pass == 0;
  for (const rosbag::MessageInstance& m : view) {
    const double rel_s = m.getTime().toSec() - bag_start_s;
    if (o.max_duration_s > 0.0 && rel_s > o.max_duration_s) break;
    if (m.getTopic() == imu_topic) {
      const auto imu = m.instantiate<sensor_msgs::Imu>();
      if (!imu) continue;
      diekf::ImuSample s;
      s.t_s = stampOf(imu->header.stamp, m.getTime()) + shift_s;
      s.accel_mps2 = diekf::Vec3(imu->linear_acceleration.x, imu->linear_acceleration.y, imu->linear_acceleration.z);
      s.gyro_radps = diekf::Vec3(imu->angular_velocity.x, imu->angular_velocity.y, imu->angular_velocity.z);
      if (exported && pass == 0) exported->addImu(s);
      estimator.addImu(s);
    } else {
      const auto img = m.instantiate<sensor_msgs::Image>();
      if (!img) continue;
      const double t_s = stampOf(img->header.stamp, m.getTime()) + shift_s;
      const cv::Mat pixels = imagePixels(img);
      if (exported && pass == 0) {
        // The exported sequence holds the 8-bit grey image the estimator works on (its one grey conversion).
        cv::Mat grey;
        diekf::toGrey8(pixels, diekf::ChannelOrder::kBgr, &grey);
        exported->addImage(t_s, grey);
      }
      estimator.addImage(t_s, pixels);
      ++images;
    }
    drain();
    if (!o.quiet) {
      const auto now = std::chrono::steady_clock::now();
      if (std::chrono::duration<double>(now - last_progress).count() >= 2.0) {
        last_progress = now;
        const double wall_s = std::chrono::duration<double>(now - wall_start).count();
        std::fprintf(stderr, "%s: %6.1f / %.1f s of data, %zu images, %zu estimates, %.2fx real time\n", kProgram,
                     rel_s, limit_s, images, rows.size() + soak_rows, wall_s > 0.0 ? rel_s / wall_s : 0.0);
      }
    }
  }
  if (o.repeat > 1) {
    drain();
    std::fprintf(stderr, "%s: pass %d/%d done: %zu estimates, VmRSS %ld kB, VmHWM %ld kB\n", kProgram, pass + 1,
                 o.repeat, rows.size() + soak_rows, procStatusKb("VmRSS:"), procStatusKb("VmHWM:"));
  }
  }
  drain();
  csv.close();
  if (exported) exported->close();
  bag.close();
  if (rows.empty()) {
    throw RunError("no estimates: " + std::to_string(images) + " images on " + image_topic +
                   " produced no result (does the IMU cover the image stamps?)");
  }

  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  if (!truth) {
    if (!o.quiet) {
      std::cerr << kProgram << ": " << rows.size() << " estimates in " << wall_s << " s wall; no " << o.pose_topic
                << " in the bag, so no evaluation\n";
    }
    return 0;
  }

  std::vector<std::optional<diekf::eval::TruthSample>> matched(rows.size());
  std::vector<diekf::eval::TruthSample> truth_rows;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    diekf::eval::TruthSample t;
    if (truth->at(rows[i].t_s, &t)) {
      matched[i] = t;
      truth_rows.push_back(t);
    }
  }
  diekf::eval::writeGroundTruthCsv((out_dir / "groundtruth.csv").string(), truth_rows);

  diekf::eval::EvaluationOptions ev_options;
  ev_options.start_delay_s = o.eval_start_delay_s;
  diekf::eval::Evaluation ev = diekf::eval::evaluate(rows, matched, ev_options);
  ev.sequence = o.sequence.empty() ? diekf::eval::sequenceNameFromBag(o.bag) : o.sequence;
  ev.wall_time_s = wall_s;
  ev.realtime_factor = ev.duration_s > 0.0 ? wall_s / ev.duration_s : std::nan("");
  diekf::eval::writeEvaluationJson((out_dir / "evaluation.json").string(), ev);
  std::cout << diekf::eval::evaluationSummary(ev) << std::flush;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  RunnerOptions options;
  try {
    options = diekf::eval::parseRunnerOptions(argc, argv);
  } catch (const diekf::eval::UsageError& e) {
    std::cerr << kProgram << ": " << e.what() << "\n";
    return 1;
  }
  if (options.help) {
    std::cout << diekf::eval::runnerUsage();
    return 0;
  }
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::string reason = e.what();
    for (char& c : reason) {
      if (c == '\n') c = ' ';
    }
    std::cerr << kProgram << ": " << reason << "\n";
    return 1;
  }
}
