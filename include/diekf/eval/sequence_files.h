// An exported sequence: what diekf_bag_runner feeds the estimator (IMU samples and 8-bit images, in its order and
// with its stamps), as plain files that a ROS-free program can read (diekf_replay; `make cross-check` runs it on
// ARM under emulation). ROS-free. Layout (docs/conventions.md section 7):
//   DIR/camchain.yaml          the Kalibr calibration the runner used (a copy)
//   DIR/events.csv             "# diekf sequence 1", then one event per line in processing order:
//                                imu,t,ax,ay,az,gx,gy,gz   (s; m/s^2; rad/s; 17 significant digits: exact)
//                                image,t,images/000000.pgm
//   DIR/images/NNNNNN.pgm      8-bit binary PGM (P5)
#pragma once

#include <cstddef>
#include <fstream>
#include <string>

#include <opencv2/core.hpp>

#include "diekf/types.h"

namespace diekf {
namespace eval {

/// Writes a sequence folder (created if needed). Throws std::runtime_error naming the file on any failure.
class SequenceWriter {
 public:
  /// `camchain_path`: the calibration file to copy into the folder.
  SequenceWriter(const std::string& dir, const std::string& camchain_path);
  SequenceWriter(const SequenceWriter&) = delete;
  SequenceWriter& operator=(const SequenceWriter&) = delete;
  void addImu(const ImuSample& sample);
  /// `grey`: CV_8UC1.
  void addImage(double t_s, const cv::Mat& grey);
  void close();
  std::size_t images() const { return images_; }

 private:
  std::string dir_;
  std::string events_path_;
  std::ofstream events_;
  std::size_t images_ = 0;
};

struct SequenceEvent {
  enum class Kind { kImu, kImage };
  Kind kind = Kind::kImu;
  ImuSample imu;           ///< kImu
  double image_t_s = 0.0;  ///< kImage: stamp
  std::string image_path;  ///< kImage: full path of the PGM
};

/// Reads the events of a sequence folder one by one. Throws std::runtime_error naming file and line on a missing
/// folder, a wrong first line or a malformed event.
class SequenceReader {
 public:
  explicit SequenceReader(const std::string& dir);
  /// The next event; false at the end.
  bool next(SequenceEvent* event);
  std::string camchainPath() const;

 private:
  std::string dir_;
  std::string events_path_;
  std::ifstream events_;
  int line_ = 0;
};

/// 8-bit binary PGM (P5, maxval 255). Both throw std::runtime_error naming the file.
void writePgm(const std::string& path, const cv::Mat& grey);
cv::Mat readPgm(const std::string& path);

}  // namespace eval
}  // namespace diekf
