#include "diekf/sim/sequence_io.h"

#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <stdexcept>

#include <geometry_msgs/PoseStamped.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <shape_msgs/Plane.h>
#include <yaml-cpp/yaml.h>

namespace diekf {
namespace sim {
namespace {

ros::Time toRosTime(std::int64_t ns) {
  ros::Time t;
  t.fromNSec(static_cast<std::uint64_t>(ns));
  return t;
}

std::string num(double v) { return yamlNumber(v); }

}  // namespace

std::string yamlNumber(double v) {
  std::ostringstream os;
  os << std::setprecision(12) << v;
  std::string s = os.str();
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

void writeYamlMatrixRows(std::ostream& f, const Eigen::Matrix4d& T) {
  for (int r = 0; r < 4; ++r)
    f << "  - [" << num(T(r, 0)) << ", " << num(T(r, 1)) << ", " << num(T(r, 2)) << ", " << num(T(r, 3)) << "]\n";
}

CameraModel myntEyeSimCamera(double scale) {
  CameraModel cam;
  cam.K.fx = 364.91 * scale;
  cam.K.fy = 364.97 * scale;
  // Pixel centres at integer coordinates: scaling keeps the image-edge geometry.
  cam.K.cx = (379.91 + 0.5) * scale - 0.5;
  cam.K.cy = (245.53 + 0.5) * scale - 0.5;
  cam.K.width = static_cast<int>(std::lround(752 * scale));
  cam.K.height = static_cast<int>(std::lround(480 * scale));
  cam.distortion = DistortionModel::kRadTan;
  cam.distortion_coeffs = Vec4(-0.3178, 0.0962, -0.00011, 0.00033);
  // IMU frame (flat-mounted): x forward, y left, z up. Camera looks down (z_C = -z_I) and is turned 90 deg
  // about its optical axis against the IMU: x_C = y_I (image right = body left), y_C = x_I (image down = forward).
  Mat3 R_CI;
  R_CI << 0, 1, 0, 1, 0, 0, 0, 0, -1;
  // Mounting error ~1 deg about a fixed oblique axis.
  const Mat3 R_err = Eigen::AngleAxisd(0.8 * M_PI / 180.0, Vec3(0.6, -0.3, 0.74).normalized()).toRotationMatrix();
  R_CI = R_err * R_CI;
  const Vec3 p_IC(0.035, -0.020, -0.012);  // camera centre in I (m)
  cam.T_cam_imu.linear() = R_CI;
  cam.T_cam_imu.translation() = -R_CI * p_IC;
  cam.timeshift_cam_imu_s = 0.0;
  cam.rostopic = "/mynteye/left/image_raw";
  return cam;
}

void writeCamchainYaml(const std::string& path, const CameraModel& cam, const std::string& rostopic) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
  const char* model = cam.distortion == DistortionModel::kEquidistant ? "equidistant" : "radtan";
  f << "cam0:\n  camera_model: pinhole\n";
  f << "  intrinsics: [" << num(cam.K.fx) << ", " << num(cam.K.fy) << ", " << num(cam.K.cx) << ", " << num(cam.K.cy)
    << "]\n";
  f << "  distortion_model: " << model << "\n";
  f << "  distortion_coeffs: [" << num(cam.distortion_coeffs[0]) << ", " << num(cam.distortion_coeffs[1]) << ", "
    << num(cam.distortion_coeffs[2]) << ", " << num(cam.distortion_coeffs[3]) << "]\n";
  f << "  resolution: [" << cam.K.width << ", " << cam.K.height << "]\n";
  f << "  T_cam_imu:\n";
  writeYamlMatrixRows(f, cam.T_cam_imu.matrix());
  f << "  timeshift_cam_imu: " << num(cam.timeshift_cam_imu_s) << "\n";
  f << "  rostopic: " << rostopic << "\n";
  if (!f) throw std::runtime_error("error writing '" + path + "'");
}

void writeImuYaml(const std::string& path, const ImuNoiseParams& n, const std::string& rostopic) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
  f << "# Kalibr IMU noise model (continuous time)\n";
  f << "accelerometer_noise_density: " << num(n.accel_noise_density) << "  # m/s^2/sqrt(Hz)\n";
  f << "accelerometer_random_walk: " << num(n.accel_random_walk) << "  # m/s^3/sqrt(Hz)\n";
  f << "gyroscope_noise_density: " << num(n.gyro_noise_density) << "  # rad/s/sqrt(Hz)\n";
  f << "gyroscope_random_walk: " << num(n.gyro_random_walk) << "  # rad/s^2/sqrt(Hz)\n";
  f << "update_rate: " << num(n.rate_hz) << "  # Hz\n";
  f << "rostopic: " << rostopic << "\n";
  if (!f) throw std::runtime_error("error writing '" + path + "'");
}

ImuNoiseParams readImuYaml(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot parse '" + path + "': " + e.what());
  }
  if (root["imu0"]) root = root["imu0"];  // camchain-imucam style nesting is accepted too
  ImuNoiseParams n;
  const auto get = [&](const char* key, double* out) {
    if (!root[key]) throw std::runtime_error("'" + path + "': missing key '" + key + "'");
    try {
      *out = root[key].as<double>();
    } catch (const std::exception&) {
      throw std::runtime_error("'" + path + "': key '" + key + "' is not a number");
    }
  };
  get("accelerometer_noise_density", &n.accel_noise_density);
  get("accelerometer_random_walk", &n.accel_random_walk);
  get("gyroscope_noise_density", &n.gyro_noise_density);
  get("gyroscope_random_walk", &n.gyro_random_walk);
  get("update_rate", &n.rate_hz);
  return n;
}

