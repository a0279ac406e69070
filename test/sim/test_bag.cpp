// A whole (tiny) simulated sequence: topics, types, rates, stamps, ground truth and calibration files.
#include <gtest/gtest.h>

#include <map>

#include <geometry_msgs/PoseStamped.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <shape_msgs/Plane.h>

#include "diekf/camera_model.h"
#include "diekf/sim/simulator.h"
#include "test_util.h"

using namespace diekf;
using namespace diekf::sim;

namespace {

struct TopicLog {
  std::string type;
  std::vector<double> stamps;  // header stamps (s, relative to the first message of any topic)
};

}  // namespace

class SimulatedBag : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new simtest::TempDir();
    opt_ = new SimulationOptions();
    opt_->preset = "flight5";
    opt_->duration_s = 2.0;
    opt_->scale = 0.125;  // 94 x 60
    opt_->incline_deg = 15.0;
    opt_->texture = "natural";
    opt_->output_dir = (dir_->path() / "out").string();
    summary_ = new SimulationSummary(runSimulation(*opt_, nullptr));
  }
  static void TearDownTestSuite() {
    delete summary_;
    delete opt_;
    delete dir_;
  }
  static simtest::TempDir* dir_;
  static SimulationOptions* opt_;
  static SimulationSummary* summary_;
};
simtest::TempDir* SimulatedBag::dir_ = nullptr;
SimulationOptions* SimulatedBag::opt_ = nullptr;
SimulationSummary* SimulatedBag::summary_ = nullptr;

