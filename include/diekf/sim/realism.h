// "Realistic camera" effects of the simulator: rolling shutter, image time offset, calibration errors in the
// written camchain, defocus, auto-exposure steps and view-dependent (non-Lambertian) ground patches.
// The rendering and the IMU always use the true camera; only what is written for the estimator is perturbed.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "diekf/camera_model.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {

/// Values of the realism options (all off = clean, today's perfect camera).
struct RealismOptions {
  double rolling_shutter_ms = 0.0;       ///< readout time top row -> bottom row (ms); 0 = global shutter
  double time_offset_ms = 0.0;           ///< image stamp = true capture time + offset (ms)
  double intrinsics_error_pct = 0.0;     ///< written fu, fv scaled by 1 + p; pu += p w/2, pv -= p h/2 (p = pct/100)
  double extrinsic_rot_error_deg = 0.0;  ///< written R_CI rotated by this angle about kExtrinsicErrorAxisC
  double defocus_px = 0.0;               ///< Gaussian blur sigma at full (752x480) resolution (px)
  bool exposure_steps = false;           ///< auto-exposure: gain steps of 10-25 % every 1-3 s
  double non_lambertian = 0.0;           ///< amplitude of the specular term on the glossy patches (0..1)
};

/// The presets of --realism: "clean" (all off) and "realistic". Returns false for an unknown name.
bool realismPreset(const std::string& name, RealismOptions* out);

/// Axis (camera frame, unit) of the extrinsic rotation error: (1, 1, 0) / sqrt(2).
Eigen::Vector3d extrinsicErrorAxisC();

/// The calibration written for the estimator: intrinsics and T_cam_imu perturbed as documented in
/// RealismOptions (distortion, resolution and timeshift_cam_imu = 0 unchanged). The camera centre in the IMU
/// frame is kept: only the rotation of T_cam_imu is wrong.
CameraModel writtenCalibration(const CameraModel& truth, const RealismOptions& r);

/// Capture time offset of image row `v` (0 = top) of an image with `height` rows against the stamp time
/// (the middle row): readout * (v / (height - 1) - 0.5) seconds.
double rowTimeOffset(int v, int height, double readout_s);

/// Auto-exposure steps: the gain multiplier is 1 until the first step; then, every 1-3 s (uniform), it is
/// multiplied by 1 +- (0.10..0.25) (uniform size, random sign, the sign chosen back toward 1 when the level has
/// left [0.7, 1.4]). Deterministic for the seed.
class ExposureSteps {
 public:
  ExposureSteps() = default;
  ExposureSteps(std::uint64_t seed, double duration_s);
  /// Gain multiplier at time t (s); 1 when built without steps.
  double gain(double t_s) const;
  const std::vector<double>& stepTimes() const { return times_; }
  const std::vector<double>& levels() const { return levels_; }  ///< level from stepTimes()[i] on

 private:
  std::vector<double> times_, levels_;
};

/// Glossy ground patches: a few smooth blobs covering ~20 % of the ground (periodic over 4 m x 4 m in the
/// plane's texture coordinates, seeded) with a specular term added to the texture's radiance:
///   L += amplitude * texture_mean * mask(X) * max(0, refl . l)^shininess,
/// refl = the viewing ray (camera -> X) reflected about the plane normal, l = a fixed light direction in W
/// (unit, toward the light, ~22 deg from vertical). The highlight follows the camera, not the texture.
class SpecularPatches {
 public:
  static constexpr int kGrid = 256;           ///< mask samples per period side
  static constexpr double kPeriodM = 4.0;     ///< mask period along both texture axes (m)
  static constexpr double kCoverage = 0.20;   ///< fraction of the ground with mask > 0.5
  static constexpr int kShininess = 16;       ///< exponent of the lobe (power of two)

  SpecularPatches(std::uint64_t seed, double amplitude);
  double amplitude() const { return amplitude_; }
  /// Light direction in W (unit, from the ground toward the light).
  const Eigen::Vector3d& lightW() const { return light_W_; }
  /// Mask in [0, 1] at plane coordinates (metres along the texture axes t1, t2 from the texture origin).
  inline float mask(float u_m, float v_m) const;
  /// Fraction of mask samples above 0.5.
  double coverage() const;

 private:
  double amplitude_ = 0.0;
  Eigen::Vector3d light_W_;
  std::vector<float> grid_;  // kGrid x kGrid, periodic
};

inline float SpecularPatches::mask(float u_m, float v_m) const {
  constexpr float s = static_cast<float>(kGrid / kPeriodM);
  float x = u_m * s, y = v_m * s;
  x = x < -1e8f ? -1e8f : (x > 1e8f ? 1e8f : x);
  y = y < -1e8f ? -1e8f : (y > 1e8f ? 1e8f : y);
  int ix = static_cast<int>(x), iy = static_cast<int>(y);
  ix -= (x < static_cast<float>(ix));
  iy -= (y < static_cast<float>(iy));
  const float fx = x - static_cast<float>(ix), fy = y - static_cast<float>(iy);
  const int x0 = ix & (kGrid - 1), y0 = iy & (kGrid - 1);
  const int x1 = (x0 + 1) & (kGrid - 1), y1 = (y0 + 1) & (kGrid - 1);
  const float a = grid_[y0 * kGrid + x0] + fx * (grid_[y0 * kGrid + x1] - grid_[y0 * kGrid + x0]);
  const float b = grid_[y1 * kGrid + x0] + fx * (grid_[y1 * kGrid + x1] - grid_[y1 * kGrid + x0]);
  return a + fy * (b - a);
}

/// Writes DIR/realism.yaml: the true values of the effects and the true vs written calibration.
void writeRealismYaml(const std::string& path, const std::string& preset_name, const RealismOptions& r,
                      double scale, const CameraModel& truth, const CameraModel& written,
                      const ExposureSteps* steps, const SpecularPatches* specular);

}  // namespace sim
}  // namespace diekf
