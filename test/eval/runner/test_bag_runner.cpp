// End-to-end test of diekf_bag_runner: writes a few seconds of a synthetic hover-and-drift flight (IMU, images of
// a textured floor, mocap poses, plane) with the rosbag API, runs the runner binary on it and checks its outputs
// against docs/conventions.md sections 4-6; plus the error paths.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <shape_msgs/Plane.h>
#include <std_msgs/String.h>
#include <yaml-cpp/yaml.h>

#include "diekf/eval/io.h"

namespace {

namespace fs = std::filesystem;

// Synthetic camera: 160x100 px pinhole, no distortion, looking down from a z-up IMU (x_C = x_I, y_C = -y_I,
// z_C = -z_I), both at the same point.
constexpr int kWidthPx = 160;
constexpr int kHeightPx = 100;
constexpr double kFocalPx = 120.0;
constexpr double kCxPx = 80.0;
constexpr double kCyPx = 50.0;
constexpr double kHeightM = 1.0;          // flight height over the level floor, m
constexpr double kSpeedMps = 0.2;         // constant drift along world x, m/s
constexpr double kT0 = 1000.0;            // first stamp, s
constexpr const char* kImageTopic = "/cam0/image_raw";  // named in the camchain, not the MYNT EYE default
constexpr const char* kImuTopic = "/mynteye/imu/data_raw";

struct Dirs {
  fs::path root;
  Dirs() {
    root = fs::temp_directory_path() /
           ("diekf_runner_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root);
    fs::create_directories(root);
  }
  ~Dirs() {
    std::error_code ec;
    fs::remove_all(root, ec);
  }
};

std::string writeCamchain(const fs::path& dir) {
  const fs::path p = dir / "camchain.yaml";
  std::ofstream f(p);
  f << "cam0:\n"
    << "  camera_model: pinhole\n"
    << "  intrinsics: [" << kFocalPx << ", " << kFocalPx << ", " << kCxPx << ", " << kCyPx << "]\n"
    << "  distortion_model: radtan\n"
    << "  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n"
    << "  resolution: [" << kWidthPx << ", " << kHeightPx << "]\n"
    << "  T_cam_imu:\n"
    << "  - [1.0, 0.0, 0.0, 0.0]\n"
    << "  - [0.0, -1.0, 0.0, 0.0]\n"
    << "  - [0.0, 0.0, -1.0, 0.0]\n"
    << "  - [0.0, 0.0, 0.0, 1.0]\n"
    << "  timeshift_cam_imu: 0.0\n"
    << "  rostopic: " << kImageTopic << "\n";
  return p.string();
}

/// Smooth floor texture, intensity 0..255 at world (x, y) in metres.
double floorTexture(double x, double y) {
  return 128.0 + 50.0 * std::sin(9.0 * x + 1.0) * std::cos(7.0 * y) + 35.0 * std::sin(17.0 * x - 13.0 * y) +
         20.0 * std::cos(31.0 * y + 5.0 * x);
}

sensor_msgs::Image renderImage(double t_s, int seq) {
  sensor_msgs::Image img;
  img.header.stamp = ros::Time(t_s);
  img.header.seq = static_cast<uint32_t>(seq);
  img.header.frame_id = "cam0";
  img.width = kWidthPx;
  img.height = kHeightPx;
  img.encoding = "mono8";
  img.step = kWidthPx;
  img.data.resize(static_cast<std::size_t>(kWidthPx * kHeightPx));
  const double cam_x = kSpeedMps * (t_s - kT0);
  for (int v = 0; v < kHeightPx; ++v) {
    for (int u = 0; u < kWidthPx; ++u) {
      // Ray (xn, yn, 1) in C hits the floor at depth kHeightM; x_W = x_C, y_W = -y_C.
      const double xw = cam_x + kHeightM * (u - kCxPx) / kFocalPx;
      const double yw = -kHeightM * (v - kCyPx) / kFocalPx;
      const double value = std::min(255.0, std::max(0.0, floorTexture(xw, yw)));
      img.data[static_cast<std::size_t>(v * kWidthPx + u)] = static_cast<uint8_t>(std::lround(value));
    }
  }
  return img;
}

/// Writes `duration_s` of the synthetic flight; returns the number of images written. The IMU runs at
/// 1000 / imu_every_ms Hz (500 Hz by default).
int writeFlightBag(const std::string& path, double duration_s, bool with_ground_truth, int imu_every_ms = 2) {
  rosbag::Bag bag;
  bag.open(path, rosbag::bagmode::Write);
  if (with_ground_truth) {
    shape_msgs::Plane plane;
    plane.coef = {0.0, 0.0, 1.0, 0.0};
    bag.write("/ground_truth/plane", ros::Time(kT0), plane);
  }
  // One common 1 kHz tick drives IMU (500 Hz by default), poses (100 Hz) and images (30 Hz, every 33-34 ticks).
  int images = 0;
  const int ticks = static_cast<int>(std::lround(duration_s * 1000.0));
  int next_image_tick = 20;  // first image 20 ms in, so IMU covers it
  for (int k = 0; k <= ticks; ++k) {
    const double t = kT0 + k * 1e-3;
    const ros::Time stamp(t);
    if (k % imu_every_ms == 0) {
      sensor_msgs::Imu imu;
      imu.header.stamp = stamp;
      imu.header.frame_id = "imu";
      imu.orientation_covariance[0] = -1.0;
      imu.linear_acceleration.z = 9.81;  // unaccelerated level flight: specific force straight up
      bag.write(kImuTopic, stamp, imu);
    }
    if (with_ground_truth && k % 10 == 0) {
      geometry_msgs::PoseStamped pose;
      pose.header.stamp = stamp;
      pose.header.frame_id = "world";
      pose.pose.position.x = kSpeedMps * (t - kT0);
      pose.pose.position.z = kHeightM;
      pose.pose.orientation.w = 1.0;
      bag.write("/mocap/pose", stamp, pose);
    }
    if (k == next_image_tick) {
      bag.write(kImageTopic, stamp, renderImage(t, images));
      ++images;
      next_image_tick = 20 + static_cast<int>(std::lround(images * 1000.0 / 30.0));
    }
  }
  bag.close();
  return images;
}

struct RunResult {
  int exit_code = -1;
  std::string out, err;
};

/// Runs a shell command line, capturing its exit code, stdout and stderr.
RunResult runCommand(const std::string& command, const fs::path& dir) {
  const fs::path out = dir / "stdout.txt";
  const fs::path err = dir / "stderr.txt";
  const std::string cmd = command + " >\"" + out.string() + "\" 2>\"" + err.string() + "\"";
  const int status = std::system(cmd.c_str());
  RunResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream o(out), e(err);
  std::stringstream so, se;
  so << o.rdbuf();
  se << e.rdbuf();
  r.out = so.str();
  r.err = se.str();
  return r;
}

RunResult runRunner(const std::string& args, const fs::path& dir) {
  return runCommand(std::string("\"") + DIEKF_BAG_RUNNER_EXE + "\" " + args, dir);
}

/// scripts/calibration_ensemble.py on one sequence folder, its runs under out/tag, at 64 px, one thread.
RunResult runEnsemble(const fs::path& seq, const fs::path& out, const std::string& tag, const std::string& args,
                      const fs::path& dir) {
  const std::string bin_dir = fs::path(DIEKF_BAG_RUNNER_EXE).parent_path().string();
  return runCommand("DIEKF_BIN_DIR=\"" + bin_dir + "\" python3 \"" + DIEKF_ENSEMBLE_SCRIPT + "\" --sequences \"" +
                        seq.string() + "\" --output \"" + out.string() + "\" --tag " + tag +
                        " --threads 1 --runner-args \"--width 64 --quiet\" " + args,
                    dir);
}

std::vector<std::string> readLines(const fs::path& path) {
  std::ifstream f(path);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(f, line)) lines.push_back(line);
  return lines;
}

int countLines(const std::string& s) { return static_cast<int>(std::count(s.begin(), s.end(), '\n')); }

TEST(BagRunner, SyntheticFlightProducesEstimatesGroundTruthAndEvaluation) {
  Dirs dirs;
  const std::string bag = (dirs.root / "hover.bag").string();
  const int images = writeFlightBag(bag, 5.0, true);
  ASSERT_GE(images, 140);
  const std::string camchain = writeCamchain(dirs.root);
  const fs::path out = dirs.root / "out";
  const RunResult r = runRunner("--bag \"" + bag + "\" --camchain \"" + camchain + "\" --output \"" +
                                    out.string() + "\" --width 80 --quiet",
                                dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;

  // estimates.csv: the header, one row per processed image, 19 columns, finite values, 9-decimal stamps.
  const std::vector<std::string> lines = readLines(out / "estimates.csv");
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines[0], diekf::eval::estimatesCsvHeader());
  const int rows = static_cast<int>(lines.size()) - 1;
  // The first images come before the IMU low-pass's first output (primed over 50 ms and settled over 56 ms at
  // 500 Hz: up to four images at 30 Hz); the last ones may wait for IMU coverage beyond the bag's end.
  EXPECT_GE(rows, images - 7);
  EXPECT_LE(rows, images);
  for (std::size_t i = 1; i < lines.size(); ++i) {
    EXPECT_EQ(std::count(lines[i].begin(), lines[i].end(), ','), 18) << lines[i];
    const std::string t = lines[i].substr(0, lines[i].find(','));
    EXPECT_GE(t.size() - t.find('.') - 1, 9u) << t;
  }
  const std::vector<diekf::eval::EstimateRow> est = diekf::eval::readEstimatesCsv((out / "estimates.csv").string());
  ASSERT_EQ(static_cast<int>(est.size()), rows);
  int updated = 0;
  for (std::size_t i = 0; i < est.size(); ++i) {
    EXPECT_TRUE(est[i].allFinite()) << "row " << i;
    if (i > 0) {
      EXPECT_GT(est[i].t_s, est[i - 1].t_s);
    }
    EXPECT_GE(est[i].t_s, kT0);
    if (est[i].updateApplied()) ++updated;
  }
  EXPECT_GT(updated, rows / 2);

  // groundtruth.csv: one row per estimate inside the pose stream, true values of the analytic flight.
  const std::vector<std::string> gt = readLines(out / "groundtruth.csv");
  ASSERT_EQ(static_cast<int>(gt.size()), rows + 1);
  EXPECT_EQ(gt[0], diekf::eval::groundTruthCsvHeader());
  std::stringstream row(gt[gt.size() / 2]);
  std::vector<double> v;
  std::string field;
  while (std::getline(row, field, ',')) v.push_back(std::stod(field));
  ASSERT_EQ(v.size(), 12u);
  EXPECT_NEAR(v[1], kHeightM, 1e-9);    // d
  EXPECT_NEAR(v[2], kHeightM, 1e-9);    // h
  EXPECT_NEAR(v[3], kSpeedMps, 1e-6);   // vx in C
  EXPECT_NEAR(v[8], 1.0, 1e-9);         // muz
  EXPECT_NEAR(v[11], 1.0, 1e-9);        // gz

  // evaluation.json: every key of docs/conventions.md section 5.
  std::ifstream json_file(out / "evaluation.json");
  std::stringstream json;
  json << json_file.rdbuf();
  for (const char* key : {"sequence", "frames", "duration_s", "rmse_distance_m", "rmse_height_m", "rmse_velocity_mps",
                          "rms_normal_deg", "rms_gravity_deg", "max_normal_deg", "max_gravity_deg", "diverged",
                          "update_ms_mean", "update_ms_median", "update_ms_p99", "realtime_factor"}) {
    EXPECT_NE(json.str().find("\"" + std::string(key) + "\":"), std::string::npos) << key;
  }
  EXPECT_NE(json.str().find("\"sequence\": \"hover\""), std::string::npos);
  EXPECT_NE(r.out.find("distance RMSE"), std::string::npos) << r.out;

  // The plotting script turns the folder into the five PNGs.
  const RunResult plot = runCommand(std::string("python3 \"") + DIEKF_PLOT_SCRIPT + "\" \"" + out.string() + "\"",
                                    dirs.root);
  ASSERT_EQ(plot.exit_code, 0) << plot.err;
  for (const char* png : {"distance.png", "velocity.png", "normal_gravity.png", "errors.png", "update_time.png"}) {
    EXPECT_GT(fs::exists(out / png) ? fs::file_size(out / png) : 0u, 1000u) << png;
  }
}

// Movers on the ground: the relief (docs/noise_model.md section 13) widens the reported distance's 1-sigma past the
// tracking threshold (init/tracking_max_relative_sigma_d, 15 %) on frames the filter's own covariance would call
// tracking. The status follows what is published: those frames are degraded, and say why; the estimates are the
// same as without the relief in the covariance, bit for bit, and without it those frames say tracking.
TEST(BagRunner, ReliefBeyondTheTrackingThresholdDegradesTheStatusNotTheEstimate) {
  Dirs dirs;
  const fs::path seq = dirs.root / "movers";
  const RunResult sim = runCommand(std::string("\"") + DIEKF_SIMULATE_EXE +
                                       "\" --preset flight4 --texture grass --duration 10 --seed 1 --movers 2 "
                                       "--scale 0.5 --output \"" + seq.string() + "\"",
                                   dirs.root);
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  const auto run = [&](const std::string& name, const std::string& set) {
    const fs::path out = dirs.root / name;
    const RunResult r = runRunner("--bag \"" + (seq / "sequence.bag").string() + "\" --camchain \"" +
                                      (seq / "camchain.yaml").string() + "\" --imu \"" + (seq / "imu.yaml").string() +
                                      "\" --output \"" + out.string() + "\" --frames-csv --quiet --set " + set,
                                  dirs.root);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return out;
  };
  const fs::path with = run("with", "photometric/relief_in_covariance=true");
  const fs::path without = run("without", "photometric/relief_in_covariance=false");
  const auto a = diekf::eval::readEstimatesCsv((with / "estimates.csv").string());
  const auto b = diekf::eval::readEstimatesCsv((without / "estimates.csv").string());
  const std::vector<std::string> frames = readLines(with / "frames.csv");
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(frames.size(), a.size() + 1);
  int degraded_by_relief = 0, tracking = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].d_m, b[i].d_m) << "row " << i;
    EXPECT_EQ(a[i].v_mps, b[i].v_mps) << "row " << i;
    EXPECT_GE(a[i].sigma_d_m, b[i].sigma_d_m) << "row " << i;
    if (a[i].status == "tracking") ++tracking;
    if (b[i].status != "tracking" || a[i].status == "tracking") continue;
    ++degraded_by_relief;
    EXPECT_EQ(a[i].status, "degraded") << "row " << i;
    EXPECT_GE(a[i].sigma_d_m / a[i].d_m, 0.15 * (1.0 - 1e-9)) << "row " << i;
    EXPECT_NE(frames[i + 1].find("with the scene's relief (tracking below 0.15)"), std::string::npos) << frames[i + 1];
  }
  std::printf("[ info ] 2 movers: %d frames tracking, %d degraded by the relief (tracking without it)\n", tracking,
              degraded_by_relief);
  EXPECT_GT(degraded_by_relief, 20);
  EXPECT_GT(tracking, 0);  // not every frame: the movers are not always in view
}