TEST_F(SimulatedBag, TopicsTypesRatesAndStamps) {
  rosbag::Bag bag(summary_->bag_path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, TopicLog> topics;
  const double t0 = opt_->start_stamp_s;
  shape_msgs::Plane plane;
  int n_plane = 0;
  for (const rosbag::MessageInstance& m : view) {
    TopicLog& log = topics[m.getTopic()];
    log.type = m.getDataType();
    if (auto im = m.instantiate<sensor_msgs::Image>()) {
      EXPECT_EQ(im->encoding, "mono8");
      EXPECT_EQ(im->width, 94u);
      EXPECT_EQ(im->height, 60u);
      EXPECT_EQ(im->step, 94u);
      EXPECT_EQ(im->data.size(), 94u * 60u);
      log.stamps.push_back(im->header.stamp.toSec() - t0);
    } else if (auto imu = m.instantiate<sensor_msgs::Imu>()) {
      log.stamps.push_back(imu->header.stamp.toSec() - t0);
    } else if (auto p = m.instantiate<geometry_msgs::PoseStamped>()) {
      log.stamps.push_back(p->header.stamp.toSec() - t0);
    } else if (auto ci = m.instantiate<sensor_msgs::CameraInfo>()) {
      EXPECT_EQ(ci->distortion_model, "plumb_bob");
      log.stamps.push_back(ci->header.stamp.toSec() - t0);
    } else if (auto pl = m.instantiate<shape_msgs::Plane>()) {
      plane = *pl;
      ++n_plane;
      log.stamps.push_back(m.getTime().toSec() - t0);
    }
    // Bag time equals the header stamp.
    if (!log.stamps.empty()) {
      EXPECT_NEAR(m.getTime().toSec() - t0, log.stamps.back(), 1e-6);
    }
  }
  ASSERT_EQ(topics.size(), 5u);
  EXPECT_EQ(topics["/mynteye/left/image_raw"].type, "sensor_msgs/Image");
  EXPECT_EQ(topics["/mynteye/left/camera_info"].type, "sensor_msgs/CameraInfo");
  EXPECT_EQ(topics["/mynteye/imu/data_raw"].type, "sensor_msgs/Imu");
  EXPECT_EQ(topics["/mocap/pose"].type, "geometry_msgs/PoseStamped");
  EXPECT_EQ(topics["/ground_truth/plane"].type, "shape_msgs/Plane");
  const auto rate = [](const std::vector<double>& s) { return (s.size() - 1) / (s.back() - s.front()); };
  EXPECT_NEAR(rate(topics["/mynteye/left/image_raw"].stamps), 30.0, 0.01);
  EXPECT_NEAR(rate(topics["/mynteye/imu/data_raw"].stamps), 500.0, 0.01);
  EXPECT_GE(rate(topics["/mocap/pose"].stamps), 100.0);
  EXPECT_EQ(topics["/mynteye/imu/data_raw"].stamps.size(), 1001u);
  for (auto& kv : topics)
    for (std::size_t i = 1; i < kv.second.stamps.size(); ++i)
      ASSERT_GT(kv.second.stamps[i], kv.second.stamps[i - 1]) << kv.first << " message " << i;
  // The plane: one message, unit normal, tilted 15 deg, camera on its positive side.
  ASSERT_EQ(n_plane, 1);
  const Eigen::Vector3d n(plane.coef[0], plane.coef[1], plane.coef[2]);
  EXPECT_NEAR(n.norm(), 1.0, 1e-12);
  EXPECT_NEAR(std::acos(n.z()) * 180.0 / M_PI, 15.0, 1e-9);
}

TEST_F(SimulatedBag, GroundTruthAndImuAgreeWithTheTrajectory) {
  // Seconds since t = 0 of the simulation, exact to the nanosecond (toSec() at ~1.6e9 s is not).
  const auto relTime = [](const ros::Time& s) {
    return static_cast<double>(static_cast<std::int64_t>(s.toNSec()) - std::llround(opt_->start_stamp_s * 1e9)) * 1e-9;
  };
  const Trajectory tr = makeTrajectory(*opt_);
  rosbag::Bag bag(summary_->bag_path, rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery(std::vector<std::string>{"/mocap/pose", "/mynteye/imu/data_raw"}));
  Eigen::Vector3d f_sum = Eigen::Vector3d::Zero(), f_true = Eigen::Vector3d::Zero();
  int n_f = 0, n_pose = 0;
  for (const rosbag::MessageInstance& m : view) {
    if (auto p = m.instantiate<geometry_msgs::PoseStamped>()) {
      const KinematicState k = tr.evaluate(relTime(p->header.stamp));
      EXPECT_NEAR(p->pose.position.x, k.p_W.x(), 1e-9);
      EXPECT_NEAR(p->pose.position.z, k.p_W.z(), 1e-9);
      const Eigen::Quaterniond q(p->pose.orientation.w, p->pose.orientation.x, p->pose.orientation.y,
                                 p->pose.orientation.z);
      EXPECT_LT((q.toRotationMatrix() - k.R_WI).norm(), 1e-9);
      ++n_pose;
    } else if (auto imu = m.instantiate<sensor_msgs::Imu>()) {
      const double t = relTime(imu->header.stamp);
      if (t > 0.19) continue;  // hover phase (hover_s = 0.2 s for a 2 s sequence)
      f_sum += Eigen::Vector3d(imu->linear_acceleration.x, imu->linear_acceleration.y, imu->linear_acceleration.z);
      f_true += tr.evaluate(t).f_I;
      ++n_f;
    }
  }
  EXPECT_GE(n_pose, 200);
  ASSERT_GT(n_f, 90);
  // Mean specific force over the hover: +9.81 up in I, up to the drawn accelerometer bias (vibration averages out).
  EXPECT_LT((f_sum / n_f - f_true / n_f - summary_->accel_bias0).norm(), 0.05);
  EXPECT_NEAR((f_true / n_f).z(), kGravityMps2, 1e-6);
}

TEST_F(SimulatedBag, CalibrationFilesParse) {
  const CameraModel cam = CameraModel::fromKalibrYaml((dir_->path() / "out" / "camchain.yaml").string());
  const CameraModel ref = myntEyeSimCamera(opt_->scale);
  EXPECT_EQ(cam.K.width, 94);
  EXPECT_EQ(cam.K.height, 60);
  EXPECT_NEAR(cam.K.fx, ref.K.fx, 1e-9);
  EXPECT_NEAR(cam.K.cy, ref.K.cy, 1e-9);
  EXPECT_EQ(cam.distortion, DistortionModel::kRadTan);
  EXPECT_NEAR(cam.distortion_coeffs[0], -0.3178, 1e-12);
  EXPECT_LT((cam.T_cam_imu.matrix() - ref.T_cam_imu.matrix()).norm(), 1e-9);
  EXPECT_EQ(cam.rostopic, "/mynteye/left/image_raw");
  // Downward camera: the camera z axis points along -z of the (level) IMU.
  EXPECT_GT(-cam.R_CI()(2, 2), 0.99);
  const ImuNoiseParams n = readImuYaml((dir_->path() / "out" / "imu.yaml").string());
  EXPECT_DOUBLE_EQ(n.rate_hz, 500.0);
  EXPECT_DOUBLE_EQ(n.gyro_noise_density, ImuNoiseParams().gyro_noise_density);
  EXPECT_DOUBLE_EQ(n.accel_random_walk, ImuNoiseParams().accel_random_walk);
}

TEST(Simulator, DroppedFramesAndUnreadableTexture) {
  simtest::TempDir dir;
  SimulationOptions o;
  o.preset = "flight1";
  o.duration_s = 1.0;
  o.scale = 0.1;
  o.drop_prob = 0.3;
  o.output_dir = dir.str();
  const SimulationSummary s = runSimulation(o, nullptr);
  EXPECT_GT(s.frames_dropped, 0);
  EXPECT_EQ(s.frames_written + s.frames_dropped, 29);
  o.texture = (dir.path() / "no_such_texture.png").string();
  try {
    runSimulation(o, nullptr);
    FAIL() << "expected an exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_texture.png"), std::string::npos) << e.what();
  }
}

