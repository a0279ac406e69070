// Writing sequences in the project's bag layout (docs/conventions.md §2) and Kalibr calibration files (§3).
#pragma once

#include <cstdint>
#include <memory>
#include <ostream>
#include <string>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/sim/imu_sim.h"
#include "diekf/sim/trajectory.h"
#include "diekf/types.h"

namespace rosbag {
class Bag;
}

namespace diekf {
namespace sim {

/// A double as YAML text: 12 significant digits, always with a decimal point or exponent (so it reads as a float).
std::string yamlNumber(double v);
/// The 4 rows of a matrix as a YAML block sequence of flow lists ("  - [a, b, c, d]"), as Kalibr writes T_cam_imu.
void writeYamlMatrixRows(std::ostream& f, const Eigen::Matrix4d& T);

struct TopicNames {
  std::string image = "/mynteye/left/image_raw";
  std::string camera_info = "/mynteye/left/camera_info";
  std::string imu = "/mynteye/imu/data_raw";
  std::string pose = "/mocap/pose";
  std::string plane = "/ground_truth/plane";
  std::string camera_frame = "mynteye_left_frame";
  std::string imu_frame = "mynteye_imu_frame";
  std::string world_frame = "world";
};

/// MYNT EYE S left camera (752x480, radtan) looking down from a flat-mounted IMU (x forward, y left, z up):
/// x_C = y_I, y_C = x_I, z_C = -z_I (turned 90 deg about the optical axis against the IMU axes), misaligned by
/// ~0.8 deg, camera centre a few cm from the IMU. `scale` scales the resolution and intrinsics (tests).
CameraModel myntEyeSimCamera(double scale = 1.0);

/// Kalibr camchain YAML with cam0 (throws std::runtime_error naming the file on failure).
void writeCamchainYaml(const std::string& path, const CameraModel& cam, const std::string& rostopic);
/// Kalibr IMU YAML (noise densities, random walks, update rate, topic).
void writeImuYaml(const std::string& path, const ImuNoiseParams& noise, const std::string& rostopic);
/// Reads the noise densities and rate of a Kalibr IMU YAML (flat, or nested under imu0); throws naming the
/// file and key.
ImuNoiseParams readImuYaml(const std::string& path);

/// Stamp on the bag clock: `start_s` + `t_s` with nanosecond rounding.
struct BagClock {
  std::int64_t start_ns = 1600000000LL * 1000000000LL;
  std::int64_t toNs(double t_s) const;
};

/// Thin writer over rosbag::Bag for the project's topics. Messages may be written in any order,
/// but the simulator and importers write them in stamp order.
class SequenceBagWriter {
 public:
  /// Opens `path` for writing (throws std::runtime_error naming the file). `lz4` enables chunk compression.
  SequenceBagWriter(const std::string& path, TopicNames topics = TopicNames(), bool lz4 = false);
  ~SequenceBagWriter();
  SequenceBagWriter(const SequenceBagWriter&) = delete;
  SequenceBagWriter& operator=(const SequenceBagWriter&) = delete;

  void writeImage(std::int64_t stamp_ns, const cv::Mat& mono8, std::uint32_t seq);
  void writeCameraInfo(std::int64_t stamp_ns, const CameraModel& cam, std::uint32_t seq);
  void writeImu(std::int64_t stamp_ns, const Vec3& accel_mps2, const Vec3& gyro_radps, std::uint32_t seq);
  void writePose(std::int64_t stamp_ns, const Mat3& R_WI, const Vec3& p_WI, std::uint32_t seq);
  void writePlane(std::int64_t stamp_ns, const Plane& plane);
  void close();

  const TopicNames& topics() const { return topics_; }

 private:
  TopicNames topics_;
  std::unique_ptr<rosbag::Bag> bag_;
};

}  // namespace sim
}  // namespace diekf