// An unknown 16 ms rolling-shutter readout (the camchain has no line delay) on flights whose climb and turns fall
// in their first seconds (the simulator's flights 2 and 3 compressed into 5 s, half resolution): estimated from the
// first image (readout_from_first_image, the default; docs/algorithm.md section 3.7) the rows are modelled through
// the convergence; estimated only from the time offset's start, 2 s after convergence, they are not, and the
// filter does not converge within the flight (measured: 0.6 / 0.4 cm against 23 / 33 cm; global shutter 0.5 / 2.0).
TEST(BagRunner, AnUnknownReadoutIsEstimatedFromTheFirstImage) {
  Dirs dirs;
  for (const char* preset : {"flight2", "flight3"}) {
    const fs::path seq = dirs.root / preset;
    const RunResult sim = runCommand(std::string("\"") + DIEKF_SIMULATE_EXE + "\" --preset " + preset +
                                         " --duration 5 --scale 0.5 --seed 2 --rolling-shutter-ms 16 --threads 1"
                                         " --output \"" + seq.string() + "\"",
                                     dirs.root);
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    const auto rmseDistance = [&](const std::string& name, const std::string& set) {
      const fs::path out = dirs.root / (std::string(preset) + "_" + name);
      const RunResult r = runRunner("--bag \"" + (seq / "sequence.bag").string() + "\" --camchain \"" +
                                        (seq / "camchain.yaml").string() + "\" --imu \"" +
                                        (seq / "imu.yaml").string() + "\" --output \"" + out.string() + "\" --quiet" +
                                        set,
                                    dirs.root);
      EXPECT_EQ(r.exit_code, 0) << r.err;
      return YAML::LoadFile((out / "evaluation.json").string())["rmse_distance_m"].as<double>();
    };
    const double first = rmseDistance("first", "");
    const double waiting = rmseDistance("waiting", " --set readout_from_first_image=false");
    std::printf("[ info ] %s in 5 s, unknown 16 ms readout: distance RMSE %.2f cm estimated from the first image, "
                "%.2f cm from the offset's start\n",
                preset, 100 * first, 100 * waiting);
    EXPECT_LT(first, 0.03) << preset;
    EXPECT_LT(first, 0.2 * waiting) << preset;
  }
}

