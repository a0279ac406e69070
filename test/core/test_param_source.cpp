// YamlParamSource, the estimator key table (config/estimator.yaml == EstimatorParams{} defaults), range
// validation, and the Kalibr IMU reader.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cstdio>
#include <fstream>
#include <functional>
#include <set>
#include <stdexcept>
#include <string>

#include "diekf/param_source.h"

namespace diekf {
namespace {

std::string packageDir() {
  std::string f = __FILE__;
  const std::string tail = "test/core/test_param_source.cpp";
  return f.substr(0, f.size() - tail.size());
}

class TempYaml {
 public:
  TempYaml(const std::string& name, const std::string& text)
      : path_(::testing::TempDir() + "diekf_paramtest_" + name + ".yaml") {
    std::ofstream(path_) << text;
  }
  ~TempYaml() { std::remove(path_.c_str()); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// Runs f, expects std::runtime_error whose message contains every string of `parts`.
void expectError(const std::function<void()>& f, const std::vector<std::string>& parts) {
  try {
    f();
    FAIL() << "no exception; expected one naming " << parts.back();
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
  }
}

// Field-by-field comparison of every parameter (exact).
bool sameParams(const EstimatorParams& a, const EstimatorParams& b) {
  const InitParams &ia = a.init, &ib = b.init;
  const ImuParams &ma = a.imu, &mb = b.imu;
  const ProcessNoiseParams &pa = a.process, &pb = b.process;
  const PreprocessParams &ra = a.preprocess, &rb = b.preprocess;
  const PhotometricParams &ha = a.photometric, &hb = b.photometric;
  const FeatureParams &fa = a.feature, &fb = b.feature;
  const DivergenceParams &da = a.divergence, &db = b.divergence;
  return a.mode == b.mode && ia.alpha0_inv_m == ib.alpha0_inv_m && ia.vartheta0_inv_s == ib.vartheta0_inv_s &&
         ia.mu0 == ib.mu0 && ia.g0 == ib.g0 && ia.g0_from_accel == ib.g0_from_accel &&
         ia.mu0_from_gravity == ib.mu0_from_gravity && ia.keep_gravity_on_restart == ib.keep_gravity_on_restart &&
         ia.warm_restart_sigma_alpha_relative == ib.warm_restart_sigma_alpha_relative &&
         ia.sigma_alpha0_inv_m == ib.sigma_alpha0_inv_m && ia.sigma_vartheta0_inv_s == ib.sigma_vartheta0_inv_s &&
         ia.sigma_mu0_rad == ib.sigma_mu0_rad && ia.sigma_g0_rad == ib.sigma_g0_rad &&
         ia.sigma_ba0_mps2 == ib.sigma_ba0_mps2 && ia.sigma_bw0_radps == ib.sigma_bw0_radps &&
         ia.sigma_time_offset_s == ib.sigma_time_offset_s && ia.sigma_readout_s == ib.sigma_readout_s &&
         ia.sigma_focal_scale == ib.sigma_focal_scale && ia.sigma_camera_rotation_rad == ib.sigma_camera_rotation_rad &&
         ia.tracking_max_relative_sigma_d == ib.tracking_max_relative_sigma_d &&
         ia.warm_restart == ib.warm_restart && ia.warm_restart_max_age_s == ib.warm_restart_max_age_s &&
         ia.scale_batch == ib.scale_batch && ia.scale_window_s == ib.scale_window_s &&
         ia.scale_max_window_s == ib.scale_max_window_s &&
         ia.scale_max_relative_sigma == ib.scale_max_relative_sigma && ma.prime_from_mean == mb.prime_from_mean &&
         ma.jacobian_accel_smoothing_s == mb.jacobian_accel_smoothing_s &&
         ma.accel_noise_density == mb.accel_noise_density && ma.gyro_noise_density == mb.gyro_noise_density &&
         ma.accel_random_walk == mb.accel_random_walk && ma.gyro_random_walk == mb.gyro_random_walk &&
         ma.input_rate_hz == mb.input_rate_hz && ma.lowpass_cutoff_hz == mb.lowpass_cutoff_hz &&
         ma.lowpass_order == mb.lowpass_order && ma.max_vibration_hz == mb.max_vibration_hz &&
         ma.aliased_lowpass_order == mb.aliased_lowpass_order && ma.aliased_notch == mb.aliased_notch &&
         ma.decimation_factor == mb.decimation_factor && ma.decimation_mean == mb.decimation_mean &&
         ma.compensate_filter_delay == mb.compensate_filter_delay &&
         ma.lever_arm_compensation == mb.lever_arm_compensation && ma.gravity_mps2 == mb.gravity_mps2 &&
         pa.alpha_rate_noise_sqrt_s == pb.alpha_rate_noise_sqrt_s && pa.alpha_inv_m_per_sqrt_s == pb.alpha_inv_m_per_sqrt_s &&
         pa.vartheta_inv_s_per_sqrt_s == pb.vartheta_inv_s_per_sqrt_s && pa.bilinear_accel_time_s == pb.bilinear_accel_time_s &&
         pa.alpha_noise_keeps_velocity == pb.alpha_noise_keeps_velocity &&
         pa.mu_rad_per_sqrt_s == pb.mu_rad_per_sqrt_s && pa.g_rad_per_sqrt_s == pb.g_rad_per_sqrt_s &&
         pa.time_offset_s_per_sqrt_s == pb.time_offset_s_per_sqrt_s && pa.readout_s_per_sqrt_s == pb.readout_s_per_sqrt_s &&
         pa.focal_scale_per_sqrt_s == pb.focal_scale_per_sqrt_s &&
         ra.working_width_px == rb.working_width_px && ra.working_height_px == rb.working_height_px &&
         ra.blur_sigma_px == rb.blur_sigma_px && ra.antialias_sigma_px == rb.antialias_sigma_px &&
         ra.normalize_brightness == rb.normalize_brightness &&
         ra.border_px == rb.border_px && ra.dot_removal_px == rb.dot_removal_px && ha.max_passes == hb.max_passes && ha.stop_threshold == hb.stop_threshold &&
         ha.intensity_noise_sigma == hb.intensity_noise_sigma && ha.gradient_weighting == hb.gradient_weighting &&
         ha.spline_degree == hb.spline_degree &&
         ha.huber_threshold == hb.huber_threshold && ha.min_valid_ratio == hb.min_valid_ratio &&
         ha.pixel_stride == hb.pixel_stride && ha.adaptive_noise == hb.adaptive_noise &&
         ha.sensor_noise_grey == hb.sensor_noise_grey && ha.noise_tiles_x == hb.noise_tiles_x &&
         ha.noise_tiles_y == hb.noise_tiles_y && ha.noise_time_constant_s == hb.noise_time_constant_s &&
         ha.gate_nis == hb.gate_nis && ha.nis_time_constant_s == hb.nis_time_constant_s && ha.gate_target_nis == hb.gate_target_nis &&
         ha.rotation_scale_sigma == hb.rotation_scale_sigma && ha.time_offset_sigma_s == hb.time_offset_sigma_s &&
         ha.outlier_threshold_sigma == hb.outlier_threshold_sigma && ha.outlier_window_fraction == hb.outlier_window_fraction &&
         ha.parallax_tolerance == hb.parallax_tolerance && ha.parallax_time_constant_s == hb.parallax_time_constant_s &&
         ha.relief_in_covariance == hb.relief_in_covariance &&
         ha.relief_in_velocity_covariance == hb.relief_in_velocity_covariance &&
         ha.focal_scale_in_covariance == hb.focal_scale_in_covariance &&
         ha.camera_rotation_in_covariance == hb.camera_rotation_in_covariance &&
         ha.brightness_model == hb.brightness_model && ha.brightness_row_knots == hb.brightness_row_knots &&
         ha.light_change_threshold == hb.light_change_threshold &&
         da.max_step_sigma == db.max_step_sigma && da.degraded_hold_s == db.degraded_hold_s &&
         da.max_nis_ratio == db.max_nis_ratio && a.input.gap_accel_sigma_mps2 == b.input.gap_accel_sigma_mps2 &&
         a.input.gap_gyro_sigma_radps == b.input.gap_gyro_sigma_radps && fa.max_corners == fb.max_corners && fa.predict_flow == fb.predict_flow &&
         fa.quality_level == fb.quality_level && fa.min_distance_px == fb.min_distance_px &&
         fa.window_px == fb.window_px && fa.pyramid_levels == fb.pyramid_levels &&
         fa.pixel_noise_sigma_px == fb.pixel_noise_sigma_px && fa.huber_threshold_px == fb.huber_threshold_px &&
         fa.working_width_px == fb.working_width_px && da.min_distance_m == db.min_distance_m &&
         da.max_distance_m == db.max_distance_m && da.max_sigma_distance_m == db.max_sigma_distance_m &&
         da.max_photometric_rms == db.max_photometric_rms &&
         da.bad_frames_before_reset == db.bad_frames_before_reset && da.max_speed_mps == db.max_speed_mps &&
         da.max_sigma_velocity_mps == db.max_sigma_velocity_mps &&
         a.input.max_imu_bridge_s == b.input.max_imu_bridge_s &&
         a.input.time_jump_reset_s == b.input.time_jump_reset_s &&
         a.input.max_frame_interval_s == b.input.max_frame_interval_s &&
         a.input.max_image_gap_s == b.input.max_image_gap_s &&
         a.input.min_image_contrast_grey == b.input.min_image_contrast_grey &&
         a.input.min_unclipped_ratio == b.input.min_unclipped_ratio &&
         a.input.max_accel_mps2 == b.input.max_accel_mps2 && a.input.max_gyro_radps == b.input.max_gyro_radps &&
         a.input.stamp_smoothing == b.input.stamp_smoothing &&
         a.input.stamp_smoothing_frames == b.input.stamp_smoothing_frames &&
         a.max_imu_gap_s == b.max_imu_gap_s &&
         a.max_queued_images == b.max_queued_images &&
         a.update_at_interval_midpoint == b.update_at_interval_midpoint &&
         a.estimate_time_offset == b.estimate_time_offset && a.max_time_offset_s == b.max_time_offset_s &&
         a.time_offset_start_s == b.time_offset_start_s && a.time_offset_consider == b.time_offset_consider &&
         a.readout_consider == b.readout_consider && a.readout_from_first_image == b.readout_from_first_image &&
         a.readout_with_considered_offset == b.readout_with_considered_offset &&
         a.line_delay_s == b.line_delay_s &&
         a.image_stamp == b.image_stamp && a.exposure_time_s == b.exposure_time_s &&
         a.estimate_readout == b.estimate_readout && a.max_readout_s == b.max_readout_s &&
         a.readout_start_sigma_time_offset_s == b.readout_start_sigma_time_offset_s &&
         a.rates_window_s == b.rates_window_s &&
         a.estimate_focal_scale == b.estimate_focal_scale && a.max_focal_scale == b.max_focal_scale &&
         a.focal_start_sigma_time_offset_s == b.focal_start_sigma_time_offset_s &&
         a.focal_scale_consider == b.focal_scale_consider &&
         a.fixed_pattern.enabled == b.fixed_pattern.enabled &&
         a.fixed_pattern.decorrelation_px == b.fixed_pattern.decorrelation_px &&
         a.fixed_pattern.memory_samples == b.fixed_pattern.memory_samples &&
         a.fixed_pattern.startup_samples == b.fixed_pattern.startup_samples &&
         a.fixed_pattern.min_ground_patches == b.fixed_pattern.min_ground_patches &&
         a.fixed_pattern.scale_losses_waive_patches == b.fixed_pattern.scale_losses_waive_patches &&
         a.fixed_pattern.scale_loss_window_s == b.fixed_pattern.scale_loss_window_s &&
         a.fixed_pattern.significance_sigma == b.fixed_pattern.significance_sigma &&
         a.fixed_pattern.min_gain == b.fixed_pattern.min_gain &&
         a.fixed_pattern.refresh_frames == b.fixed_pattern.refresh_frames &&
         a.fixed_pattern.radial_vignetting == b.fixed_pattern.radial_vignetting &&
         a.fixed_pattern.report_fraction == b.fixed_pattern.report_fraction &&
         a.fixed_pattern.dominant_contrast_share == b.fixed_pattern.dominant_contrast_share &&
         a.fixed_pattern.auto_dot_removal_px == b.fixed_pattern.auto_dot_removal_px &&
         a.fixed_pattern.dot_detect_share == b.fixed_pattern.dot_detect_share &&
         a.fixed_pattern.dot_detect_contrast == b.fixed_pattern.dot_detect_contrast &&
         a.fixed_pattern.dot_detect_levels == b.fixed_pattern.dot_detect_levels &&
         a.fixed_pattern.max_dot_removal_px == b.fixed_pattern.max_dot_removal_px &&
         a.fixed_pattern.dot_fill == b.fixed_pattern.dot_fill &&
         a.fixed_pattern.dot_gain == b.fixed_pattern.dot_gain &&
         a.fixed_pattern.discount_biased_updates == b.fixed_pattern.discount_biased_updates &&
         a.fixed_pattern.vignetting_file == b.fixed_pattern.vignetting_file;
}

// Leaf keys ("a/b") of a YAML map.
void leafKeys(const YAML::Node& n, const std::string& prefix, std::set<std::string>* out) {
  for (const auto& kv : n) {
    const std::string key = prefix + kv.first.as<std::string>();
    if (kv.second.IsMap()) {
      leafKeys(kv.second, key + "/", out);
    } else {
      out->insert(key);
    }
  }
}

std::string estimatorYaml() { return packageDir() + "config/estimator.yaml"; }

TEST(YamlParamSource, NestedKeysAndTypes) {
  TempYaml f("types", "a:\n  b:\n    c: 3\n  x: 2.5\n  flag: true\n  name: hello\n  list: [1, 2.5, -3]\n"
                      "top: 7\nbadnum: abc\nbadlist: [1, x]\n");
  YamlParamSource src(f.path());
  EXPECT_EQ(src.origin(), f.path());
  double d = 0;
  ASSERT_TRUE(src.get("a/b/c", &d));  // an int where a double is expected
  EXPECT_EQ(d, 3.0);
  ASSERT_TRUE(src.get("a/x", &d));
  EXPECT_EQ(d, 2.5);
  int i = 0;
  ASSERT_TRUE(src.get("top", &i));
  EXPECT_EQ(i, 7);
  bool b = false;
  ASSERT_TRUE(src.get("a/flag", &b));
  EXPECT_TRUE(b);
  std::string s;
  ASSERT_TRUE(src.get("a/name", &s));
  EXPECT_EQ(s, "hello");
  std::vector<double> v;
  ASSERT_TRUE(src.get("a/list", &v));
  EXPECT_EQ(v, (std::vector<double>{1.0, 2.5, -3.0}));
  // Absent keys: false, value untouched.
  d = 42.0;
  EXPECT_FALSE(src.get("a/missing", &d));
  EXPECT_FALSE(src.get("nothere/deeper", &d));
  EXPECT_EQ(d, 42.0);
  // Wrong types: errors naming file and key.
  expectError([&] { src.get("a/x", &i); }, {f.path(), "a/x", "integer"});
  expectError([&] { src.get("badnum", &d); }, {f.path(), "badnum"});
  expectError([&] { src.get("a/name", &b); }, {f.path(), "a/name"});
  expectError([&] { src.get("a/list", &d); }, {f.path(), "a/list"});
  expectError([&] { src.get("a/b", &s); }, {f.path(), "a/b"});
  expectError([&] { src.get("badlist", &v); }, {f.path(), "badlist"});
  expectError([&] { src.get("top/sub", &d); }, {f.path(), "top/sub"});
  // Unreadable or malformed files.
  expectError([] { YamlParamSource("/nonexistent_diekf_dir/p.yaml"); }, {"/nonexistent_diekf_dir/p.yaml"});
  TempYaml bad("malformed", "a: [1, 2\nb: {\n");
  expectError([&] { YamlParamSource{bad.path()}; }, {bad.path()});
}

TEST(EstimatorParams, ConfigFileReproducesDefaultsExactly) {
  YamlParamSource src(estimatorYaml());
  EstimatorParams p;
  p.photometric.max_passes = 99;  // must be overwritten by the file
  p.init.mu0 = Vec3(1, 2, 3);
  loadEstimatorParams(src, &p);
  EXPECT_TRUE(sameParams(p, EstimatorParams{}));
}

TEST(EstimatorParams, ConfigFileHasExactlyTheTableKeys) {
  const YAML::Node root = YAML::LoadFile(estimatorYaml());
  std::set<std::string> in_file;
  leafKeys(root, "", &in_file);
  const auto table = estimatorParamKeys();
  const std::set<std::string> in_table(table.begin(), table.end());
  EXPECT_EQ(in_table.size(), table.size()) << "duplicate key in the table";
  for (const auto& k : in_table) EXPECT_EQ(in_file.count(k), 1u) << "config/estimator.yaml lacks " << k;
  for (const auto& k : in_file) EXPECT_EQ(in_table.count(k), 1u) << "config/estimator.yaml has unknown " << k;
  // Every key carries a comment (unit and meaning): check the raw text line by line.
  std::ifstream in(estimatorYaml());
  std::string line;
  int commented = 0;
  while (std::getline(in, line)) {
    const auto colon = line.find(':');
    if (line.empty() || line[0] == '#' || colon == std::string::npos) continue;
    const std::string rest = line.substr(colon + 1);
    if (rest.find_first_not_of(' ') == std::string::npos) continue;  // a section header ("imu:")
    EXPECT_NE(rest.find('#'), std::string::npos) << "no comment on: " << line;
    ++commented;
  }
  EXPECT_EQ(commented, static_cast<int>(table.size()));
}

// A non-default valid value for every key, derived from its default in the config file.
std::string perturbed(const std::string& key, const YAML::Node& def) {
  if (key == "mode") return "lk";
  if (key == "image_stamp") return "start";
  if (key == "photometric/brightness_model") return "gain";
  if (key == "line_delay_s") return "3.3e-05";  // s per row: a 16 ms readout of 480 rows
  if (key == "fixed_pattern/vignetting_file") return "flat_field.png";  // a path (read by the estimator, not here)
  if (key == "fixed_pattern/dot_detect_levels") return "1";  // (1..3)
  if (key == "input/stamp_smoothing_frames") return "64";  // (8..128)
  if (key == "photometric/spline_degree") return "5";  // (3, 5)
  if (def.IsSequence()) return "[0.1, 0.2, 0.9]";
  const std::string s = def.Scalar();
  if (s == "true") return "false";
  if (s == "false") return "true";
  if (s.find_first_of(".eE") == std::string::npos) return std::to_string(std::stoi(s) + 4);  // int (even step)
  const double v = def.as<double>();
  return std::to_string(v == 0.0 ? 0.5 : 1.5 * v);
}

TEST(EstimatorParams, EveryKeyChangesItsField) {
  const YAML::Node root = YAML::LoadFile(estimatorYaml());
  for (const std::string& key : estimatorParamKeys()) {
    // Build "a:\n  b: value" for the key.
    const auto slash = key.find('/');
    const YAML::Node def = slash == std::string::npos ? root[key] : root[key.substr(0, slash)][key.substr(slash + 1)];
    ASSERT_TRUE(def.IsDefined()) << key;
    const std::string value = perturbed(key, def);
    const std::string text = slash == std::string::npos
                                 ? key + ": " + value + "\n"
                                 : key.substr(0, slash) + ":\n  " + key.substr(slash + 1) + ": " + value + "\n";
    TempYaml f("perturb", text);
    EstimatorParams p;
    ASSERT_NO_THROW(loadEstimatorParams(YamlParamSource(f.path()), &p)) << key << " = " << value;
    EXPECT_FALSE(sameParams(p, EstimatorParams{})) << key << " = " << value << " changed nothing";
  }
  // Spot checks of the mapping.
  TempYaml f("spot", "mode: ekf\ninit:\n  mu0: [0, 0.6, 0.8]\nimu:\n  lowpass_cutoff_hz: 35\n"
                     "preprocess:\n  working_width_px: 180\nphotometric:\n  max_passes: 5\n");
  EstimatorParams p;
  loadEstimatorParams(YamlParamSource(f.path()), &p);
  EXPECT_EQ(p.mode, UpdateMode::kEkf);
  EXPECT_EQ(p.init.mu0, Vec3(0, 0.6, 0.8));
  EXPECT_EQ(p.imu.lowpass_cutoff_hz, 35.0);
  EXPECT_EQ(p.preprocess.working_width_px, 180);
  EXPECT_EQ(p.photometric.max_passes, 5);
  EXPECT_EQ(p.photometric.stop_threshold, PhotometricParams{}.stop_threshold);  // untouched
}

TEST(EstimatorParams, ValidationErrorsNameOriginAndKey) {
  struct Case {
    std::string text, key;
  };
  const std::vector<Case> cases = {
      {"imu:\n  lowpass_cutoff_hz: -1\n", "imu/lowpass_cutoff_hz"},
      {"imu:\n  lowpass_cutoff_hz: 300\n", "imu/lowpass_cutoff_hz"},  // above input_rate_hz / 2
      {"imu:\n  input_rate_hz: 30\n", "imu/input_rate_hz"},          // makes the 20 Hz cutoff invalid
      {"imu:\n  lowpass_order: 3\n", "imu/lowpass_order"},
      {"imu:\n  gravity_mps2: abc\n", "imu/gravity_mps2"},
      {"mode: fast\n", "mode"},
      {"init:\n  mu0: [0, 0, 0]\n", "init/mu0"},
      {"init:\n  g0: [0, 1]\n", "init/g0"},
      {"init:\n  alpha0_inv_m: 0\n", "init/alpha0_inv_m"},
      {"preprocess:\n  working_width_px: 90.5\n", "preprocess/working_width_px"},
      {"preprocess:\n  working_height_px: 2\n", "preprocess/working_height_px"},
      {"preprocess:\n  blur_sigma_px: -0.1\n", "preprocess/blur_sigma_px"},
      {"preprocess:\n  antialias_sigma_px: 3\n", "preprocess/antialias_sigma_px"},
      {"photometric:\n  max_passes: 0\n", "photometric/max_passes"},
      {"photometric:\n  min_valid_ratio: 1.5\n", "photometric/min_valid_ratio"},
      {"photometric:\n  brightness_model: linear\n", "photometric/brightness_model"},
      {"photometric:\n  spline_degree: 4\n", "photometric/spline_degree"},
      {"divergence:\n  max_distance_m: 0.01\n", "divergence/max_distance_m"},
      {"max_queued_images: 0\n", "max_queued_images"},
      {"preprocess: 5\n", "preprocess/"},
  };
  for (const Case& c : cases) {
    TempYaml f("invalid", c.text);
    EstimatorParams p;
    p.photometric.max_passes = 2;
    expectError([&] { loadEstimatorParams(YamlParamSource(f.path()), &p); }, {f.path(), c.key});
    EXPECT_EQ(p.photometric.max_passes, 2) << "params modified by a failed load: " << c.text;
  }
}

TEST(KalibrImu, SampleFileParses) {
  ImuParams imu;
  imu.lowpass_cutoff_hz = 33.0;
  loadKalibrImuYaml(packageDir() + "config/mynteye_imu.yaml", &imu);
  EXPECT_EQ(imu.accel_noise_density, 2.0e-2);
  EXPECT_EQ(imu.accel_random_walk, 2.0e-3);
  EXPECT_EQ(imu.gyro_noise_density, 1.7e-3);
  EXPECT_EQ(imu.gyro_random_walk, 2.0e-5);
  EXPECT_EQ(imu.input_rate_hz, 500.0);
  EXPECT_EQ(imu.decimation_factor, 5);
  EXPECT_EQ(imu.lowpass_cutoff_hz, 33.0);  // not an IMU-file key: untouched
}

// The file's rate changes the decimation, not the prediction's rate: 100 Hz from a 200, 500 or 1000 Hz IMU (at
// 200 Hz the configured factor of 5 would predict at 40 Hz), and a factor set for 500 Hz prediction stays that.
TEST(KalibrImu, RateKeepsThePredictionRate) {
  const auto decimationFor = [](const char* rate, int configured_factor) {
    TempYaml f("imu_rate",
               std::string("accelerometer_noise_density: 0.03\naccelerometer_random_walk: 0.004\n"
                           "gyroscope_noise_density: 0.002\ngyroscope_random_walk: 3.0e-5\nupdate_rate: ") +
                   rate + "\n");
    ImuParams imu;
    imu.decimation_factor = configured_factor;
    loadKalibrImuYaml(f.path(), &imu);
    return imu.decimation_factor;
  };
  EXPECT_EQ(decimationFor("200", 5), 2);
  EXPECT_EQ(decimationFor("500", 5), 5);
  EXPECT_EQ(decimationFor("1000", 5), 10);
  EXPECT_EQ(decimationFor("100", 5), 1);
  EXPECT_EQ(decimationFor("50", 5), 1);  // never below one
  EXPECT_EQ(decimationFor("200", 1), 1);  // 500 Hz prediction asked for: every sample of the 200 Hz IMU
}

TEST(KalibrImu, TopLevelKeysAndErrors) {
  const std::string body =
      "accelerometer_noise_density: 0.03\naccelerometer_random_walk: 0.004\ngyroscope_noise_density: 0.002\n"
      "gyroscope_random_walk: 3.0e-5\nupdate_rate: 200\nrostopic: /imu\n";
  {
    TempYaml f("imu_top", body);
    ImuParams imu;
    loadKalibrImuYaml(f.path(), &imu);
    EXPECT_EQ(imu.accel_noise_density, 0.03);
    EXPECT_EQ(imu.gyro_random_walk, 3.0e-5);
    EXPECT_EQ(imu.input_rate_hz, 200.0);
  }
  {
    TempYaml f("imu_missing", "imu0:\n  accelerometer_noise_density: 0.03\n  accelerometer_random_walk: 0.004\n"
                              "  gyroscope_noise_density: 0.002\n  update_rate: 200\n");
    ImuParams imu;
    expectError([&] { loadKalibrImuYaml(f.path(), &imu); }, {f.path(), "imu0/gyroscope_random_walk", "missing"});
    EXPECT_EQ(imu.accel_noise_density, ImuParams{}.accel_noise_density);  // unchanged on error
  }
  {
    std::string text = body;
    text.replace(text.find("0.002"), 5, "fast");
    TempYaml f("imu_text", text);
    ImuParams imu;
    expectError([&] { loadKalibrImuYaml(f.path(), &imu); }, {f.path(), "gyroscope_noise_density"});
  }
  {
    std::string text = body;
    text.replace(text.find("200"), 3, "-5");
    TempYaml f("imu_neg", text);
    ImuParams imu;
    expectError([&] { loadKalibrImuYaml(f.path(), &imu); }, {f.path(), "update_rate"});
  }
  ImuParams imu;
  expectError([&] { loadKalibrImuYaml("/nonexistent_diekf_dir/imu.yaml", &imu); }, {"/nonexistent_diekf_dir/imu.yaml"});
}

// Keys of a parameter file that no parameter reads are ignored with a warning through the callback (file, key,
// closest known key), before any value is read; known keys and groups are not reported; values still load.
TEST(EstimatorParams, UnknownKeysWarnWithTheClosestKnownKey) {
  TempYaml f("unknown", "mode: ekf\nphotometric:\n  max_pases: 5\n  stop_threshold: 0.01\n"
                        "max_passes: 4\nimu:\n  lowpass_cutof_hz: 30\nfeature:\nnode_setting: x\n");
  const YamlParamSource src(f.path());
  EXPECT_EQ(src.keys(), (std::vector<std::string>{"mode", "photometric/max_pases", "photometric/stop_threshold",
                                                  "max_passes", "imu/lowpass_cutof_hz", "feature", "node_setting"}));
  std::vector<std::string> warnings;
  EstimatorParams p;
  loadEstimatorParams(src, &p, [&](const std::string& w) { warnings.push_back(w); });
  ASSERT_EQ(warnings.size(), 4u);
  const std::vector<std::pair<std::string, std::string>> expected = {
      {"photometric/max_pases", "photometric/max_passes"},
      {"max_passes", "photometric/max_passes"},  // a key without its group
      {"imu/lowpass_cutof_hz", "imu/lowpass_cutoff_hz"},
      {"node_setting", ""}};
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_NE(warnings[i].find(f.path()), std::string::npos) << warnings[i];
    EXPECT_NE(warnings[i].find("'" + expected[i].first + "'"), std::string::npos) << warnings[i];
    if (!expected[i].second.empty()) {
      EXPECT_NE(warnings[i].find("closest known key: '" + expected[i].second + "'"), std::string::npos)
          << warnings[i];
    }
  }
  // The known keys were read; the unknown ones changed nothing.
  EXPECT_EQ(p.mode, UpdateMode::kEkf);
  EXPECT_EQ(p.photometric.stop_threshold, 0.01);
  EXPECT_EQ(p.photometric.max_passes, PhotometricParams{}.max_passes);
  EXPECT_EQ(p.imu.lowpass_cutoff_hz, ImuParams{}.lowpass_cutoff_hz);

  // The same list from unknownParamKeys; a front end's own keys are not reported.
  const std::vector<UnknownParamKey> unknown = unknownParamKeys(src, {"node_setting"});
  ASSERT_EQ(unknown.size(), 3u);
  EXPECT_EQ(unknown[0].origin, f.path());
  EXPECT_EQ(unknown[0].key, "photometric/max_pases");
  EXPECT_EQ(unknown[0].closest, "photometric/max_passes");
  EXPECT_EQ(unknown[2].closest, "imu/lowpass_cutoff_hz");
  EXPECT_EQ(unknown[0].message(), f.path() + ": unknown parameter key 'photometric/max_pases' ignored (closest "
                                              "known key: 'photometric/max_passes')");
  warnings.clear();
  loadEstimatorParams(src, &p, [&](const std::string& w) { warnings.push_back(w); }, {"node_setting"});
  EXPECT_EQ(warnings.size(), 3u);

  // A warning is not an error: a bad value still throws, and the shipped config file warns about nothing.
  warnings.clear();
  loadEstimatorParams(YamlParamSource(estimatorYaml()), &p, [&](const std::string& w) { warnings.push_back(w); });
  EXPECT_TRUE(warnings.empty()) << warnings.front();
  TempYaml bad("unknown_bad", "photometric:\n  max_pases: 5\n  max_passes: 0\n");
  warnings.clear();
  expectError([&] { loadEstimatorParams(YamlParamSource(bad.path()), &p, [&](const std::string& w) {
                      warnings.push_back(w);
                    }); },
              {bad.path(), "photometric/max_passes"});
  EXPECT_EQ(warnings.size(), 1u);
}

}  // namespace
}  // namespace diekf
