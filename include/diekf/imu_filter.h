// IMU preprocessing: rotate raw readings into the camera frame (with the lever-arm term), low-pass filter
// (Butterworth, cascaded biquads) and decimate (500 Hz -> 100 Hz by default), with the filter's delay
// compensated in the output stamps.
#pragma once

#include <vector>

#include "diekf/camera_model.h"
#include "diekf/params.h"

namespace diekf {

class ImuPreprocessor {
 public:
  ImuPreprocessor(const Eigen::Isometry3d& T_cam_imu, const ImuParams& params);

  /// Feeds one raw sample (IMU frame, IMU clock). Returns true and fills `out` (camera frame, stamp on the IMU
  /// clock minus the filter delay) when a decimated sample is ready.
  bool push(const ImuSample& raw_imu, ImuSample* out);
  /// Clears the filter memory (next sample re-primes it).
  void reset();
  /// Low-frequency group delay of the filter, s (subtracted from output stamps when compensation is on).
  double delay_s() const { return delay_s_; }

 private:
  struct Biquad {
    double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0;  // normalised (a0 = 1)
  };
  struct BiquadState {
    Eigen::Matrix<double, 6, 1> z1 = Eigen::Matrix<double, 6, 1>::Zero();
    Eigen::Matrix<double, 6, 1> z2 = Eigen::Matrix<double, 6, 1>::Zero();
  };
  Eigen::Matrix<double, 6, 1> filter(const Eigen::Matrix<double, 6, 1>& in);

  ImuParams params_;
  Mat3 R_CI_;
  Vec3 r_imu_to_cam_C_;      // lever arm from the IMU origin to the camera centre, in C, m
  std::vector<Biquad> sections_;
  std::vector<BiquadState> states_;
  double delay_s_ = 0.0;
  bool primed_ = false;
  int counter_ = 0;
  Vec3 last_gyro_C_ = Vec3::Zero();
  double last_t_s_ = 0.0;
};

}  // namespace diekf