TEST(BagRunner, MeasuresTheImuRateAndDesignsThePreprocessingForIt) {
  // The configuration says 500 Hz; a 200 Hz recording gets the low-pass and decimation designed for 200 Hz (as the
  // nodelet does at start-up), a 500 Hz one is processed exactly as configured.
  Dirs dirs;
  const std::string camchain = writeCamchain(dirs.root);
  for (const int every_ms : {2, 5}) {
    const std::string bag = (dirs.root / ("imu" + std::to_string(every_ms) + ".bag")).string();
    writeFlightBag(bag, 4.0, true, every_ms);
    const fs::path out = dirs.root / ("out" + std::to_string(every_ms));
    const RunResult r = runRunner("--bag \"" + bag + "\" --camchain \"" + camchain + "\" --output \"" +
                                      out.string() + "\" --width 80",
                                  dirs.root);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    if (every_ms == 2) {
      EXPECT_NE(r.err.find("IMU at 500 Hz (measured), as configured"), std::string::npos) << r.err;
    } else {
      EXPECT_NE(r.err.find("IMU at 200 Hz (measured; imu/input_rate_hz 500 Hz)"), std::string::npos) << r.err;
      EXPECT_NE(r.err.find("decimation 2 -> prediction at 100 Hz"), std::string::npos) << r.err;
    }
    const std::vector<diekf::eval::EstimateRow> est =
        diekf::eval::readEstimatesCsv((out / "estimates.csv").string());
    ASSERT_GT(est.size(), 90u);
    for (const auto& row : est) EXPECT_TRUE(row.allFinite()) << every_ms;
  }
}

