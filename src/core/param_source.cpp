// YAML parameter source, the estimator's parameter key table, and the Kalibr IMU noise reader.
#include "diekf/param_source.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <iostream>
#include <set>
#include <sstream>
#include <stdexcept>

namespace diekf {

// ------------------------------------------------------------------------------------------------------------
// YamlParamSource
// ------------------------------------------------------------------------------------------------------------
struct YamlParamSource::Impl {
  YAML::Node root;
};

namespace {

[[noreturn]] void failKey(const std::string& origin, const std::string& key, const std::string& what) {
  throw std::runtime_error(origin + ": key '" + key + "': " + what);
}

std::string show(const YAML::Node& n) {
  if (n.IsScalar()) return "'" + n.Scalar() + "'";
  if (n.IsSequence()) return "a list";
  if (n.IsMap()) return "a map";
  return "an empty value";
}

bool scalarToDouble(const YAML::Node& n, double* v) {
  if (!n.IsScalar()) return false;
  try {
    *v = n.as<double>();
  } catch (const YAML::Exception&) {
    return false;
  }
  return std::isfinite(*v);
}

}  // namespace

YamlParamSource::YamlParamSource(const std::string& path) : path_(path), impl_(new Impl) {
  try {
    impl_->root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    delete impl_;
    throw std::runtime_error(path + ": cannot open the parameter file");
  } catch (const YAML::Exception& e) {
    delete impl_;
    throw std::runtime_error(path + ": cannot parse YAML: " + e.what());
  } catch (const std::exception& e) {  // e.g. a directory: the stream fails while reading
    delete impl_;
    throw std::runtime_error(path + ": cannot read the parameter file: " + e.what());
  }
  if (!impl_->root.IsMap() && !impl_->root.IsNull()) {
    delete impl_;
    throw std::runtime_error(path + ": expected a YAML map of parameters at the top level");
  }
}

YamlParamSource::~YamlParamSource() { delete impl_; }

namespace {

// Walks "a/b/c" through nested maps; returns an invalid node when a component is absent.
YAML::Node lookup(const YAML::Node& root, const std::string& key, const std::string& origin) {
  YAML::Node node = root;  // YAML::Node copies are references; reassigning below rebinds, not overwrites
  std::size_t start = 0;
  std::string walked;
  while (true) {
    const std::size_t slash = key.find('/', start);
    const std::string part = key.substr(start, slash == std::string::npos ? std::string::npos : slash - start);
    if (part.empty()) failKey(origin, key, "malformed key (empty component)");
    if (!node.IsMap()) {
      if (!node || node.IsNull()) return YAML::Node(YAML::NodeType::Undefined);
      failKey(origin, key, "'" + walked + "' is " + show(node) + ", not a map");
    }
    const YAML::Node child = node[part];
    if (!child) return YAML::Node(YAML::NodeType::Undefined);
    walked += (walked.empty() ? "" : "/") + part;
    node.reset(child);
    if (slash == std::string::npos) return node;
    start = slash + 1;
  }
}

}  // namespace

namespace {

// Leaf keys of a YAML map ("a/b"), in document order.
void collectLeafKeys(const YAML::Node& map, const std::string& prefix, std::vector<std::string>* out) {
  for (const auto& kv : map) {
    const std::string key = prefix + (kv.first.IsScalar() ? kv.first.Scalar() : std::string("?"));
    if (kv.second.IsMap() && kv.second.size() > 0) {
      collectLeafKeys(kv.second, key + "/", out);
    } else {
      out->push_back(key);
    }
  }
}

}  // namespace

std::vector<std::string> YamlParamSource::keys() const {
  std::vector<std::string> out;
  if (impl_->root.IsMap()) collectLeafKeys(impl_->root, "", &out);
  return out;
}

bool YamlParamSource::get(const std::string& key, double* value) const {
  const YAML::Node n = lookup(impl_->root, key, path_);
  if (!n.IsDefined()) return false;
  double v = 0.0;
  if (!scalarToDouble(n, &v)) failKey(path_, key, "expected a finite number, got " + show(n));
  *value = v;
  return true;
}

bool YamlParamSource::get(const std::string& key, int* value) const {
  const YAML::Node n = lookup(impl_->root, key, path_);
  if (!n.IsDefined()) return false;
  double v = 0.0;
  if (!scalarToDouble(n, &v) || v != std::floor(v) || std::abs(v) > 2147483647.0) {
    failKey(path_, key, "expected an integer, got " + show(n));
  }
  *value = static_cast<int>(v);
  return true;
}

bool YamlParamSource::get(const std::string& key, bool* value) const {
  const YAML::Node n = lookup(impl_->root, key, path_);
  if (!n.IsDefined()) return false;
  bool v = false;
  try {
    if (!n.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
    v = n.as<bool>();
  } catch (const YAML::Exception&) {
    failKey(path_, key, "expected true or false, got " + show(n));
  }
  *value = v;
  return true;
}

bool YamlParamSource::get(const std::string& key, std::string* value) const {
  const YAML::Node n = lookup(impl_->root, key, path_);
  if (!n.IsDefined()) return false;
  if (!n.IsScalar()) failKey(path_, key, "expected a string, got " + show(n));
  *value = n.Scalar();
  return true;
}

bool YamlParamSource::get(const std::string& key, std::vector<double>* value) const {
  const YAML::Node n = lookup(impl_->root, key, path_);
  if (!n.IsDefined()) return false;
  if (!n.IsSequence()) failKey(path_, key, "expected a list of numbers, got " + show(n));
  std::vector<double> out;
  for (std::size_t i = 0; i < n.size(); ++i) {
    double v = 0.0;
    if (!scalarToDouble(n[i], &v)) {
      failKey(path_, key, "element " + std::to_string(i) + ": expected a finite number, got " + show(n[i]));
    }
    out.push_back(v);
  }
  *value = std::move(out);
  return true;
}

// ------------------------------------------------------------------------------------------------------------
// Estimator parameter table
// ------------------------------------------------------------------------------------------------------------
namespace {

using Loader = std::function<void(const ParamSource&, EstimatorParams&)>;

struct Entry {
  std::string key;
  Loader load;
};

std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

// Numeric range: lo/hi inclusive unless the *_open flag is set.
struct Range {
  double lo = -HUGE_VAL, hi = HUGE_VAL;
  bool lo_open = false, hi_open = false;
  std::string describe() const {
    std::string s;
    if (lo > -HUGE_VAL) s += std::string(lo_open ? "> " : ">= ") + num(lo);
    if (hi < HUGE_VAL) s += std::string(s.empty() ? "" : " and ") + (hi_open ? "< " : "<= ") + num(hi);
    return s;
  }
  bool contains(double v) const {
    return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
};

Range positive(double hi = HUGE_VAL) { return Range{0.0, hi, true, false}; }
Range nonNegative(double hi = HUGE_VAL) { return Range{0.0, hi, false, false}; }
Range between(double lo, double hi) { return Range{lo, hi, false, false}; }

void checkRange(const ParamSource& src, const std::string& key, double v, const Range& r) {
  if (!r.contains(v)) failKey(src.origin(), key, "value " + num(v) + " out of range: must be " + r.describe());
}

Entry real(const std::string& key, std::function<double&(EstimatorParams&)> field, Range range) {
  return {key, [=](const ParamSource& s, EstimatorParams& p) {
            double v = 0.0;
            if (!s.get(key, &v)) return;
            checkRange(s, key, v, range);
            field(p) = v;
          }};
}

Entry integer(const std::string& key, std::function<int&(EstimatorParams&)> field, Range range) {
  return {key, [=](const ParamSource& s, EstimatorParams& p) {
            int v = 0;
            if (!s.get(key, &v)) return;
            checkRange(s, key, v, range);
            field(p) = v;
          }};
}

Entry flag(const std::string& key, std::function<bool&(EstimatorParams&)> field) {
  return {key, [=](const ParamSource& s, EstimatorParams& p) {
            bool v = false;
            if (s.get(key, &v)) field(p) = v;
          }};
}

// A 3-vector; `nonzero` requires a norm above 1e-6 (directions, normalised on use).
Entry vec3(const std::string& key, std::function<Vec3&(EstimatorParams&)> field, bool nonzero) {
  return {key, [=](const ParamSource& s, EstimatorParams& p) {
            std::vector<double> v;
            if (!s.get(key, &v)) return;
            if (v.size() != 3) {
              failKey(s.origin(), key, "expected a list of 3 numbers, got " + std::to_string(v.size()));
            }
            const Vec3 x(v[0], v[1], v[2]);
            if (nonzero && !(x.norm() > 1e-6)) failKey(s.origin(), key, "direction must be non-zero");
            field(p) = x;
          }};
}

// A value named by a string (an enum): `parse` throws std::invalid_argument naming the accepted names, reported
// with the key.
template <class Enum, class Field>
Entry named(const std::string& key, Field field, Enum (*parse)(const std::string&)) {
  return {key, [=](const ParamSource& s, EstimatorParams& p) {
            std::string name;
            if (!s.get(key, &name)) return;
            try {
              field(p) = parse(name);
            } catch (const std::invalid_argument& e) {
              failKey(s.origin(), key, e.what());
            }
          }};
}

#define DIEKF_FIELD(type, expr) [](EstimatorParams& p) -> type& { return p.expr; }

const std::vector<Entry>& table() {
  static const std::vector<Entry> entries = [] {
    std::vector<Entry> t;
    t.push_back(named("mode", DIEKF_FIELD(UpdateMode, mode), &parseUpdateMode));
    // init
    t.push_back(real("init/alpha0_inv_m", DIEKF_FIELD(double, init.alpha0_inv_m), positive(1e4)));
    t.push_back(vec3("init/vartheta0_inv_s", DIEKF_FIELD(Vec3, init.vartheta0_inv_s), false));
    t.push_back(vec3("init/mu0", DIEKF_FIELD(Vec3, init.mu0), true));
    t.push_back(vec3("init/g0", DIEKF_FIELD(Vec3, init.g0), true));
    t.push_back(flag("init/g0_from_accel", DIEKF_FIELD(bool, init.g0_from_accel)));
    t.push_back(flag("init/mu0_from_gravity", DIEKF_FIELD(bool, init.mu0_from_gravity)));
    t.push_back(flag("init/keep_gravity_on_restart", DIEKF_FIELD(bool, init.keep_gravity_on_restart)));
    t.push_back(real("init/sigma_alpha0_inv_m", DIEKF_FIELD(double, init.sigma_alpha0_inv_m), positive()));
    t.push_back(real("init/sigma_vartheta0_inv_s", DIEKF_FIELD(double, init.sigma_vartheta0_inv_s), positive()));
    t.push_back(real("init/sigma_mu0_rad", DIEKF_FIELD(double, init.sigma_mu0_rad), positive(M_PI)));
    t.push_back(real("init/sigma_g0_rad", DIEKF_FIELD(double, init.sigma_g0_rad), positive(M_PI)));
    t.push_back(real("init/sigma_ba0_mps2", DIEKF_FIELD(double, init.sigma_ba0_mps2), positive()));
    t.push_back(real("init/sigma_bw0_radps", DIEKF_FIELD(double, init.sigma_bw0_radps), positive()));
    t.push_back(real("init/sigma_time_offset_s", DIEKF_FIELD(double, init.sigma_time_offset_s), positive(1.0)));
    t.push_back(real("init/sigma_readout_s", DIEKF_FIELD(double, init.sigma_readout_s), positive(1.0)));
    t.push_back(real("init/sigma_focal_scale", DIEKF_FIELD(double, init.sigma_focal_scale), positive(0.5)));
    t.push_back(real("init/sigma_camera_rotation_rad", DIEKF_FIELD(double, init.sigma_camera_rotation_rad),
                     positive(0.5)));
    t.push_back(real("init/tracking_max_relative_sigma_d", DIEKF_FIELD(double, init.tracking_max_relative_sigma_d),
                     positive()));
    t.push_back(flag("init/scale_batch", DIEKF_FIELD(bool, init.scale_batch)));
    t.push_back(real("init/scale_window_s", DIEKF_FIELD(double, init.scale_window_s), positive(30.0)));
    t.push_back(real("init/scale_max_window_s", DIEKF_FIELD(double, init.scale_max_window_s), positive(60.0)));
    t.push_back(real("init/scale_max_relative_sigma", DIEKF_FIELD(double, init.scale_max_relative_sigma),
                     positive(1.0)));
    t.push_back(flag("init/warm_restart", DIEKF_FIELD(bool, init.warm_restart)));
    t.push_back(real("init/warm_restart_max_age_s", DIEKF_FIELD(double, init.warm_restart_max_age_s), nonNegative()));
    t.push_back(real("init/warm_restart_sigma_alpha_relative",
                     DIEKF_FIELD(double, init.warm_restart_sigma_alpha_relative), positive()));
    // imu
    t.push_back(real("imu/accel_noise_density", DIEKF_FIELD(double, imu.accel_noise_density), positive()));
    t.push_back(real("imu/gyro_noise_density", DIEKF_FIELD(double, imu.gyro_noise_density), positive()));
    t.push_back(real("imu/accel_random_walk", DIEKF_FIELD(double, imu.accel_random_walk), nonNegative()));
    t.push_back(real("imu/gyro_random_walk", DIEKF_FIELD(double, imu.gyro_random_walk), nonNegative()));
    t.push_back(real("imu/input_rate_hz", DIEKF_FIELD(double, imu.input_rate_hz), positive(1e5)));
    t.push_back(real("imu/lowpass_cutoff_hz", DIEKF_FIELD(double, imu.lowpass_cutoff_hz), positive()));
    t.push_back(integer("imu/lowpass_order", DIEKF_FIELD(int, imu.lowpass_order), between(0, 8)));
    t.push_back(real("imu/max_vibration_hz", DIEKF_FIELD(double, imu.max_vibration_hz), positive(1e5)));
    t.push_back(integer("imu/aliased_lowpass_order", DIEKF_FIELD(int, imu.aliased_lowpass_order), between(0, 8)));
    t.push_back(flag("imu/aliased_notch", DIEKF_FIELD(bool, imu.aliased_notch)));
    t.push_back(integer("imu/decimation_factor", DIEKF_FIELD(int, imu.decimation_factor), between(1, 1000)));
    t.push_back(flag("imu/decimation_mean", DIEKF_FIELD(bool, imu.decimation_mean)));
    t.push_back(flag("imu/compensate_filter_delay", DIEKF_FIELD(bool, imu.compensate_filter_delay)));
    t.push_back(flag("imu/lever_arm_compensation", DIEKF_FIELD(bool, imu.lever_arm_compensation)));
    t.push_back(flag("imu/prime_from_mean", DIEKF_FIELD(bool, imu.prime_from_mean)));
    t.push_back(real("imu/jacobian_accel_smoothing_s", DIEKF_FIELD(double, imu.jacobian_accel_smoothing_s),
                     between(-1.0, 1.0)));
    t.push_back(real("imu/gravity_mps2", DIEKF_FIELD(double, imu.gravity_mps2), between(1.0, 30.0)));
    // process noise
    t.push_back(real("process/alpha_inv_m_per_sqrt_s", DIEKF_FIELD(double, process.alpha_inv_m_per_sqrt_s),
                     nonNegative()));
    t.push_back(real("process/alpha_rate_noise_sqrt_s", DIEKF_FIELD(double, process.alpha_rate_noise_sqrt_s),
                     nonNegative()));
    t.push_back(real("process/vartheta_inv_s_per_sqrt_s",
                     DIEKF_FIELD(double, process.vartheta_inv_s_per_sqrt_s), nonNegative()));
    t.push_back(flag("process/alpha_noise_keeps_velocity", DIEKF_FIELD(bool, process.alpha_noise_keeps_velocity)));
    t.push_back(real("process/bilinear_accel_time_s", DIEKF_FIELD(double, process.bilinear_accel_time_s),
                     between(0.0, 10.0)));
    t.push_back(real("process/mu_rad_per_sqrt_s", DIEKF_FIELD(double, process.mu_rad_per_sqrt_s), nonNegative()));
    t.push_back(real("process/g_rad_per_sqrt_s", DIEKF_FIELD(double, process.g_rad_per_sqrt_s), nonNegative()));
    t.push_back(real("process/time_offset_s_per_sqrt_s", DIEKF_FIELD(double, process.time_offset_s_per_sqrt_s),
                     nonNegative()));
    t.push_back(real("process/readout_s_per_sqrt_s", DIEKF_FIELD(double, process.readout_s_per_sqrt_s),
                     nonNegative()));
    t.push_back(real("process/focal_scale_per_sqrt_s", DIEKF_FIELD(double, process.focal_scale_per_sqrt_s),
                     nonNegative()));
    // preprocess
    t.push_back(integer("preprocess/working_width_px", DIEKF_FIELD(int, preprocess.working_width_px),
                        between(3, 4096)));
    t.push_back(integer("preprocess/working_height_px", DIEKF_FIELD(int, preprocess.working_height_px),
                        between(0, 4096)));
    t.push_back(real("preprocess/blur_sigma_px", DIEKF_FIELD(double, preprocess.blur_sigma_px), between(0.0, 20.0)));
    t.push_back(real("preprocess/antialias_sigma_px", DIEKF_FIELD(double, preprocess.antialias_sigma_px),
                     between(0.0, 2.0)));
    t.push_back(flag("preprocess/normalize_brightness", DIEKF_FIELD(bool, preprocess.normalize_brightness)));
    t.push_back(integer("preprocess/border_px", DIEKF_FIELD(int, preprocess.border_px), between(1, 100)));
    t.push_back(integer("preprocess/dot_removal_px", DIEKF_FIELD(int, preprocess.dot_removal_px), between(0, 31)));
    // photometric update
    t.push_back(integer("photometric/max_passes", DIEKF_FIELD(int, photometric.max_passes), between(1, 100)));
    t.push_back(real("photometric/stop_threshold", DIEKF_FIELD(double, photometric.stop_threshold), positive()));
    t.push_back(real("photometric/intensity_noise_sigma", DIEKF_FIELD(double, photometric.intensity_noise_sigma),
                     positive()));
    t.push_back(flag("photometric/gradient_weighting", DIEKF_FIELD(bool, photometric.gradient_weighting)));
    t.push_back(integer("photometric/spline_degree", DIEKF_FIELD(int, photometric.spline_degree), between(3, 5)));
    t.push_back(real("photometric/huber_threshold", DIEKF_FIELD(double, photometric.huber_threshold),
                     nonNegative()));
    t.push_back(real("photometric/min_valid_ratio", DIEKF_FIELD(double, photometric.min_valid_ratio),
                     between(0.0, 1.0)));
    t.push_back(integer("photometric/pixel_stride", DIEKF_FIELD(int, photometric.pixel_stride), between(1, 64)));
    t.push_back(flag("photometric/adaptive_noise", DIEKF_FIELD(bool, photometric.adaptive_noise)));
    t.push_back(real("photometric/sensor_noise_grey", DIEKF_FIELD(double, photometric.sensor_noise_grey),
                     between(0.0, 255.0)));
    t.push_back(integer("photometric/noise_tiles_x", DIEKF_FIELD(int, photometric.noise_tiles_x), between(2, 16)));
    t.push_back(integer("photometric/noise_tiles_y", DIEKF_FIELD(int, photometric.noise_tiles_y), between(2, 16)));
    t.push_back(real("photometric/noise_time_constant_s", DIEKF_FIELD(double, photometric.noise_time_constant_s),
                     between(0.0, 1000.0)));
    t.push_back(real("photometric/gate_nis", DIEKF_FIELD(double, photometric.gate_nis), between(0.0, 1e6)));
    t.push_back(real("photometric/gate_target_nis", DIEKF_FIELD(double, photometric.gate_target_nis),
                     Range{0.0, 1e6, true, false}));
    t.push_back(real("photometric/nis_time_constant_s", DIEKF_FIELD(double, photometric.nis_time_constant_s),
                     between(0.0, 1000.0)));
    t.push_back(real("photometric/rotation_scale_sigma", DIEKF_FIELD(double, photometric.rotation_scale_sigma),
                     between(0.0, 1.0)));
    t.push_back(real("photometric/time_offset_sigma_s", DIEKF_FIELD(double, photometric.time_offset_sigma_s),
                     between(0.0, 1.0)));
    t.push_back(real("photometric/outlier_threshold_sigma",
                     DIEKF_FIELD(double, photometric.outlier_threshold_sigma), between(0.0, 1000.0)));
    t.push_back(real("photometric/outlier_window_fraction",
                     DIEKF_FIELD(double, photometric.outlier_window_fraction), between(0.0, 1.0)));
    t.push_back(real("photometric/parallax_tolerance", DIEKF_FIELD(double, photometric.parallax_tolerance),
                     between(0.0, 10.0)));
    t.push_back(real("photometric/parallax_time_constant_s",
                     DIEKF_FIELD(double, photometric.parallax_time_constant_s), between(0.0, 100.0)));
    t.push_back(flag("photometric/relief_in_covariance", DIEKF_FIELD(bool, photometric.relief_in_covariance)));
    t.push_back(flag("photometric/relief_in_velocity_covariance",
                     DIEKF_FIELD(bool, photometric.relief_in_velocity_covariance)));
    t.push_back(flag("photometric/focal_scale_in_covariance",
                     DIEKF_FIELD(bool, photometric.focal_scale_in_covariance)));
    t.push_back(flag("photometric/camera_rotation_in_covariance",
                     DIEKF_FIELD(bool, photometric.camera_rotation_in_covariance)));
    t.push_back(named("photometric/brightness_model", DIEKF_FIELD(BrightnessModel, photometric.brightness_model),
                      &parseBrightnessModel));
    t.push_back(integer("photometric/brightness_row_knots", DIEKF_FIELD(int, photometric.brightness_row_knots),
                        between(4, PhotometricParams::kMaxBrightnessRowKnots)));
    t.push_back(real("photometric/light_change_threshold", DIEKF_FIELD(double, photometric.light_change_threshold),
                     between(0.0, 1.0)));
    // camera-fixed pattern (FixedPattern)
    t.push_back(flag("fixed_pattern/enabled", DIEKF_FIELD(bool, fixed_pattern.enabled)));
    t.push_back(real("fixed_pattern/decorrelation_px", DIEKF_FIELD(double, fixed_pattern.decorrelation_px),
                     Range{0.0, 1000.0, true, false}));
    t.push_back(real("fixed_pattern/memory_samples", DIEKF_FIELD(double, fixed_pattern.memory_samples),
                     between(1.0, 1e6)));
    t.push_back(real("fixed_pattern/startup_samples", DIEKF_FIELD(double, fixed_pattern.startup_samples),
                     between(1.0, 1e6)));
    t.push_back(real("fixed_pattern/min_ground_patches", DIEKF_FIELD(double, fixed_pattern.min_ground_patches),
                     between(0.0, 1e6)));
    t.push_back(integer("fixed_pattern/scale_losses_waive_patches",
                        DIEKF_FIELD(int, fixed_pattern.scale_losses_waive_patches), between(0, 1000)));
    t.push_back(real("fixed_pattern/scale_loss_window_s", DIEKF_FIELD(double, fixed_pattern.scale_loss_window_s),
                     between(0.0, 1e6)));
    t.push_back(real("fixed_pattern/significance_sigma", DIEKF_FIELD(double, fixed_pattern.significance_sigma),
                     between(0.0, 100.0)));
    t.push_back(real("fixed_pattern/min_gain", DIEKF_FIELD(double, fixed_pattern.min_gain), between(0.0, 1.0)));
    t.push_back(integer("fixed_pattern/refresh_frames", DIEKF_FIELD(int, fixed_pattern.refresh_frames),
                        between(1, 1000)));
    t.push_back(flag("fixed_pattern/radial_vignetting", DIEKF_FIELD(bool, fixed_pattern.radial_vignetting)));
    t.push_back(real("fixed_pattern/report_fraction", DIEKF_FIELD(double, fixed_pattern.report_fraction),
                     between(0.0, 1.0)));
    t.push_back(flag("fixed_pattern/discount_biased_updates",
                     DIEKF_FIELD(bool, fixed_pattern.discount_biased_updates)));
    t.push_back(real("fixed_pattern/dominant_contrast_share",
                     DIEKF_FIELD(double, fixed_pattern.dominant_contrast_share), between(0.0, 1.0)));
    t.push_back(integer("fixed_pattern/auto_dot_removal_px", DIEKF_FIELD(int, fixed_pattern.auto_dot_removal_px),
                        between(0, 31)));
    t.push_back(real("fixed_pattern/dot_detect_share", DIEKF_FIELD(double, fixed_pattern.dot_detect_share),
                     Range{0.0, 1.0, false, true}));
    t.push_back(real("fixed_pattern/dot_detect_contrast", DIEKF_FIELD(double, fixed_pattern.dot_detect_contrast),
                     Range{0.0, 10.0, true, false}));
    t.push_back(integer("fixed_pattern/dot_detect_levels", DIEKF_FIELD(int, fixed_pattern.dot_detect_levels),
                        between(1, 3)));
    t.push_back(integer("fixed_pattern/max_dot_removal_px", DIEKF_FIELD(int, fixed_pattern.max_dot_removal_px),
                        between(0, 31)));
    t.push_back(flag("fixed_pattern/dot_fill", DIEKF_FIELD(bool, fixed_pattern.dot_fill)));
    t.push_back(flag("fixed_pattern/dot_gain", DIEKF_FIELD(bool, fixed_pattern.dot_gain)));
    t.push_back({"fixed_pattern/vignetting_file", [](const ParamSource& s, EstimatorParams& p) {
                   std::string path;
                   if (s.get("fixed_pattern/vignetting_file", &path)) p.fixed_pattern.vignetting_file = path;
                 }});
    // feature baseline
    t.push_back(integer("feature/max_corners", DIEKF_FIELD(int, feature.max_corners), between(1, 100000)));
    t.push_back(real("feature/quality_level", DIEKF_FIELD(double, feature.quality_level), Range{0.0, 1.0, true, false}));
    t.push_back(real("feature/min_distance_px", DIEKF_FIELD(double, feature.min_distance_px), nonNegative()));
    t.push_back(integer("feature/window_px", DIEKF_FIELD(int, feature.window_px), between(3, 255)));
    t.push_back(integer("feature/pyramid_levels", DIEKF_FIELD(int, feature.pyramid_levels), between(0, 10)));
    t.push_back(real("feature/pixel_noise_sigma_px", DIEKF_FIELD(double, feature.pixel_noise_sigma_px), positive()));
    t.push_back(real("feature/huber_threshold_px", DIEKF_FIELD(double, feature.huber_threshold_px), nonNegative()));
    t.push_back(integer("feature/working_width_px", DIEKF_FIELD(int, feature.working_width_px), between(8, 4096)));
    t.push_back(flag("feature/predict_flow", DIEKF_FIELD(bool, feature.predict_flow)));
    // divergence handling
    t.push_back(real("divergence/min_distance_m", DIEKF_FIELD(double, divergence.min_distance_m), positive()));
    t.push_back(real("divergence/max_distance_m", DIEKF_FIELD(double, divergence.max_distance_m), positive()));
    t.push_back(real("divergence/max_sigma_distance_m", DIEKF_FIELD(double, divergence.max_sigma_distance_m),
                     positive()));
    t.push_back(real("divergence/max_photometric_rms", DIEKF_FIELD(double, divergence.max_photometric_rms),
                     positive()));
    t.push_back(integer("divergence/bad_frames_before_reset", DIEKF_FIELD(int, divergence.bad_frames_before_reset),
                        between(1, 1000000)));
    t.push_back(real("divergence/max_speed_mps", DIEKF_FIELD(double, divergence.max_speed_mps), positive()));
    t.push_back(real("divergence/max_sigma_velocity_mps", DIEKF_FIELD(double, divergence.max_sigma_velocity_mps),
                     positive()));
    t.push_back(real("divergence/max_step_sigma", DIEKF_FIELD(double, divergence.max_step_sigma), positive()));
    t.push_back(real("divergence/degraded_hold_s", DIEKF_FIELD(double, divergence.degraded_hold_s),
                     between(0.0, 3600.0)));
    t.push_back(real("divergence/max_nis_ratio", DIEKF_FIELD(double, divergence.max_nis_ratio), positive()));
    // input checks
    t.push_back(real("input/max_imu_bridge_s", DIEKF_FIELD(double, input.max_imu_bridge_s), positive(60.0)));
    t.push_back(real("input/time_jump_reset_s", DIEKF_FIELD(double, input.time_jump_reset_s), positive()));
    t.push_back(real("input/max_frame_interval_s", DIEKF_FIELD(double, input.max_frame_interval_s), positive()));
    t.push_back(real("input/max_image_gap_s", DIEKF_FIELD(double, input.max_image_gap_s), positive(60.0)));
    t.push_back(real("input/min_image_contrast_grey", DIEKF_FIELD(double, input.min_image_contrast_grey),
                     between(0.0, 100.0)));
    t.push_back(real("input/min_unclipped_ratio", DIEKF_FIELD(double, input.min_unclipped_ratio), between(0.0, 1.0)));
    t.push_back(real("input/max_accel_mps2", DIEKF_FIELD(double, input.max_accel_mps2), positive()));
    t.push_back(real("input/max_gyro_radps", DIEKF_FIELD(double, input.max_gyro_radps), positive()));
    t.push_back(real("input/gap_accel_sigma_mps2", DIEKF_FIELD(double, input.gap_accel_sigma_mps2),
                     between(0.0, 1000.0)));
    t.push_back(real("input/gap_gyro_sigma_radps", DIEKF_FIELD(double, input.gap_gyro_sigma_radps),
                     between(0.0, 100.0)));
    t.push_back(flag("input/stamp_smoothing", DIEKF_FIELD(bool, input.stamp_smoothing)));
    t.push_back(integer("input/stamp_smoothing_frames", DIEKF_FIELD(int, input.stamp_smoothing_frames), between(8, 128)));
    // queueing
    t.push_back(real("max_imu_gap_s", DIEKF_FIELD(double, max_imu_gap_s), positive()));
    t.push_back(integer("max_queued_images", DIEKF_FIELD(int, max_queued_images), between(1, 10000)));
    t.push_back(flag("update_at_interval_midpoint", DIEKF_FIELD(bool, update_at_interval_midpoint)));
    t.push_back(flag("estimate_time_offset", DIEKF_FIELD(bool, estimate_time_offset)));
    t.push_back(real("max_time_offset_s", DIEKF_FIELD(double, max_time_offset_s), between(0.0, 1.0)));
    t.push_back(real("time_offset_start_s", DIEKF_FIELD(double, time_offset_start_s), between(0.0, 1e4)));
    t.push_back(flag("time_offset_consider", DIEKF_FIELD(bool, time_offset_consider)));
    t.push_back(flag("estimate_readout", DIEKF_FIELD(bool, estimate_readout)));
    t.push_back(flag("readout_consider", DIEKF_FIELD(bool, readout_consider)));
    t.push_back(flag("readout_from_first_image", DIEKF_FIELD(bool, readout_from_first_image)));
    t.push_back(flag("readout_with_considered_offset", DIEKF_FIELD(bool, readout_with_considered_offset)));
    t.push_back(real("max_readout_s", DIEKF_FIELD(double, max_readout_s), between(0.0, 1.0)));
    t.push_back(real("readout_start_sigma_time_offset_s", DIEKF_FIELD(double, readout_start_sigma_time_offset_s),
                     between(0.0, 1.0)));
    t.push_back(real("rates_window_s", DIEKF_FIELD(double, rates_window_s), between(0.0, 100.0)));
    t.push_back(real("line_delay_s", DIEKF_FIELD(double, line_delay_s), between(0.0, 1e-3)));
    t.push_back(flag("estimate_focal_scale", DIEKF_FIELD(bool, estimate_focal_scale)));
    t.push_back(real("focal_start_sigma_time_offset_s", DIEKF_FIELD(double, focal_start_sigma_time_offset_s),
                     positive(1.0)));
    t.push_back(flag("focal_scale_consider", DIEKF_FIELD(bool, focal_scale_consider)));
    t.push_back(real("max_focal_scale", DIEKF_FIELD(double, max_focal_scale), between(0.0, 0.5)));
    t.push_back(named("image_stamp", DIEKF_FIELD(ImageStamp, image_stamp), &parseImageStamp));
    t.push_back(real("exposure_time_s", DIEKF_FIELD(double, exposure_time_s), between(0.0, 1.0)));
    return t;
  }();
  return entries;
}

#undef DIEKF_FIELD

// Checks that involve more than one key (reported against the key that was set in the source, if any).
void checkConsistency(const ParamSource& s, const EstimatorParams& p) {
  // Name the first key if the source sets it, else the second (which then is the one changed).
  auto blame = [&](const std::string& a, const std::string& b) {
    double unused = 0.0;
    return s.get(a, &unused) ? a : b;
  };
  const ImuParams& imu = p.imu;
  if (p.photometric.spline_degree != 3 && p.photometric.spline_degree != 5) {
    failKey(s.origin(), "photometric/spline_degree",
            "value " + std::to_string(p.photometric.spline_degree) + " must be 3 (cubic) or 5 (quintic)");
  }
  if (imu.lowpass_order % 2 != 0) {
    failKey(s.origin(), "imu/lowpass_order",
            "value " + std::to_string(imu.lowpass_order) + " must be even (0 disables the filter)");
  }
  if (imu.aliased_lowpass_order % 2 != 0) {
    failKey(s.origin(), "imu/aliased_lowpass_order",
            "value " + std::to_string(imu.aliased_lowpass_order) + " must be even (0: always imu/lowpass_order)");
  }
  if (imu.lowpass_order > 0 && !(imu.lowpass_cutoff_hz < 0.5 * imu.input_rate_hz)) {
    failKey(s.origin(), blame("imu/lowpass_cutoff_hz", "imu/input_rate_hz"),
            "lowpass_cutoff_hz " + num(imu.lowpass_cutoff_hz) + " must be below input_rate_hz / 2 = " +
                num(0.5 * imu.input_rate_hz));
  }
  if (!(p.divergence.max_distance_m > p.divergence.min_distance_m)) {
    failKey(s.origin(), blame("divergence/max_distance_m", "divergence/min_distance_m"),
            "max_distance_m " + num(p.divergence.max_distance_m) + " must exceed min_distance_m " +
                num(p.divergence.min_distance_m));
  }
  if (!(p.input.max_imu_bridge_s >= p.max_imu_gap_s)) {
    failKey(s.origin(), blame("input/max_imu_bridge_s", "max_imu_gap_s"),
            "max_imu_bridge_s " + num(p.input.max_imu_bridge_s) + " must be at least max_imu_gap_s " +
                num(p.max_imu_gap_s));
  }
  if (p.preprocess.working_height_px != 0 && p.preprocess.working_height_px < 3) {
    failKey(s.origin(), "preprocess/working_height_px", "must be 0 (keep the aspect ratio) or >= 3");
  }
}

}  // namespace

std::vector<std::string> estimatorParamKeys() {
  std::vector<std::string> keys;
  for (const Entry& e : table()) keys.push_back(e.key);
  return keys;
}

// ------------------------------------------------------------------------------------------------------------
// Unknown keys
// ------------------------------------------------------------------------------------------------------------
namespace {

// Levenshtein distance (insertions, deletions, substitutions of one character each).
std::size_t editDistance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t substitute = diagonal + (a[i - 1] == b[j - 1] ? 0 : 1);
      diagonal = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, substitute});
    }
  }
  return row[b.size()];
}

