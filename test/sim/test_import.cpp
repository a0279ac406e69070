// Importers: round trips of tiny generated datasets, and clear errors on bad input.
#include <gtest/gtest.h>

#include <fstream>

#include <geometry_msgs/PoseStamped.h>
#include <opencv2/imgcodecs.hpp>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>

#include "diekf/camera_model.h"
#include "diekf/sim/importers.h"
#include "diekf/sim/sequence_io.h"
#include "test_util.h"

using namespace diekf;
using namespace diekf::sim;
namespace fs = std::filesystem;

namespace {

void writeText(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream f(p);
  f << text;
}

cv::Mat pattern(int seed) {
  cv::Mat m(12, 20, CV_8UC1);
  for (int v = 0; v < m.rows; ++v)
    for (int u = 0; u < m.cols; ++u) m.at<unsigned char>(v, u) = static_cast<unsigned char>((u * 7 + v * 13 + seed * 31) % 256);
  return m;
}

struct BagContents {
  std::vector<sensor_msgs::Image> images;
  std::vector<sensor_msgs::Imu> imu;
  std::vector<geometry_msgs::PoseStamped> poses;
  std::vector<double> bag_times;
};

BagContents readBag(const std::string& path) {
  BagContents c;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  for (const rosbag::MessageInstance& m : view) {
    c.bag_times.push_back(m.getTime().toSec());
    if (auto im = m.instantiate<sensor_msgs::Image>()) {
      EXPECT_EQ(m.getTopic(), "/mynteye/left/image_raw");
      c.images.push_back(*im);
    } else if (auto imu = m.instantiate<sensor_msgs::Imu>()) {
      EXPECT_EQ(m.getTopic(), "/mynteye/imu/data_raw");
      c.imu.push_back(*imu);
    } else if (auto p = m.instantiate<geometry_msgs::PoseStamped>()) {
      EXPECT_EQ(m.getTopic(), "/mocap/pose");
      c.poses.push_back(*p);
    }
  }
  return c;
}

/// mynteye-folder sample: 5 IMU rows (with header), 3 images (one 16-bit, one colour).
void makeMynteyeFolder(const fs::path& dir) {
  writeText(dir / "imu0.csv",
            "t_us, ax, ay, az, gx, gy, gz\n"
            "1000000, 0.1, 0.2, 9.8, 0.01, 0.02, 0.03\n"
            "1002000, 0.1, 0.2, 9.7, 0.01, 0.02, 0.04\n"
            "1004000, 0.1, 0.2, 9.6, 0.01, 0.02, 0.05\n"
            "1036000, 0.1, 0.2, 9.5, 0.01, 0.02, 0.06\n"
            "1070000, 0.1, 0.2, 9.4, 0.01, 0.02, 0.07\n");
  fs::create_directories(dir / "left");
  cv::imwrite((dir / "left" / "1003000.png").string(), pattern(0));
  cv::Mat m16;
  pattern(1).convertTo(m16, CV_16U, 256.0);
  cv::imwrite((dir / "left" / "1036333.png").string(), m16);
  cv::Mat bgr;
  cv::Mat ch[3] = {pattern(2), pattern(2), pattern(2)};
  cv::merge(ch, 3, bgr);
  cv::imwrite((dir / "left" / "1069666.png").string(), bgr);
}

std::string expectImportError(const ImportOptions& o) {
  try {
    runImport(o);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected an import error";
  return "";
}

}  // namespace

TEST(ImportMynteye, RoundTrip) {
  simtest::TempDir tmp;
  makeMynteyeFolder(tmp.path() / "in");
  ImportOptions o;
  o.format = "mynteye-folder";
  o.input_dir = (tmp.path() / "in").string();
  o.output_dir = (tmp.path() / "out").string();
  const ImportSummary s = runImport(o);
  EXPECT_EQ(s.images, 3u);
  EXPECT_EQ(s.imu, 5u);
  ASSERT_FALSE(s.notes.empty());  // default calibration was written
  const BagContents c = readBag(s.bag_path);
  ASSERT_EQ(c.images.size(), 3u);
  ASSERT_EQ(c.imu.size(), 5u);
  EXPECT_EQ(c.images[0].header.stamp.toNSec(), 1003000000ull);
  EXPECT_EQ(c.images[1].header.stamp.toNSec(), 1036333000ull);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(c.images[k].encoding, "mono8");
    const cv::Mat ref = pattern(k);
    ASSERT_EQ(c.images[k].data.size(), ref.total());
    EXPECT_TRUE(std::equal(c.images[k].data.begin(), c.images[k].data.end(), ref.data)) << "image " << k;
  }
  EXPECT_EQ(c.imu[3].header.stamp.toNSec(), 1036000000ull);
  EXPECT_DOUBLE_EQ(c.imu[3].linear_acceleration.z, 9.5);
  EXPECT_DOUBLE_EQ(c.imu[3].angular_velocity.z, 0.06);
  EXPECT_DOUBLE_EQ(c.imu[0].linear_acceleration.x, 0.1);
  EXPECT_DOUBLE_EQ(c.imu[0].angular_velocity.y, 0.02);
  for (std::size_t i = 1; i < c.bag_times.size(); ++i) EXPECT_LE(c.bag_times[i - 1], c.bag_times[i]);
  const CameraModel cam = CameraModel::fromKalibrYaml((tmp.path() / "out" / "camchain.yaml").string());
  EXPECT_EQ(cam.K.width, 752);
  EXPECT_NEAR(cam.K.fx, 364.91, 1e-9);
  const ImuNoiseParams n = readImuYaml((tmp.path() / "out" / "imu.yaml").string());
  EXPECT_GT(n.rate_hz, 0.0);
}