TEST(SimulatorCli, ParsesAndRejects) {
  SimulationOptions o;
  std::string err;
  EXPECT_EQ(parseSimulateArgs({"--preset", "flight3", "--duration=12.5", "--seed", "9", "--incline-deg", "20",
                               "--texture", "natural", "--output", "x"},
                              &o, &err),
            ParseResult::kOk)
      << err;
  EXPECT_EQ(o.preset, "flight3");
  EXPECT_DOUBLE_EQ(o.duration_s, 12.5);
  EXPECT_EQ(o.seed, 9u);
  EXPECT_DOUBLE_EQ(o.incline_deg, 20.0);
  EXPECT_EQ(o.texture, "natural");
  EXPECT_EQ(parseSimulateArgs({"--help"}, &o, &err), ParseResult::kHelp);
  SimulationOptions h;
  EXPECT_EQ(parseSimulateArgs({"--texture", "grass", "--height", "0.4", "--height-amplitude", "0.1", "--output", "x"},
                              &h, &err),
            ParseResult::kOk)
      << err;
  EXPECT_EQ(h.texture, "grass");
  EXPECT_DOUBLE_EQ(h.height_amplitude_m, 0.1);
  EXPECT_LT(SimulationOptions().height_amplitude_m, 0.0);  // default: the preset's
  EXPECT_TRUE(h.lens_distortion);  // the MYNT EYE's distortion unless --no-distortion
  SimulationOptions pin;
  EXPECT_EQ(parseSimulateArgs({"--no-distortion", "--output", "x"}, &pin, &err), ParseResult::kOk) << err;
  EXPECT_FALSE(pin.lens_distortion);
  EXPECT_NE(simulateUsage().find("grass"), std::string::npos);
  const std::vector<std::vector<std::string>> bad = {{"--preset", "flight9", "--output", "x"},
                                                     {"--duration", "abc", "--output", "x"},
                                                     {"--incline-deg", "80", "--output", "x"},
                                                     {"--height-amplitude", "-0.1", "--output", "x"},
                                                     {"--seed", "-3", "--output", "x"},
                                                     {"--frobnicate", "--output", "x"},
                                                     {"--duration"},
                                                     {"--preset", "flight1"}};
  for (const auto& args : bad) {
    err.clear();
    SimulationOptions fresh;
    EXPECT_EQ(parseSimulateArgs(args, &fresh, &err), ParseResult::kError) << args[0];
    EXPECT_FALSE(err.empty());
    EXPECT_EQ(err.find('\n'), std::string::npos);  // one line
  }
}

TEST(Simulator, HeightAmplitudeBoundsTheHeight) {
  SimulationOptions o;
  o.preset = "flight5";
  o.duration_s = 20.0;
  o.height_m = 0.4;
  const SpeedStats preset = makeTrajectory(o).stats(100.0);
  o.height_amplitude_m = 0.1;
  const SpeedStats bounded = makeTrajectory(o).stats(100.0);
  // The preset's +-0.30 m would take the IMU to ~0.1 m above the ground; +-0.1 m keeps it within 0.3-0.5 m.
  EXPECT_LT(preset.min_height_m, 0.2);
  EXPECT_GT(bounded.min_height_m, 0.29);
  EXPECT_LT(bounded.max_height_m, 0.51);
  // Horizontal motion unchanged.
  EXPECT_NEAR(bounded.rms_mps, preset.rms_mps, 0.02);
}