std::string lastComponent(const std::string& key) {
  const std::size_t slash = key.rfind('/');
  return slash == std::string::npos ? key : key.substr(slash + 1);
}

}  // namespace

std::string UnknownParamKey::message() const {
  std::string m = origin + ": unknown parameter key '" + key + "' ignored";
  if (!closest.empty()) m += " (closest known key: '" + closest + "')";
  return m;
}

std::vector<UnknownParamKey> unknownParamKeys(const ParamSource& source, const std::vector<std::string>& other_known) {
  std::vector<std::string> known = estimatorParamKeys();
  known.insert(known.end(), other_known.begin(), other_known.end());
  const std::set<std::string> known_set(known.begin(), known.end());
  std::vector<UnknownParamKey> out;
  for (const std::string& key : source.keys()) {
    if (known_set.count(key) > 0) continue;
    const std::string group = key + "/";
    const bool is_group = std::any_of(known.begin(), known.end(), [&](const std::string& k) {
      return k.compare(0, group.size(), group) == 0;
    });
    if (is_group) continue;
    UnknownParamKey u;
    u.origin = source.origin();
    u.key = key;
    std::size_t best = static_cast<std::size_t>(-1);
    const std::string leaf = lastComponent(key);
    for (const std::string& k : known) {
      const std::size_t d = std::min(editDistance(key, k), editDistance(leaf, lastComponent(k)) + 1);
      if (d < best) {
        best = d;
        u.closest = k;
      }
    }
    out.push_back(u);
  }
  return out;
}