TEST(BagRunner, DeterministicAcrossRuns) {
  Dirs dirs;
  const std::string bag = (dirs.root / "f.bag").string();
  writeFlightBag(bag, 2.0, false);
  const std::string camchain = writeCamchain(dirs.root);
  std::vector<std::vector<std::string>> results;
  for (const char* name : {"a", "b"}) {
    const RunResult r = runRunner("--bag " + bag + " --camchain " + camchain + " --output " +
                                      (dirs.root / name).string() + " --width 64 --quiet",
                                  dirs.root);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_FALSE(fs::exists(dirs.root / name / "evaluation.json"));  // no ground truth in this bag
    std::vector<std::string> lines = readLines(dirs.root / name / "estimates.csv");
    // Drop the update_ms and status columns (wall time differs between runs).
    for (std::string& l : lines) l = l.substr(0, l.rfind(',', l.rfind(',') - 1));
    results.push_back(lines);
  }
  ASSERT_GT(results[0].size(), 10u);
  EXPECT_EQ(results[0], results[1]);
}

TEST(BagRunner, HelpAndBadArguments) {
  Dirs dirs;
  RunResult r = runRunner("--help", dirs.root);
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("--camchain"), std::string::npos);
  r = runRunner("--bag x.bag --output o", dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(countLines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("--camchain"), std::string::npos);
  r = runRunner("--bag x.bag --camchain c.yaml --output o --mode foo", dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("--mode"), std::string::npos);
}