TEST(ImportMynteye, CamchainInFolderIsUsed) {
  simtest::TempDir tmp;
  makeMynteyeFolder(tmp.path() / "in");
  CameraModel cam = myntEyeSimCamera(0.5);
  writeCamchainYaml((tmp.path() / "in" / "camchain.yaml").string(), cam, "/mynteye/left/image_raw");
  ImportOptions o;
  o.format = "mynteye-folder";
  o.input_dir = (tmp.path() / "in").string();
  o.output_dir = (tmp.path() / "out").string();
  const ImportSummary s = runImport(o);
  EXPECT_TRUE(s.notes.empty() || s.notes[0].find("default") == std::string::npos);
  const CameraModel back = CameraModel::fromKalibrYaml((tmp.path() / "out" / "camchain.yaml").string());
  EXPECT_EQ(back.K.width, 376);
  EXPECT_LT((back.T_cam_imu.matrix() - cam.T_cam_imu.matrix()).norm(), 1e-9);
}

TEST(ImportMynteye, BadInputNamesFileAndLine) {
  simtest::TempDir tmp;
  const fs::path in = tmp.path() / "in";
  makeMynteyeFolder(in);
  ImportOptions o;
  o.format = "mynteye-folder";
  o.input_dir = in.string();
  o.output_dir = (tmp.path() / "out").string();

  // Malformed row (line 3: non-numeric), short row (line 4), non-increasing time (line 3).
  writeText(in / "imu0.csv", "t_us,ax,ay,az,gx,gy,gz\n1000000,0,0,9.8,0,0,0\n1002000,0,0,x9.8,0,0,0\n");
  std::string e = expectImportError(o);
  EXPECT_NE(e.find("imu0.csv:3"), std::string::npos) << e;
  writeText(in / "imu0.csv", "1000000,0,0,9.8,0,0,0\n1002000,0,0,9.8,0,0,0\n\n1004000,0,0,9.8,0,0\n");
  e = expectImportError(o);
  EXPECT_NE(e.find("imu0.csv:4"), std::string::npos) << e;
  EXPECT_NE(e.find("expected 7 fields"), std::string::npos) << e;
  writeText(in / "imu0.csv", "1000000,0,0,9.8,0,0,0\n1000000,0,0,9.8,0,0,0\n");
  e = expectImportError(o);
  EXPECT_NE(e.find("imu0.csv:2"), std::string::npos) << e;
  EXPECT_NE(e.find("not increasing"), std::string::npos) << e;

  // Missing IMU file.
  fs::remove(in / "imu0.csv");
  e = expectImportError(o);
  EXPECT_NE(e.find("imu0.csv"), std::string::npos) << e;
  EXPECT_NE(e.find("missing"), std::string::npos) << e;

  // Unreadable image (not a PNG), and a badly named one.
  writeText(in / "imu0.csv", "1000000,0,0,9.8,0,0,0\n1002000,0,0,9.8,0,0,0\n");
  writeText(in / "left" / "1036333.png", "this is not a png");
  e = expectImportError(o);
  EXPECT_NE(e.find("1036333.png"), std::string::npos) << e;
  EXPECT_NE(e.find("cannot read image"), std::string::npos) << e;
  writeText(in / "left" / "frame_a.png", "x");
  e = expectImportError(o);
  EXPECT_NE(e.find("frame_a.png"), std::string::npos) << e;
}

