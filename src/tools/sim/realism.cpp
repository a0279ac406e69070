// Realistic-camera effects: presets, the perturbed calibration, exposure steps, glossy patches, realism.yaml.
#include "diekf/sim/realism.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <random>
#include <stdexcept>

#include "diekf/sim/sequence_io.h"

namespace diekf {
namespace sim {
namespace {

std::string num(double v) { return yamlNumber(v); }

void writeMatrix(std::ostream& f, const char* key, const Eigen::Matrix4d& T) {
  f << key << ":\n";
  writeYamlMatrixRows(f, T);
}

}  // namespace

bool realismPreset(const std::string& name, RealismOptions* out) {
  if (name == "clean") {
    *out = RealismOptions();
    return true;
  }
  if (name == "realistic") {
    RealismOptions r;
    r.rolling_shutter_ms = 16.0;
    r.time_offset_ms = 5.0;
    r.intrinsics_error_pct = 1.5;
    r.extrinsic_rot_error_deg = 1.0;
    r.defocus_px = 1.0;
    r.exposure_steps = true;
    r.non_lambertian = 0.3;
    *out = r;
    return true;
  }
  return false;
}

Eigen::Vector3d extrinsicErrorAxisC() { return Eigen::Vector3d(1.0, 1.0, 0.0).normalized(); }

CameraModel writtenCalibration(const CameraModel& truth, const RealismOptions& r) {
  CameraModel w = truth;
  const double p = r.intrinsics_error_pct / 100.0;
  w.K.fx = truth.K.fx * (1.0 + p);
  w.K.fy = truth.K.fy * (1.0 + p);
  w.K.cx = truth.K.cx + p * 0.5 * truth.K.width;
  w.K.cy = truth.K.cy - p * 0.5 * truth.K.height;
  if (r.extrinsic_rot_error_deg != 0.0) {
    const Eigen::Matrix3d R_err =
        Eigen::AngleAxisd(r.extrinsic_rot_error_deg * M_PI / 180.0, extrinsicErrorAxisC()).toRotationMatrix();
    const Eigen::Vector3d p_IC = -truth.T_cam_imu.linear().transpose() * truth.T_cam_imu.translation();
    const Eigen::Matrix3d R_CI = R_err * truth.T_cam_imu.linear();
    w.T_cam_imu.linear() = R_CI;
    w.T_cam_imu.translation() = -R_CI * p_IC;
  }
  w.timeshift_cam_imu_s = 0.0;
  return w;
}

double rowTimeOffset(int v, int height, double readout_s) {
  if (height <= 1) return 0.0;
  return readout_s * (static_cast<double>(v) / (height - 1) - 0.5);
}

ExposureSteps::ExposureSteps(std::uint64_t seed, double duration_s) {
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 0x5EED0E7905E5ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  double level = 1.0;
  double t = 1.0 + 2.0 * uni(rng);
  while (t < duration_s) {
    const double size = 0.10 + 0.15 * uni(rng);
    double sign = uni(rng) < 0.5 ? -1.0 : 1.0;
    if (level > 1.4) sign = -1.0;
    if (level < 0.7) sign = 1.0;
    level *= 1.0 + sign * size;
    times_.push_back(t);
    levels_.push_back(level);
    t += 1.0 + 2.0 * uni(rng);
  }
}

double ExposureSteps::gain(double t_s) const {
  const auto it = std::upper_bound(times_.begin(), times_.end(), t_s);
  if (it == times_.begin()) return 1.0;
  return levels_[static_cast<std::size_t>(it - times_.begin()) - 1];
}

SpecularPatches::SpecularPatches(std::uint64_t seed, double amplitude)
    : amplitude_(amplitude), light_W_(Eigen::Vector3d(0.3, 0.25, 1.0).normalized()), grid_(kGrid * kGrid) {
  // A smooth random field: periodic Gaussian blobs (radius 0.25-0.6 m) with random weights.
  std::mt19937_64 rng(seed * 0xD1B54A32D192ED03ull + 0x61055ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  struct Blob {
    double x, y, s, w;
  };
  std::vector<Blob> blobs(14);
  for (Blob& b : blobs) b = {uni(rng) * kPeriodM, uni(rng) * kPeriodM, 0.25 + 0.35 * uni(rng), 0.5 + uni(rng)};
  std::vector<double> f(grid_.size(), 0.0);
  const double cell = kPeriodM / kGrid;
  for (int j = 0; j < kGrid; ++j)
    for (int i = 0; i < kGrid; ++i) {
      const double x = (i + 0.5) * cell, y = (j + 0.5) * cell;
      double sum = 0.0;
      for (const Blob& b : blobs) {
        double dx = std::fabs(x - b.x), dy = std::fabs(y - b.y);
        dx = std::min(dx, kPeriodM - dx);  // nearest periodic image
        dy = std::min(dy, kPeriodM - dy);
        sum += b.w * std::exp(-0.5 * (dx * dx + dy * dy) / (b.s * b.s));
      }
      f[static_cast<std::size_t>(j) * kGrid + i] = sum;
    }
  // Threshold at the (1 - coverage) quantile with a smooth edge spanning the 10 % of the area around it.
  std::vector<double> sorted = f;
  std::sort(sorted.begin(), sorted.end());
  const auto q = [&](double p) { return sorted[std::min(sorted.size() - 1, static_cast<std::size_t>(p * sorted.size()))]; };
  const double mid = q(1.0 - kCoverage);
  const double half = std::max(1e-9, 0.5 * (q(1.0 - kCoverage + 0.05) - q(1.0 - kCoverage - 0.05)));
  for (std::size_t k = 0; k < f.size(); ++k) {
    const double x = std::clamp((f[k] - mid) / (2.0 * half) + 0.5, 0.0, 1.0);
    grid_[k] = static_cast<float>(x * x * (3.0 - 2.0 * x));
  }
}

double SpecularPatches::coverage() const {
  std::size_t n = 0;
  for (float m : grid_) n += m > 0.5f;
  return static_cast<double>(n) / grid_.size();
}

void writeRealismYaml(const std::string& path, const std::string& preset_name, const RealismOptions& r,
                      double scale, const CameraModel& truth, const CameraModel& written, const ExposureSteps* steps,
                      const SpecularPatches* specular) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
  f << "# True values of the simulated camera imperfections (diekf_simulate, docs/simulator.md).\n";
  f << "realism: " << preset_name << "\n";
  f << "rolling_shutter_ms: " << num(r.rolling_shutter_ms) << "  # readout top row -> bottom row\n";
  f << "rolling_shutter_line_time_s: "
    << num(truth.K.height > 1 ? r.rolling_shutter_ms * 1e-3 / (truth.K.height - 1) : 0.0) << "\n";
  f << "image_stamp_row: " << num(0.5 * (truth.K.height - 1)) << "  # the stamp is the middle row's mid-exposure\n";
  f << "time_offset_ms: " << num(r.time_offset_ms) << "  # image stamp = true capture time + offset\n";
  f << "true_timeshift_cam_imu_s: " << num(r.time_offset_ms == 0.0 ? 0.0 : -r.time_offset_ms * 1e-3) << "  # Kalibr: t_imu = t_cam + timeshift\n";
  f << "written_timeshift_cam_imu_s: " << num(written.timeshift_cam_imu_s) << "\n";
  f << "intrinsics_error_pct: " << num(r.intrinsics_error_pct) << "\n";
  f << "true_intrinsics: [" << num(truth.K.fx) << ", " << num(truth.K.fy) << ", " << num(truth.K.cx) << ", "
    << num(truth.K.cy) << "]\n";
  f << "written_intrinsics: [" << num(written.K.fx) << ", " << num(written.K.fy) << ", " << num(written.K.cx) << ", "
    << num(written.K.cy) << "]\n";
  const Eigen::Vector3d axis = extrinsicErrorAxisC();
  f << "extrinsic_rot_error_deg: " << num(r.extrinsic_rot_error_deg) << "\n";
  f << "extrinsic_rot_error_axis_cam: [" << num(axis.x()) << ", " << num(axis.y()) << ", " << num(axis.z())
    << "]  # R_CI_written = R(axis, angle) R_CI_true\n";
  writeMatrix(f, "true_T_cam_imu", truth.T_cam_imu.matrix());
  writeMatrix(f, "written_T_cam_imu", written.T_cam_imu.matrix());
  f << "defocus_px: " << num(r.defocus_px) << "  # Gaussian sigma at full resolution\n";
  f << "defocus_sigma_px_at_output_scale: " << num(r.defocus_px * scale) << "\n";
  f << "exposure_steps: " << (r.exposure_steps ? "true" : "false") << "\n";
  if (steps && r.exposure_steps) {
    f << "exposure_step_times_s: [";
    for (std::size_t i = 0; i < steps->stepTimes().size(); ++i) f << (i ? ", " : "") << num(steps->stepTimes()[i]);
    f << "]\nexposure_step_levels: [";
    for (std::size_t i = 0; i < steps->levels().size(); ++i) f << (i ? ", " : "") << num(steps->levels()[i]);
    f << "]\n";
  }
  f << "non_lambertian: " << num(r.non_lambertian) << "\n";
  if (specular && r.non_lambertian > 0.0) {
    const Eigen::Vector3d& l = specular->lightW();
    f << "non_lambertian_coverage: " << num(specular->coverage()) << "\n";
    f << "non_lambertian_light_W: [" << num(l.x()) << ", " << num(l.y()) << ", " << num(l.z()) << "]\n";
    f << "non_lambertian_shininess: " << SpecularPatches::kShininess << "\n";
  }
  if (!f) throw std::runtime_error("error writing '" + path + "'");
}

}  // namespace sim
}  // namespace diekf
