// diekf_replay: runs an exported sequence (diekf_bag_runner --export-sequence; docs/conventions.md section 7)
// through the estimator core without ROS: the same events in the same order as the bag runner, so the estimates
// are the runner's. Built by the catkin build and by the ROS-free core build of `make cross-check`
// (cross/CMakeLists.txt), where it runs on ARM under emulation. Usage: diekf_replay --help.

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/estimator.h"
#include "diekf/eval/io.h"
#include "diekf/eval/param_overlay.h"
#include "diekf/eval/sequence_files.h"
#include "diekf/param_source.h"
#include "diekf/imu_rate.h"
#include "diekf/params.h"
#include "diekf/photometric_update.h"
#include "estimate_row.h"

namespace {

namespace fs = std::filesystem;
constexpr const char* kProgram = "diekf_replay";

const char* usage() {
  return R"(Usage: diekf_replay --sequence DIR [options]

Runs an exported sequence (diekf_bag_runner --export-sequence DIR) through the estimator core, without ROS, in
the runner's order, on one thread. Prints the SIMD instruction set of the photometric sweep.

  --sequence DIR      the exported sequence (events.csv, camchain.yaml, images/)
  --output DIR        write DIR/estimates.csv (the runner's format) and DIR/states.csv (every state component,
                      17 significant digits); no output files without it
  --config FILE       estimator YAML (default: built-in defaults, equal to the package's config/estimator.yaml)
  --imu FILE          Kalibr IMU YAML (noise densities); overrides the config's IMU keys, as in the runner
  --mode iekf|ekf|lk  update mode (default: the config's)
  --width PX          working image width, px
  --set KEY=VALUE     override one estimator parameter (repeatable; applied after the config)
  --max-images N      stop before the (N+1)-th image (default: all)
  --preload           read every event and image first, then process (instruction counts of the processing)
  --load-only         with --preload: stop after reading (the reading's own cost)
  --quiet             only errors on stderr
  --help              this text
)";
}

struct Options {
  std::string sequence, output, config, imu, mode;
  int width_px = 0;
  std::vector<std::string> sets;
  long max_images = -1;
  bool preload = false, load_only = false, quiet = false, help = false;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    auto integer = [&](long lo) {
      const std::string v = value();
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || n < lo) throw std::invalid_argument(a + " expects an integer >= " +
                                                                           std::to_string(lo) + ", got '" + v + "'");
      return n;
    };
    if (a == "--help" || a == "-h") {
      o.help = true;
    } else if (a == "--sequence") {
      o.sequence = value();
    } else if (a == "--output") {
      o.output = value();
    } else if (a == "--config") {
      o.config = value();
    } else if (a == "--imu") {
      o.imu = value();
    } else if (a == "--mode") {
      o.mode = value();
    } else if (a == "--width") {
      o.width_px = static_cast<int>(integer(8));
    } else if (a == "--set") {
      o.sets.push_back(value());
    } else if (a == "--max-images") {
      o.max_images = integer(0);
    } else if (a == "--preload") {
      o.preload = true;
    } else if (a == "--load-only") {
      o.load_only = true;
    } else if (a == "--quiet") {
      o.quiet = true;
    } else {
      throw std::invalid_argument("unknown argument '" + a + "' (see --help)");
    }
  }
  if (!o.help && o.sequence.empty()) throw std::invalid_argument("--sequence is required (see --help)");
  if (o.load_only && !o.preload) throw std::invalid_argument("--load-only needs --preload");
  return o;
}

/// The runner's order of parameter sources: config file, IMU file, --set, then --mode and --width.
diekf::EstimatorParams loadParams(const Options& o) {
  diekf::EstimatorParams params;
  if (!o.config.empty()) diekf::loadEstimatorParams(diekf::YamlParamSource(o.config), &params);
  if (!o.imu.empty()) diekf::loadKalibrImuYaml(o.imu, &params.imu);
  diekf::eval::applyCommandLine(o.sets, o.mode, o.width_px, &params);
  return params;
}

struct Event {
  diekf::eval::SequenceEvent e;
  cv::Mat image;  // kImage
};

const char* kStatesHeader =
    "t,applied,passes,status,alpha,vartheta_x,vartheta_y,vartheta_z,mu_x,mu_y,mu_z,g_x,g_y,g_z,ba_x,ba_y,ba_z,"
    "bw_x,bw_y,bw_z,d,h,vx,vy,vz,sigma_d,photometric_rms,nis";

void writeStateRow(std::FILE* f, const diekf::FrameResult& r) {
  const diekf::State& x = r.state;
  const diekf::Vec3 v = r.velocity_mps();
  std::fprintf(f, "%.17g,%d,%d,%s", r.t_s, r.update_applied ? 1 : 0, r.passes, diekf::toString(r.status));
  const double values[] = {x.alpha,         x.vartheta.x(),  x.vartheta.y(),  x.vartheta.z(),  x.mu.vector().x(),
                           x.mu.vector().y(), x.mu.vector().z(), x.g.vector().x(), x.g.vector().y(), x.g.vector().z(),
                           x.b_a.x(),       x.b_a.y(),       x.b_a.z(),       x.b_w.x(),       x.b_w.y(),
                           x.b_w.z(),       r.distance_m(),  r.height_m(),    v.x(),           v.y(),
                           v.z(),           r.sigma_distance_m(), r.photometric_rms, r.nis};
  for (double value : values) std::fprintf(f, ",%.17g", value);
  std::fputc('\n', f);
}

int run(const Options& o) {
  cv::setNumThreads(1);  // one core, as on the robot's estimator thread (and exact instruction counts)
  diekf::eval::SequenceReader reader(o.sequence);
  const diekf::CameraModel camera = diekf::CameraModel::fromKalibrYaml(reader.camchainPath());
  diekf::EstimatorParams params = loadParams(o);
  {
    // The IMU rate from the first second of stamps, decided as diekf_bag_runner decides it.
    diekf::eval::SequenceReader rate_reader(o.sequence);
    diekf::RateMeter meter(1.0, 20);
    diekf::eval::SequenceEvent e;
    while (rate_reader.next(&e)) {
      if (e.kind == diekf::eval::SequenceEvent::Kind::kImu && meter.add(e.imu.t_s)) break;
    }
    std::string summary;
    params.imu = diekf::imuPreprocessingForRecording(params.imu, meter.rateHz(), 0.05, &summary);
    if (!o.quiet) std::fprintf(stderr, "%s: %s\n", kProgram, summary.c_str());
  }
  if (!o.quiet) {
    std::fprintf(stderr, "%s: photometric sweep SIMD: %s\n", kProgram, diekf::photometricSweepSimd());
    std::fprintf(stderr, "%s: %s: mode %s, working width %d px, config %s\n", kProgram, o.sequence.c_str(),
                 diekf::toString(params.mode), params.mode == diekf::UpdateMode::kFeature
                                                  ? params.feature.working_width_px
                                                  : params.preprocess.working_width_px,
                 o.config.empty() ? "(built-in defaults)" : o.config.c_str());
  }

  // The next event with its image read; false at the end or at --max-images.
  long images_read = 0;
  auto next_event = [&](Event* ev) {
    if (!reader.next(&ev->e)) return false;
    ev->image = cv::Mat();
    if (ev->e.kind == diekf::eval::SequenceEvent::Kind::kImage) {
      if (o.max_images >= 0 && images_read >= o.max_images) return false;
      ev->image = diekf::eval::readPgm(ev->e.image_path);
      ++images_read;
    }
    return true;
  };
  // --preload: every event (up to --max-images) in memory first.
  std::vector<Event> preloaded;
  if (o.preload) {
    Event ev;
    while (next_event(&ev)) preloaded.push_back(ev);
    if (o.load_only) {
      if (!o.quiet) std::fprintf(stderr, "%s: read %zu events, %ld images\n", kProgram, preloaded.size(), images_read);
      return 0;
    }
  }

  std::unique_ptr<diekf::eval::EstimatesCsvWriter> csv;
  std::FILE* states = nullptr;
  if (!o.output.empty()) {
    std::error_code ec;
    fs::create_directories(o.output, ec);
    csv = std::make_unique<diekf::eval::EstimatesCsvWriter>((fs::path(o.output) / "estimates.csv").string());
    const std::string states_path = (fs::path(o.output) / "states.csv").string();
    states = std::fopen(states_path.c_str(), "w");
    if (states == nullptr) throw std::runtime_error("cannot write '" + states_path + "'");
    std::fprintf(states, "%s\n", kStatesHeader);
  }

  diekf::Estimator estimator(camera, params);
  diekf::FrameResult result;
  long estimates = 0, images = 0;
  auto process = [&](const diekf::eval::SequenceEvent& e, const cv::Mat& image) {
    if (e.kind == diekf::eval::SequenceEvent::Kind::kImu) {
      estimator.addImu(e.imu);
    } else {
      estimator.addImage(e.image_t_s, image);
      ++images;
    }
    while (estimator.popResult(&result)) {
      ++estimates;
      if (csv) csv->write(diekf::tools::toEstimateRow(result));
      if (states != nullptr) writeStateRow(states, result);
    }
    if (!o.quiet) {
      const std::string warning = estimator.takeWarning();
      if (!warning.empty()) std::fprintf(stderr, "%s: warning: %s\n", kProgram, warning.c_str());
    }
  };
  if (o.preload) {
    for (const Event& ev : preloaded) process(ev.e, ev.image);
  } else {
    Event ev;
    while (next_event(&ev)) process(ev.e, ev.image);
  }
  if (csv) csv->close();
  if (states != nullptr && std::fclose(states) != 0) throw std::runtime_error("cannot write states.csv");
  if (!o.quiet) std::fprintf(stderr, "%s: %ld images, %ld estimates\n", kProgram, images, estimates);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parse(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", kProgram, e.what());
    return 1;
  }
  if (o.help) {
    std::cout << usage();
    return 0;
  }
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", kProgram, e.what());
    return 1;
  }
}