std::int64_t BagClock::toNs(double t_s) const { return start_ns + static_cast<std::int64_t>(std::llround(t_s * 1e9)); }

SequenceBagWriter::SequenceBagWriter(const std::string& path, TopicNames topics, bool lz4)
    : topics_(std::move(topics)), bag_(new rosbag::Bag) {
  try {
    bag_->open(path, rosbag::bagmode::Write);
    if (lz4) bag_->setCompression(rosbag::compression::LZ4);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot open '" + path + "' for writing: " + e.what());
  }
}

SequenceBagWriter::~SequenceBagWriter() {
  try {
    close();
  } catch (...) {
  }
}

void SequenceBagWriter::close() {
  if (bag_ && bag_->isOpen()) bag_->close();
}

void SequenceBagWriter::writeImage(std::int64_t stamp_ns, const cv::Mat& mono8, std::uint32_t seq) {
  if (mono8.type() != CV_8UC1) throw std::invalid_argument("writeImage: mono8 image expected");
  sensor_msgs::Image m;
  m.header.stamp = toRosTime(stamp_ns);
  m.header.seq = seq;
  m.header.frame_id = topics_.camera_frame;
  m.height = static_cast<std::uint32_t>(mono8.rows);
  m.width = static_cast<std::uint32_t>(mono8.cols);
  m.encoding = "mono8";
  m.is_bigendian = 0;
  m.step = static_cast<std::uint32_t>(mono8.cols);
  m.data.resize(static_cast<std::size_t>(mono8.rows) * mono8.cols);
  for (int r = 0; r < mono8.rows; ++r)
    std::copy(mono8.ptr<unsigned char>(r), mono8.ptr<unsigned char>(r) + mono8.cols, &m.data[static_cast<std::size_t>(r) * mono8.cols]);
  bag_->write(topics_.image, m.header.stamp, m);
}

void SequenceBagWriter::writeCameraInfo(std::int64_t stamp_ns, const CameraModel& cam, std::uint32_t seq) {
  sensor_msgs::CameraInfo m;
  m.header.stamp = toRosTime(stamp_ns);
  m.header.seq = seq;
  m.header.frame_id = topics_.camera_frame;
  m.width = static_cast<std::uint32_t>(cam.K.width);
  m.height = static_cast<std::uint32_t>(cam.K.height);
  if (cam.distortion == DistortionModel::kEquidistant) {
    m.distortion_model = "equidistant";
    m.D = {cam.distortion_coeffs[0], cam.distortion_coeffs[1], cam.distortion_coeffs[2], cam.distortion_coeffs[3]};
  } else {
    m.distortion_model = "plumb_bob";
    m.D = {cam.distortion_coeffs[0], cam.distortion_coeffs[1], cam.distortion_coeffs[2], cam.distortion_coeffs[3], 0.0};
  }
  m.K = {cam.K.fx, 0, cam.K.cx, 0, cam.K.fy, cam.K.cy, 0, 0, 1};
  m.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  m.P = {cam.K.fx, 0, cam.K.cx, 0, 0, cam.K.fy, cam.K.cy, 0, 0, 0, 1, 0};
  bag_->write(topics_.camera_info, m.header.stamp, m);
}

void SequenceBagWriter::writeImu(std::int64_t stamp_ns, const Vec3& a, const Vec3& w, std::uint32_t seq) {
  sensor_msgs::Imu m;
  m.header.stamp = toRosTime(stamp_ns);
  m.header.seq = seq;
  m.header.frame_id = topics_.imu_frame;
  m.orientation_covariance[0] = -1.0;  // no orientation
  m.linear_acceleration.x = a.x();
  m.linear_acceleration.y = a.y();
  m.linear_acceleration.z = a.z();
  m.angular_velocity.x = w.x();
  m.angular_velocity.y = w.y();
  m.angular_velocity.z = w.z();
  bag_->write(topics_.imu, m.header.stamp, m);
}

void SequenceBagWriter::writePose(std::int64_t stamp_ns, const Mat3& R_WI, const Vec3& p_WI, std::uint32_t seq) {
  geometry_msgs::PoseStamped m;
  m.header.stamp = toRosTime(stamp_ns);
  m.header.seq = seq;
  m.header.frame_id = topics_.world_frame;
  const Eigen::Quaterniond q(R_WI);
  m.pose.position.x = p_WI.x();
  m.pose.position.y = p_WI.y();
  m.pose.position.z = p_WI.z();
  m.pose.orientation.w = q.w();
  m.pose.orientation.x = q.x();
  m.pose.orientation.y = q.y();
  m.pose.orientation.z = q.z();
  bag_->write(topics_.pose, m.header.stamp, m);
}

void SequenceBagWriter::writePlane(std::int64_t stamp_ns, const Plane& plane) {
  shape_msgs::Plane m;
  m.coef = {plane.n.x(), plane.n.y(), plane.n.z(), plane.e_m};
  bag_->write(topics_.plane, toRosTime(stamp_ns), m);
}

}  // namespace sim
}  // namespace diekf