namespace {

/// EuRoC sample: 6 IMU rows, 2 images, 3 ground-truth rows, sensor.yaml files with OpenCV's %YAML header.
void makeEuroc(const fs::path& root) {
  const fs::path mav = root / "mav0";
  writeText(mav / "imu0" / "data.csv",
            "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],"
            "a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
            "1403636579758555392,-0.099,0.142,0.025,8.13,-0.37,-2.42\n"
            "1403636579763555584,-0.098,0.143,0.026,8.14,-0.38,-2.43\n"
            "1403636579768555520,-0.097,0.144,0.027,8.15,-0.39,-2.44\n"
            "1403636579773555456,-0.096,0.145,0.028,8.16,-0.40,-2.45\n"
            "1403636579778555392,-0.095,0.146,0.029,8.17,-0.41,-2.46\n"
            "1403636579783555584,-0.094,0.147,0.030,8.18,-0.42,-2.47\n");
  writeText(mav / "cam0" / "data.csv",
            "#timestamp [ns],filename\n"
            "1403636579763555584,1403636579763555584.png\n"
            "1403636579813555456,1403636579813555456.png\n");
  fs::create_directories(mav / "cam0" / "data");
  cv::imwrite((mav / "cam0" / "data" / "1403636579763555584.png").string(), pattern(4));
  cv::imwrite((mav / "cam0" / "data" / "1403636579813555456.png").string(), pattern(5));
  writeText(mav / "state_groundtruth_estimate0" / "data.csv",
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
            "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
            "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
            "1403636579758555392,4.688,-1.786,0.783,0.534,-0.153,-0.827,-0.082,-0.027,0.033,-0.807,-0.003,0.021,"
            "0.078,-0.025,0.136,0.076\n"
            "1403636579763555584,4.688,-1.786,0.787,0.534,-0.153,-0.827,-0.082,-0.026,0.033,-0.808,-0.003,0.021,"
            "0.078,-0.025,0.136,0.076\n"
            "1403636579768555520,4.688,-1.786,0.791,0.534,-0.153,-0.827,-0.082,-0.026,0.034,-0.808,-0.003,0.021,"
            "0.078,-0.025,0.136,0.076\n");
  writeText(mav / "cam0" / "sensor.yaml",
            "%YAML:1.0\n"
            "sensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\n"
            "T_BS:\n  cols: 4\n  rows: 4\n"
            "  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,\n"
            "         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,\n"
            "        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,\n"
            "         0.0, 0.0, 0.0, 1.0]\n"
            "rate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n"
            "intrinsics: [458.654, 457.296, 367.215, 248.375]\n"
            "distortion_model: radial-tangential\n"
            "distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n");
  writeText(mav / "imu0" / "sensor.yaml",
            "%YAML:1.0\nsensor_type: imu\ncomment: VI-Sensor IMU (ADIS16448)\n"
            "T_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n"
            "rate_hz: 200\n"
            "gyroscope_noise_density: 1.6968e-04\ngyroscope_random_walk: 1.9393e-05\n"
            "accelerometer_noise_density: 2.0000e-3\naccelerometer_random_walk: 3.0000e-3\n");
}

}  // namespace