void loadEstimatorParams(const ParamSource& source, EstimatorParams* params) {
  loadEstimatorParams(source, params, [](const std::string& warning) { std::cerr << "warning: " << warning << "\n"; });
}

void loadEstimatorParams(const ParamSource& source, EstimatorParams* params, const ParamWarningFn& warn,
                         const std::vector<std::string>& other_known) {
  if (params == nullptr) throw std::invalid_argument("loadEstimatorParams: null params");
  if (warn) {
    for (const UnknownParamKey& u : unknownParamKeys(source, other_known)) warn(u.message());
  }
  EstimatorParams p = *params;
  for (const Entry& e : table()) e.load(source, p);
  checkConsistency(source, p);
  *params = p;
}

// ------------------------------------------------------------------------------------------------------------
// Kalibr IMU YAML
// ------------------------------------------------------------------------------------------------------------
void loadKalibrImuYaml(const std::string& path, ImuParams* imu) {
  if (imu == nullptr) throw std::invalid_argument("loadKalibrImuYaml: null imu");
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error(path + ": cannot open the IMU file");
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(path + ": cannot parse YAML: " + e.what());
  } catch (const std::exception& e) {  // e.g. a directory: the stream fails while reading
    throw std::runtime_error(path + ": cannot read the file: " + e.what());
  }
  if (!root.IsMap()) throw std::runtime_error(path + ": expected a YAML map at the top level");
  std::string prefix;
  YAML::Node m = root;
  if (root["imu0"]) {
    m.reset(root["imu0"]);
    prefix = "imu0/";
    if (!m.IsMap()) failKey(path, "imu0", "expected a map");
  }
  auto read = [&](const char* name) {
    const YAML::Node n = m[name];
    const std::string key = prefix + name;
    if (!n || n.IsNull()) failKey(path, key, "missing");
    double v = 0.0;
    if (!scalarToDouble(n, &v)) failKey(path, key, "expected a finite number, got " + show(n));
    if (!(v > 0.0)) failKey(path, key, "value " + num(v) + " must be > 0");
    return v;
  };
  ImuParams out = *imu;
  out.accel_noise_density = read("accelerometer_noise_density");
  out.accel_random_walk = read("accelerometer_random_walk");
  out.gyro_noise_density = read("gyroscope_noise_density");
  out.gyro_random_walk = read("gyroscope_random_walk");
  out.input_rate_hz = read("update_rate");
  // The prediction keeps its rate (imu/input_rate_hz / imu/decimation_factor as configured, 100 Hz by default):
  // an IMU at 200 Hz is decimated by 2, not by the 5 meant for 500 Hz (which would predict at 40 Hz).
  const double prediction_hz = imu->input_rate_hz / std::max(1, imu->decimation_factor);
  out.decimation_factor = std::max(1, static_cast<int>(std::lround(out.input_rate_hz / prediction_hz)));
  *imu = out;
}

}  // namespace diekf