TEST(BagRunner, MissingBagIsAOneLineError) {
  Dirs dirs;
  const std::string camchain = writeCamchain(dirs.root);
  const RunResult r = runRunner("--bag " + (dirs.root / "nope.bag").string() + " --camchain " + camchain +
                                    " --output " + (dirs.root / "o").string(),
                                dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(countLines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("nope.bag"), std::string::npos) << r.err;
}

TEST(BagRunner, NotABagIsAnError) {
  Dirs dirs;
  const std::string camchain = writeCamchain(dirs.root);
  const fs::path fake = dirs.root / "fake.bag";
  std::ofstream(fake) << "this is not a bag\n";
  const RunResult r = runRunner("--bag " + fake.string() + " --camchain " + camchain + " --output " +
                                    (dirs.root / "o").string(),
                                dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(countLines(r.err), 1) << r.err;
}

TEST(BagRunner, BagWithoutSensorTopicsListsWhatItHas) {
  Dirs dirs;
  const std::string camchain = writeCamchain(dirs.root);
  const fs::path path = dirs.root / "other.bag";
  {
    rosbag::Bag bag;
    bag.open(path.string(), rosbag::bagmode::Write);
    std_msgs::String s;
    s.data = "hello";
    bag.write("/chatter", ros::Time(kT0), s);
    sensor_msgs::Imu imu;
    imu.header.stamp = ros::Time(kT0);
    bag.write("/some/imu", ros::Time(kT0), imu);
    bag.close();
  }
  const RunResult r = runRunner("--bag " + path.string() + " --camchain " + camchain + " --output " +
                                    (dirs.root / "o").string(),
                                dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(countLines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("/chatter"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("/some/imu"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(kImageTopic), std::string::npos) << r.err;  // the topic it looked for
}

TEST(BagRunner, UnknownSetKeyIsRejected) {
  Dirs dirs;
  const std::string bag = (dirs.root / "f.bag").string();
  writeFlightBag(bag, 0.5, false);
  const std::string camchain = writeCamchain(dirs.root);
  const RunResult r = runRunner("--bag " + bag + " --camchain " + camchain + " --output " +
                                    (dirs.root / "o").string() + " --set no_such/key=1",
                                dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("no_such/key"), std::string::npos) << r.err;
}

RunResult runReplay(const std::string& args, const fs::path& dir) {
  return runCommand(std::string("\"") + DIEKF_REPLAY_EXE + "\" " + args, dir);
}

/// estimates.csv lines without the update_ms column (wall time).
std::vector<std::string> withoutUpdateMs(const fs::path& csv) {
  std::vector<std::string> lines = readLines(csv);
  for (std::string& l : lines) {
    const std::size_t status = l.rfind(',');
    const std::size_t ms = l.rfind(',', status - 1);
    l = l.substr(0, ms) + l.substr(status);
  }
  return lines;
}

// The exported sequence, replayed without ROS by diekf_replay, gives the runner's estimates exactly (same events,
// same order, same parameters).
TEST(BagRunner, ExportedSequenceReplaysToTheRunnersEstimates) {
  Dirs dirs;
  const std::string bag = (dirs.root / "f.bag").string();
  const int images = writeFlightBag(bag, 2.0, false);
  const std::string camchain = writeCamchain(dirs.root);
  const fs::path seq = dirs.root / "seq";
  const std::string params = " --width 64 --set photometric/max_passes=2";
  RunResult r = runRunner("--bag " + bag + " --camchain " + camchain + " --output " + (dirs.root / "runner").string() +
                              params + " --export-sequence " + seq.string(),
                          dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("photometric sweep SIMD: "), std::string::npos) << r.err;
  // The folder: calibration copy, one PGM per image, events in the runner's order.
  EXPECT_EQ(readLines(seq / "camchain.yaml"), readLines(camchain));
  const std::vector<std::string> events = readLines(seq / "events.csv");
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events[0], "# diekf sequence 1");
  int image_events = 0, imu_events = 0;
  for (const std::string& e : events) {
    if (e.rfind("image,", 0) == 0) ++image_events;
    if (e.rfind("imu,", 0) == 0) ++imu_events;
  }
  EXPECT_EQ(image_events, images);
  EXPECT_GT(imu_events, 900);  // 500 Hz over 2 s
  EXPECT_TRUE(fs::is_regular_file(seq / "images" / "000000.pgm"));

  r = runReplay("--sequence " + seq.string() + " --output " + (dirs.root / "replay").string() + params, dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("photometric sweep SIMD: "), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("scalar"), std::string::npos) << r.err;
  const std::vector<std::string> runner = withoutUpdateMs(dirs.root / "runner" / "estimates.csv");
  ASSERT_GT(runner.size(), 30u);
  EXPECT_EQ(withoutUpdateMs(dirs.root / "replay" / "estimates.csv"), runner);
  // states.csv: one full-precision row per estimate.
  EXPECT_EQ(readLines(dirs.root / "replay" / "states.csv").size(), runner.size());

  // Another parameter set gives other estimates (the replay's options reach the estimator).
  r = runReplay("--sequence " + seq.string() + " --output " + (dirs.root / "ekf").string() + params + " --mode ekf",
                dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(withoutUpdateMs(dirs.root / "ekf" / "estimates.csv"), runner);
  // --max-images stops early; --preload processes the same events.
  r = runReplay("--sequence " + seq.string() + " --output " + (dirs.root / "pre").string() + params +
                    " --preload --max-images 20",
                dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> pre = withoutUpdateMs(dirs.root / "pre" / "estimates.csv");
  // Header + one estimate per image, but for images before the IMU low-pass's first output (it is primed from the
  // mean of its first 50 ms and settled over 56 ms: at most four images at 30 Hz).
  ASSERT_GE(pre.size(), 17u);
  ASSERT_LE(pre.size(), 21u);
  EXPECT_TRUE(std::equal(pre.begin(), pre.end(), runner.begin()));
  // Errors: no sequence folder, unknown option.
  r = runReplay("--sequence " + (dirs.root / "none").string(), dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("events.csv"), std::string::npos) << r.err;
  r = runReplay("--sequence " + seq.string() + " --bogus", dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("--bogus"), std::string::npos) << r.err;
}

int maxIterations(const fs::path& csv) {
  int max_it = -1;
  for (const diekf::eval::EstimateRow& r : diekf::eval::readEstimatesCsv(csv.string())) {
    max_it = std::max(max_it, r.iterations);
  }
  return max_it;
}

TEST(BagRunner, ModeAndSetReachTheEstimator) {
  Dirs dirs;
  const std::string bag = (dirs.root / "f.bag").string();
  writeFlightBag(bag, 2.0, false);
  const std::string common = "--bag " + bag + " --camchain " + writeCamchain(dirs.root) + " --width 64 --quiet";
  // Three passes allowed: the first updates, starting far from the true distance, use more than one.
  RunResult r = runRunner(common + " --mode iekf --set photometric/max_passes=3 --set photometric/stop_threshold=1e-9"
                                   " --output " + (dirs.root / "iekf").string(),
                          dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(maxIterations(dirs.root / "iekf" / "estimates.csv"), 3);
  r = runRunner(common + " --mode iekf --set photometric/max_passes=1 --output " + (dirs.root / "one").string(),
                dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(maxIterations(dirs.root / "one" / "estimates.csv"), 1);
  r = runRunner(common + " --mode ekf --output " + (dirs.root / "ekf").string(), dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(maxIterations(dirs.root / "ekf" / "estimates.csv"), 1);
  // A value of the wrong type names the key.
  r = runRunner(common + " --set photometric/max_passes=two --output " + (dirs.root / "bad").string(), dirs.root);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("photometric/max_passes"), std::string::npos) << r.err;
}

TEST(BagRunner, CalibrationEnsembleDrawsFromThePriorAndPoolsTheConsistency) {
  // scripts/calibration_ensemble.py: each draw's camchain is the true one with the focal lengths times (1 + e) and
  // the camera frame turned by theta (both as recorded in draw.json), the draws repeat with the seed, the pooled
  // table counts every run, and a draw of zero is exactly the runner on the true calibration.
  Dirs dirs;
  const fs::path seq = dirs.root / "flight";
  fs::create_directories(seq);
  writeFlightBag((seq / "sequence.bag").string(), 5.0, true);
  writeCamchain(seq);
  const fs::path ens = dirs.root / "ens";
  auto ensemble = [&](const std::string& tag, const std::string& args) {
    return runEnsemble(seq, ens, tag, args, dirs.root);
  };
  const std::string drawn = "--draws 2 --seed 7 --sigma-focal 0.05 --sigma-rotation-deg 2";
  RunResult r = ensemble("a", drawn);
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  double focal_errors[2] = {0.0, 0.0};
  for (int k = 0; k < 2; ++k) {
    const fs::path run = ens / "a" / ("flight_d" + std::to_string(k));
    const YAML::Node draw = YAML::LoadFile((run / "draw.json").string());
    const YAML::Node cam = YAML::LoadFile((run / "camchain.yaml").string())["cam0"];
    const double e = draw["focal_error"].as<double>();
    focal_errors[k] = e;
    EXPECT_GT(std::abs(e), 1e-6);
    EXPECT_NEAR(cam["intrinsics"][0].as<double>(), kFocalPx * (1.0 + e), 1e-9);
    EXPECT_NEAR(cam["intrinsics"][1].as<double>(), kFocalPx * (1.0 + e), 1e-9);
    EXPECT_NEAR(cam["intrinsics"][2].as<double>(), kCxPx, 1e-12);
    EXPECT_NEAR(cam["intrinsics"][3].as<double>(), kCyPx, 1e-12);
    // R_written R_true^T is the rotation by theta: angle and axis.
    double R[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) R[i][j] = cam["T_cam_imu"][i][j].as<double>();
    const double true_diag[3] = {1.0, -1.0, -1.0};
    double D[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) D[i][j] = R[i][j] * true_diag[j];
    double theta[3], norm2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      theta[i] = draw["rotation_deg"][i].as<double>() * M_PI / 180.0;
      norm2 += theta[i] * theta[i];
    }
    const double angle = std::acos(std::min(1.0, 0.5 * (D[0][0] + D[1][1] + D[2][2] - 1.0)));
    EXPECT_NEAR(angle, std::sqrt(norm2), 1e-9);
    const double s = 2.0 * std::sin(angle);
    EXPECT_NEAR((D[2][1] - D[1][2]) / s * angle, theta[0], 1e-9);
    EXPECT_NEAR((D[0][2] - D[2][0]) / s * angle, theta[1], 1e-9);
    EXPECT_NEAR((D[1][0] - D[0][1]) / s * angle, theta[2], 1e-9);
    EXPECT_TRUE(fs::exists(run / "estimates.csv"));
  }
  EXPECT_NE(focal_errors[0], focal_errors[1]);
  const YAML::Node pooled = YAML::LoadFile((ens / "a.json").string());
  EXPECT_EQ(pooled["runs"].size(), 2u);
  EXPECT_EQ(pooled["failed"].size(), 0u);
  EXPECT_EQ(pooled["pooled"]["all"]["runs"].as<int>(), 2);
  const double coverage = pooled["pooled"]["all"]["coverage2_d"].as<double>();
  EXPECT_GE(coverage, 0.0);
  EXPECT_LE(coverage, 1.0);
  EXPECT_NE(r.out.find("| all | 2 |"), std::string::npos) << r.out;

  // The same seed draws the same calibrations.
  r = ensemble("b", drawn);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (int k = 0; k < 2; ++k) {
    const std::string name = "flight_d" + std::to_string(k);
    EXPECT_EQ(readLines(ens / "a" / name / "camchain.yaml"), readLines(ens / "b" / name / "camchain.yaml")) << k;
  }

  // A draw of zero runs the true calibration (and passes no prior): the estimates of the runner given it directly.
  r = ensemble("zero", "--draws 1 --sigma-focal 0 --sigma-rotation-deg 0");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path direct = dirs.root / "direct";
  r = runRunner("--bag \"" + (seq / "sequence.bag").string() + "\" --camchain \"" + (seq / "camchain.yaml").string() +
                    "\" --output \"" + direct.string() +
                    "\" --width 64 --quiet",
                dirs.root);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::vector<std::string> a = readLines(ens / "zero" / "flight_d0" / "estimates.csv");
  std::vector<std::string> b = readLines(direct / "estimates.csv");
  for (auto* lines : {&a, &b})
    for (std::string& l : *lines) l = l.substr(0, l.rfind(',', l.rfind(',') - 1));  // without update_ms, status
  ASSERT_GT(a.size(), 50u);
  EXPECT_EQ(a, b);
}

TEST(BagRunner, CalibrationEnsembleRestoresTheListedPartsOfTheTrueCalibration) {
  // scripts/calibration_ensemble.py --restore: the camchain as written with only the listed parts taken from the
  // simulator's realism.yaml (which calibration error matters); a misspelt part is refused by name.
  Dirs dirs;
  const fs::path seq = dirs.root / "flight";
  fs::create_directories(seq);
  writeFlightBag((seq / "sequence.bag").string(), 5.0, true);
  writeCamchain(seq);  // as written: f 120, principal point (80, 50), T_cam_imu diag(1, -1, -1)
  {
    std::ofstream f(seq / "realism.yaml");
    f << "true_intrinsics: [118.0, 118.5, 83.0, 47.0]\n"
      << "true_T_cam_imu:\n"
      << "  - [0.0, -1.0, 0.0, 0.01]\n"
      << "  - [-1.0, 0.0, 0.0, 0.02]\n"
      << "  - [0.0, 0.0, -1.0, 0.0]\n"
      << "  - [0.0, 0.0, 0.0, 1.0]\n";
  }
  const fs::path ens = dirs.root / "ens";
  auto ensemble = [&](const std::string& tag, const std::string& restore) {
    return runEnsemble(seq, ens, tag, "--draws 1 --sigma-focal 0 --sigma-rotation-deg 0 --restore " + restore,
                       dirs.root);
  };
  auto camchain = [&](const std::string& tag) {
    return YAML::LoadFile((ens / tag / "flight_d0" / "camchain.yaml").string())["cam0"];
  };
  RunResult r = ensemble("pp", "principal_point");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  YAML::Node cam = camchain("pp");
  EXPECT_DOUBLE_EQ(cam["intrinsics"][0].as<double>(), kFocalPx) << "focal lengths as written";
  EXPECT_DOUBLE_EQ(cam["intrinsics"][1].as<double>(), kFocalPx);
  EXPECT_DOUBLE_EQ(cam["intrinsics"][2].as<double>(), 83.0) << "principal point restored";
  EXPECT_DOUBLE_EQ(cam["intrinsics"][3].as<double>(), 47.0);
  EXPECT_DOUBLE_EQ(cam["T_cam_imu"][0][0].as<double>(), 1.0) << "rotation as written";
  EXPECT_TRUE(fs::exists(ens / "pp" / "flight_d0" / "estimates.csv"));
  EXPECT_EQ(YAML::LoadFile((ens / "pp" / "flight_d0" / "draw.json").string())["restored"][0].as<std::string>(),
            "principal_point");

  r = ensemble("fr", "focal_lengths,rotation");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  cam = camchain("fr");
  EXPECT_DOUBLE_EQ(cam["intrinsics"][0].as<double>(), 118.0);
  EXPECT_DOUBLE_EQ(cam["intrinsics"][1].as<double>(), 118.5);
  EXPECT_DOUBLE_EQ(cam["intrinsics"][2].as<double>(), kCxPx);
  EXPECT_DOUBLE_EQ(cam["T_cam_imu"][0][1].as<double>(), -1.0) << "the true camera-IMU transform";
  EXPECT_DOUBLE_EQ(cam["T_cam_imu"][1][3].as<double>(), 0.02);

  r = ensemble("none", "none");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  cam = camchain("none");
  EXPECT_DOUBLE_EQ(cam["intrinsics"][2].as<double>(), kCxPx) << "nothing restored: as written";

  r = ensemble("bad", "principal_points");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("principal_points"), std::string::npos) << r.err;
}

/// Ground-truth poses (200 Hz) and image stamps (30 Hz, 1x1 images) for scripts/rolling_shutter_warp_check.py: the
/// camera at kHeightM over the level floor moving at speed_mps along world y, pitching by amplitude_rad
/// sin(omega t) about world x.
void writePoseBag(const std::string& path, double duration_s, double speed_mps, double amplitude_rad, double omega) {
  rosbag::Bag bag;
  bag.open(path, rosbag::bagmode::Write);
  shape_msgs::Plane plane;
  plane.coef = {0.0, 0.0, 1.0, 0.0};
  bag.write("/ground_truth/plane", ros::Time(kT0), plane);
  int images = 0;
  const int ticks = static_cast<int>(std::lround(duration_s * 1000.0));
  for (int k = 0; k <= ticks; ++k) {
    const double t = k * 1e-3;
    const ros::Time stamp(kT0 + t);
    if (k % 5 == 0) {
      geometry_msgs::PoseStamped pose;
      pose.header.stamp = stamp;
      pose.header.frame_id = "world";
      pose.pose.position.y = speed_mps * t;
      pose.pose.position.z = kHeightM;
      const double angle = amplitude_rad * std::sin(omega * t);
      pose.pose.orientation.x = std::sin(0.5 * angle);
      pose.pose.orientation.w = std::cos(0.5 * angle);
      bag.write("/mocap/pose", stamp, pose);
    }
    if (k == 20 + static_cast<int>(std::lround(images * 1000.0 / 30.0))) {
      sensor_msgs::Image img;
      img.header.stamp = stamp;
      img.width = img.height = img.step = 1;
      img.encoding = "mono8";
      img.data.assign(1, 128);
      bag.write(kImageTopic, stamp, img);
      ++images;
    }
  }
  bag.close();
}

TEST(BagRunner, RollingShutterWarpCheckMeasuresTheRowsAgainstExactCorrespondences) {
  // scripts/rolling_shutter_warp_check.py on two flights with a 3 ms readout (3e-5 s per row). Moving steadily
  // along the readout's direction, the warp's rows are exact (the reference pixel's time solved for its own
  // effect) and the old ones off by the lengthened interval's flow taken to first order; pitching at up to 1 rad/s
  // while moving, the flow's rate at the reference image's end (the rows since session 52) is several times
  // closer than the mean flow, and both far closer than the global-shutter warp.
  Dirs dirs;
  auto check = [&](const std::string& name, double speed_mps, double amplitude_rad, double omega) {
    const fs::path seq = dirs.root / name;
    fs::create_directories(seq);
    writePoseBag((seq / "sequence.bag").string(), 2.0, speed_mps, amplitude_rad, omega);
    writeCamchain(seq);
    std::ofstream(seq / "realism.yaml") << "rolling_shutter_line_time_s: 3.0e-05\n";
    const fs::path json = dirs.root / (name + ".json");
    const RunResult r = runCommand(std::string("python3 \"") + DIEKF_RS_CHECK_SCRIPT + "\" \"" + seq.string() +
                                       "\" --from 0.5 --to 1.5 --width 160 --step 4 --image-topic " + kImageTopic +
                                       " --json \"" + json.string() + "\"",
                                   dirs.root);
    EXPECT_EQ(r.exit_code, 0) << r.err << r.out;
    return YAML::LoadFile(json.string());
  };
  const YAML::Node steady = check("steady", 3.0, 0.0, 0.0);
  ASSERT_TRUE(steady["variants"]) << "no table";
  EXPECT_EQ(steady["pairs"].as<int>(), 30);
  const double steady_now = steady["variants"]["now"]["px_rms"].as<double>();
  const double steady_before = steady["variants"]["before"]["px_rms"].as<double>();
  const double steady_global = steady["variants"]["global_shutter"]["px_rms"].as<double>();
  std::printf("[rolling shutter rows] steady 3 m/s: now %.2e px, before %.2e, global shutter %.3f\n", steady_now,
              steady_before, steady_global);
  // Measured: 1.4e-11 px, 1.0e-3 (the lengthened interval's flow to first order) and 0.093.
  EXPECT_LT(steady_now, 1e-6);
  EXPECT_LT(steady_before, 5e-3);
  EXPECT_GT(steady_global, 0.05);
  const YAML::Node pitching = check("pitching", 2.5, 0.5, 2.0);
  ASSERT_TRUE(pitching["variants"]) << "no table";
  const double now = pitching["variants"]["now"]["px_rms"].as<double>();
  const double before = pitching["variants"]["before"]["px_rms"].as<double>();
  const double global = pitching["variants"]["global_shutter"]["px_rms"].as<double>();
  std::printf("[rolling shutter rows] pitching at 2.5 m/s: now %.2e px, before %.2e, global shutter %.3f\n", now,
              before, global);
  // Measured: 3.9e-5 px, 6.1e-4 and 0.037.
  EXPECT_LT(now, 0.25 * before);
  EXPECT_GT(global, 20.0 * before);
}

}  // namespace
