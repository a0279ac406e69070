// The MYNT EYE S left camera of the project's sample calibration (config/mynteye_camchain.yaml): 752x480,
// radtan distortion. Intrinsics only (T_cam_imu identity), for tests of the camera model and preprocessing.
#pragma once

#include "diekf/camera_model.h"

namespace diekf {

inline CameraModel myntEyeCamera() {
  CameraModel m;
  m.K = PinholeK{364.91, 364.97, 379.91, 245.53, 752, 480};
  m.distortion = DistortionModel::kRadTan;
  m.distortion_coeffs = Vec4(-0.3178, 0.0962, -0.00011, 0.00033);
  return m;
}

}  // namespace diekf