TEST(ImportEuroc, RoundTrip) {
  simtest::TempDir tmp;
  makeEuroc(tmp.path() / "in");
  ImportOptions o;
  o.format = "euroc";
  o.input_dir = (tmp.path() / "in").string();
  o.output_dir = (tmp.path() / "out").string();
  const ImportSummary s = runImport(o);
  EXPECT_EQ(s.images, 2u);
  EXPECT_EQ(s.imu, 6u);
  EXPECT_EQ(s.poses, 3u);
  const BagContents c = readBag(s.bag_path);
  ASSERT_EQ(c.images.size(), 2u);
  ASSERT_EQ(c.imu.size(), 6u);
  ASSERT_EQ(c.poses.size(), 3u);
  EXPECT_EQ(c.images[1].header.stamp.toNSec(), 1403636579813555456ull);
  const cv::Mat ref = pattern(5);
  EXPECT_TRUE(std::equal(c.images[1].data.begin(), c.images[1].data.end(), ref.data));
  // EuRoC columns: gyro first, then accelerometer.
  EXPECT_DOUBLE_EQ(c.imu[0].angular_velocity.x, -0.099);
  EXPECT_DOUBLE_EQ(c.imu[0].linear_acceleration.x, 8.13);
  EXPECT_DOUBLE_EQ(c.imu[5].linear_acceleration.z, -2.47);
  EXPECT_EQ(c.imu[1].header.stamp.toNSec(), 1403636579763555584ull);
  EXPECT_DOUBLE_EQ(c.poses[1].pose.position.z, 0.787);
  const Eigen::Quaterniond q(c.poses[0].pose.orientation.w, c.poses[0].pose.orientation.x,
                             c.poses[0].pose.orientation.y, c.poses[0].pose.orientation.z);
  EXPECT_NEAR(q.norm(), 1.0, 1e-9);
  EXPECT_NEAR(std::abs(q.w()), 0.534 / Eigen::Vector4d(0.534, -0.153, -0.827, -0.082).norm(), 1e-9);
  for (std::size_t i = 1; i < c.bag_times.size(); ++i) EXPECT_LE(c.bag_times[i - 1], c.bag_times[i]);
  // Calibration: intrinsics and T_cam_imu = T_BS(cam)^-1 (IMU = body).
  const CameraModel cam = CameraModel::fromKalibrYaml((tmp.path() / "out" / "camchain.yaml").string());
  EXPECT_NEAR(cam.K.fx, 458.654, 1e-9);
  EXPECT_NEAR(cam.K.cy, 248.375, 1e-9);
  EXPECT_NEAR(cam.distortion_coeffs[3], 1.76187114e-05, 1e-15);
  Eigen::Matrix4d T_BS;
  T_BS << 0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975, 0.999557249008, 0.0149672133247,
      0.025715529948, -0.064676986768, -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949, 0, 0, 0,
      1;
  EXPECT_LT((cam.T_cam_imu.matrix() - T_BS.inverse()).norm(), 1e-6);
  const ImuNoiseParams n = readImuYaml((tmp.path() / "out" / "imu.yaml").string());
  EXPECT_DOUBLE_EQ(n.rate_hz, 200.0);
  EXPECT_DOUBLE_EQ(n.accel_random_walk, 3.0e-3);
}

TEST(ImportEuroc, BadInputNamesFileAndLine) {
  simtest::TempDir tmp;
  const fs::path in = tmp.path() / "in";
  makeEuroc(in);
  ImportOptions o;
  o.format = "euroc";
  o.input_dir = in.string();
  o.output_dir = (tmp.path() / "out").string();
  // Image list pointing at a missing file (line 3).
  writeText(in / "mav0" / "cam0" / "data.csv", "#timestamp [ns],filename\n1,1403636579763555584.png\n2,nope.png\n");
  std::string e = expectImportError(o);
  EXPECT_NE(e.find("data.csv:3"), std::string::npos) << e;
  EXPECT_NE(e.find("nope.png"), std::string::npos) << e;
  // Ground truth row with too few fields.
  makeEuroc(in);
  writeText(in / "mav0" / "state_groundtruth_estimate0" / "data.csv", "#t\n1,2,3\n");
  e = expectImportError(o);
  EXPECT_NE(e.find("state_groundtruth_estimate0/data.csv:2"), std::string::npos) << e;
  // Corrupt camera calibration.
  makeEuroc(in);
  writeText(in / "mav0" / "cam0" / "sensor.yaml", "%YAML:1.0\nintrinsics: [1, 2]\n");
  e = expectImportError(o);
  EXPECT_NE(e.find("sensor.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("intrinsics"), std::string::npos) << e;
  // Not a EuRoC folder at all.
  o.input_dir = (tmp.path() / "nothing").string();
  e = expectImportError(o);
  EXPECT_NE(e.find("mav0"), std::string::npos) << e;
}

TEST(ImportCli, ParsesAndRejects) {
  ImportOptions o;
  std::string err;
  EXPECT_EQ(parseImportArgs({"--format", "euroc", "--input", "a", "--output", "b"}, &o, &err), 0) << err;
  EXPECT_EQ(o.input_dir, "a");
  EXPECT_EQ(parseImportArgs({"--help"}, &o, &err), 1);
  ImportOptions o2;
  EXPECT_EQ(parseImportArgs({"--format", "kitti", "--input", "a", "--output", "b"}, &o2, &err), -1);
  EXPECT_NE(err.find("kitti"), std::string::npos);
  ImportOptions o3;
  EXPECT_EQ(parseImportArgs({"--format", "euroc", "--input"}, &o3, &err), -1);
  EXPECT_NE(err.find("--input"), std::string::npos);
}
