#include "diekf/ros/camera_info_calibration.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace diekf_ros {

namespace {

[[noreturn]] void fail(const std::string& topic, const std::string& field, const std::string& what) {
  throw std::runtime_error("camera_info on " + topic + ": " + field + ": " + what);
}

void requireZero(const sensor_msgs::CameraInfo& info, size_t from, const std::string& topic, const std::string& why) {
  for (size_t i = from; i < info.D.size(); ++i) {
    if (info.D[i] != 0.0) {
      std::ostringstream os;
      os << "D[" << i << "] = " << info.D[i] << " " << why;
      fail(topic, "D", os.str());
    }
  }
}

}  // namespace

diekf::CameraModel cameraModelFromCameraInfo(const sensor_msgs::CameraInfo& info, const Eigen::Isometry3d& T_cam_imu,
                                             const std::string& topic) {
  diekf::CameraModel m;
  if (info.width == 0 || info.height == 0 || info.width > 65535 || info.height > 65535) {
    fail(topic, "width/height", "no usable image size (" + std::to_string(info.width) + "x" +
                                    std::to_string(info.height) + ")");
  }
  m.K.width = static_cast<int>(info.width);
  m.K.height = static_cast<int>(info.height);
  m.K.fx = info.K[0];
  m.K.fy = info.K[4];
  m.K.cx = info.K[2];
  m.K.cy = info.K[5];
  for (double v : info.K) {
    if (!std::isfinite(v)) fail(topic, "K", "non-finite entry");
  }
  for (double v : info.D) {
    if (!std::isfinite(v)) fail(topic, "D", "non-finite entry");
  }
  if (!(m.K.fx > 0.0) || !(m.K.fy > 0.0)) fail(topic, "K", "focal lengths must be positive (uncalibrated camera?)");
  if (info.K[1] != 0.0) fail(topic, "K", "skew K[1] is not supported");
  if (info.K[3] != 0.0 || info.K[6] != 0.0 || info.K[7] != 0.0 || info.K[8] != 1.0) {
    fail(topic, "K", "not of the form [fx 0 cx; 0 fy cy; 0 0 1]");
  }
  if (info.binning_x > 1 || info.binning_y > 1) fail(topic, "binning_x/binning_y", "binning is not supported");
  const auto& roi = info.roi;
  if ((roi.width != 0 && roi.width != info.width) || (roi.height != 0 && roi.height != info.height) ||
      roi.x_offset != 0 || roi.y_offset != 0) {
    fail(topic, "roi", "a region of interest is not supported");
  }

  const std::string& model = info.distortion_model;
  const size_t n = info.D.size();
  if (model == "plumb_bob") {
    if (n != 4 && n != 5) fail(topic, "D", "plumb_bob needs 5 coefficients (k1 k2 p1 p2 k3), got " + std::to_string(n));
    m.distortion = diekf::DistortionModel::kRadTan;
    m.distortion_coeffs = diekf::Vec4(info.D[0], info.D[1], info.D[2], info.D[3]);
    if (n == 5) m.radial_extra[0] = info.D[4];
  } else if (model == "rational_polynomial") {
    if (n < 8) {
      fail(topic, "D", "rational_polynomial needs 8 coefficients (k1 k2 p1 p2 k3 k4 k5 k6), got " +
                           std::to_string(n));
    }
    requireZero(info, 8, topic, "(thin-prism or tilt terms are not supported)");
    m.distortion = diekf::DistortionModel::kRadTan;
    m.distortion_coeffs = diekf::Vec4(info.D[0], info.D[1], info.D[2], info.D[3]);
    m.radial_extra = diekf::Vec4(info.D[4], info.D[5], info.D[6], info.D[7]);
  } else if (model == "equidistant" || model == "fisheye" || model == "KANNALA_BRANDT") {
    if (n != 4 && n != 5) fail(topic, "D", model + " needs 4 coefficients (k1 k2 k3 k4), got " + std::to_string(n));
    requireZero(info, 4, topic, "(a 5th equidistant coefficient is not supported)");
    m.distortion = diekf::DistortionModel::kEquidistant;
    m.distortion_coeffs = diekf::Vec4(info.D[0], info.D[1], info.D[2], info.D[3]);
  } else if (model.empty() || model == "none") {
    requireZero(info, 0, topic, "with no distortion model");
    m.distortion = diekf::DistortionModel::kNone;
  } else {
    fail(topic, "distortion_model",
         "'" + model + "' is not supported (plumb_bob, rational_polynomial, equidistant, fisheye, KANNALA_BRANDT)");
  }
  m.T_cam_imu = T_cam_imu;
  m.timeshift_cam_imu_s = 0.0;  // camera_info has none: the driver's stamps are taken as they are
  return m;
}

}  // namespace diekf_ros
