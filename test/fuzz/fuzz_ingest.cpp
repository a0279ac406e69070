// libFuzzer target (built by `make fuzz`, outside the catkin tree): an arbitrary byte stream is decoded into a
// sequence of IMU samples, images, resets and result reads fed to one diekf::Estimator. Checks: no crash, no
// sanitizer report, no exception escaping the facade, and every result finite.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>

#include <opencv2/core.hpp>

#include "diekf/estimator.h"

namespace {

/// Consumes bytes from the input; zeros when exhausted.
class Reader {
 public:
  Reader(const uint8_t* data, size_t size) : data_(data), size_(size) {}
  bool done() const { return pos_ >= size_; }
  uint8_t u8() { return pos_ < size_ ? data_[pos_++] : 0; }
  int16_t i16() { return static_cast<int16_t>(u8() | (u8() << 8)); }
  double rawDouble() {
    uint64_t bits = 0;
    for (int i = 0; i < 8; ++i) bits |= static_cast<uint64_t>(u8()) << (8 * i);
    double v;
    std::memcpy(&v, &bits, sizeof v);
    return v;
  }

 private:
  const uint8_t* data_;
  size_t size_;
  size_t pos_ = 0;
};

diekf::CameraModel smallCamera() {
  diekf::CameraModel cam;
  cam.K.width = 40;
  cam.K.height = 30;
  cam.K.fx = cam.K.fy = 30.0;
  cam.K.cx = 19.5;
  cam.K.cy = 14.5;
  cam.distortion = diekf::DistortionModel::kRadTan;
  cam.distortion_coeffs = diekf::Vec4(-0.2, 0.05, 0.001, -0.001);
  return cam;
}

void checkFinite(const diekf::FrameResult& r) {
  if (!r.state.allFinite() || !r.covariance.allFinite() || !std::isfinite(r.t_s) ||
      !std::isfinite(r.distance_m()) || !r.velocity_mps().allFinite() || !std::isfinite(r.photometric_rms) ||
      !std::isfinite(r.valid_ratio)) {
    std::abort();  // a non-finite value would have been published
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const diekf::CameraModel cam = smallCamera();
  Reader in(data, size);
  diekf::EstimatorParams params;
  params.preprocess.working_width_px = 16 + in.u8() % 17;
  params.mode = in.u8() % 8 == 0 ? diekf::UpdateMode::kEkf : diekf::UpdateMode::kIterated;
  params.feature.working_width_px = 40;
  diekf::Estimator est(cam, params);
  double t_s = 0.0;  // running stamp, s
  diekf::FrameResult r;
  int ops = 0;
  while (!in.done() && ops++ < 4000) {
    const uint8_t op = in.u8();
    switch (op % 8) {
      case 0:
      case 1:
      case 2:
      case 3: {  // plausible IMU sample: small stamp step (may be 0 or negative), values around hover
        t_s += in.i16() * 1e-5;
        diekf::ImuSample s;
        s.t_s = t_s;
        s.accel_mps2 = diekf::Vec3(in.i16() * 1e-3, in.i16() * 1e-3, 9.81 + in.i16() * 1e-3);
        s.gyro_radps = diekf::Vec3(in.i16() * 1e-4, in.i16() * 1e-4, in.i16() * 1e-4);
        est.addImu(s);
        break;
      }
      case 4: {  // raw IMU sample: any bit pattern (NaN, Inf, huge, denormal)
        diekf::ImuSample s;
        s.t_s = (op & 0x80) ? in.rawDouble() : t_s + in.i16() * 1e-3;
        for (int i = 0; i < 3; ++i) s.accel_mps2[i] = in.rawDouble();
        for (int i = 0; i < 3; ++i) s.gyro_radps[i] = in.rawDouble();
        est.addImu(s);
        break;
      }
      case 5:
      case 6: {  // image: mostly the calibration size, any type, patterned or constant content
        const uint8_t shape = in.u8();
        const int w = (shape & 0x0f) == 0 ? in.u8() % 64 : cam.K.width;
        const int h = (shape & 0xf0) == 0 ? in.u8() % 48 : cam.K.height;
        static const int kTypes[] = {CV_8UC1, CV_8UC1, CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_32FC1, CV_8UC2};
        const int type = kTypes[in.u8() % 8];
        cv::Mat img(h, w, type);
        const uint8_t fill = in.u8();
        if (img.empty()) {
          // nothing to fill: an empty image is a case of its own
        } else if (fill % 3 == 0) {
          img.setTo(cv::Scalar::all(in.u8()));  // uniform, black or saturated
        } else {
          cv::RNG rng(in.u8() | (in.u8() << 8));
          rng.fill(img, cv::RNG::UNIFORM, 0, fill % 3 == 1 ? 256 : 4);
        }
        double t_img = t_s + in.i16() * 1e-4;
        if (op & 0x80) t_img = in.rawDouble();
        est.addImage(t_img, img);
        break;
      }
      default: {
        const uint8_t what = in.u8();
        if (what == 0) est.reset("fuzz");
        if (what == 1) t_s += in.i16() * 1e-2;  // large time jump, either way
        break;
      }
    }
    while (est.popResult(&r)) checkFinite(r);
    est.takeWarning();
  }
  if (!est.state().allFinite()) std::abort();
  return 0;
}
