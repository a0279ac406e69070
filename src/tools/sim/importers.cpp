// mynteye-folder and EuRoC MAV importers.
#include "diekf/sim/importers.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

#include "diekf/grey_image.h"
#include "diekf/sim/sequence_io.h"

namespace diekf {
namespace sim {
namespace {

namespace fs = std::filesystem;

std::string trim(const std::string& s) {
  const std::size_t a = s.find_first_not_of(" \t\r\n");
  if (a == std::string::npos) return "";
  const std::size_t b = s.find_last_not_of(" \t\r\n");
  return s.substr(a, b - a + 1);
}

std::vector<std::string> splitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string f;
  while (std::getline(ss, f, ',')) out.push_back(trim(f));
  if (!line.empty() && line.back() == ',') out.push_back("");
  return out;
}

bool toDouble(const std::string& s, double* v) {
  if (s.empty()) return false;
  try {
    std::size_t pos = 0;
    *v = std::stod(s, &pos);
    return pos == s.size() && std::isfinite(*v);
  } catch (...) {
    return false;
  }
}

std::string shorten(const std::string& s) { return s.size() > 60 ? s.substr(0, 57) + "..." : s; }

/// Reads an image as mono8 (8/16-bit grey or colour accepted); throws naming the file.
cv::Mat readMono8(const std::string& path) {
  cv::Mat im = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (im.empty()) throw std::runtime_error("cannot read image '" + path + "'");
  cv::Mat grey;  // imread gives colour in BGR order; 16-bit scaled by 1/256
  if (!toGrey8(im, ChannelOrder::kBgr, &grey)) {
    throw std::runtime_error("unsupported pixel depth or channel count in '" + path + "'");
  }
  return grey;
}

/// Loads a YAML file, dropping OpenCV's "%YAML:1.0" header line (EuRoC sensor.yaml) that yaml-cpp rejects.
YAML::Node loadYamlLenient(const std::string& path) {
  std::ifstream f(path);
  if (!f) throw std::runtime_error("cannot open '" + path + "'");
  std::stringstream text;
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("%YAML", 0) != 0) text << line << "\n";
  try {
    return YAML::Load(text.str());
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot parse '" + path + "': " + e.what());
  }
}

std::vector<double> yamlNumbers(const YAML::Node& n, const std::string& path, const std::string& key, std::size_t count) {
  if (!n || !n.IsSequence() || (count > 0 && n.size() != count))
    throw std::runtime_error("'" + path + "': key '" + key + "' needs " + std::to_string(count) + " numbers");
  std::vector<double> v;
  try {
    for (const auto& x : n) v.push_back(x.as<double>());
  } catch (const std::exception&) {
    throw std::runtime_error("'" + path + "': key '" + key + "' has a non-numeric entry");
  }
  return v;
}

Eigen::Matrix4d eurocTBS(const YAML::Node& root, const std::string& path) {
  const YAML::Node t = root["T_BS"];
  if (!t) throw std::runtime_error("'" + path + "': missing key 'T_BS'");
  const auto d = yamlNumbers(t["data"], path, "T_BS.data", 16);
  Eigen::Matrix4d T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T(r, c) = d[static_cast<std::size_t>(4 * r + c)];
  return T;
}

/// EuRoC cam0 sensor.yaml (+ imu0 sensor.yaml for T_BS of the IMU) -> CameraModel.
CameraModel eurocCamera(const std::string& cam_yaml, const std::string& imu_yaml_path) {
  const YAML::Node root = loadYamlLenient(cam_yaml);
  CameraModel cam;
  const auto in = yamlNumbers(root["intrinsics"], cam_yaml, "intrinsics", 4);
  cam.K.fx = in[0];
  cam.K.fy = in[1];
  cam.K.cx = in[2];
  cam.K.cy = in[3];
  const auto res = yamlNumbers(root["resolution"], cam_yaml, "resolution", 2);
  cam.K.width = static_cast<int>(res[0]);
  cam.K.height = static_cast<int>(res[1]);
  const std::string model = root["distortion_model"] ? root["distortion_model"].as<std::string>() : "radial-tangential";
  if (model == "radial-tangential" || model == "radtan" || model == "plumb_bob") {
    cam.distortion = DistortionModel::kRadTan;
  } else if (model == "equidistant" || model == "fisheye") {
    cam.distortion = DistortionModel::kEquidistant;
  } else {
    throw std::runtime_error("'" + cam_yaml + "': unsupported distortion_model '" + model + "'");
  }
  const auto dc = yamlNumbers(root["distortion_coefficients"], cam_yaml, "distortion_coefficients", 0);
  if (dc.size() < 4) throw std::runtime_error("'" + cam_yaml + "': distortion_coefficients needs 4 numbers");
  cam.distortion_coeffs = Vec4(dc[0], dc[1], dc[2], dc[3]);
  Eigen::Matrix4d T_B_cam = eurocTBS(root, cam_yaml);
  Eigen::Matrix4d T_B_imu = Eigen::Matrix4d::Identity();
  if (!imu_yaml_path.empty() && fs::exists(imu_yaml_path)) T_B_imu = eurocTBS(loadYamlLenient(imu_yaml_path), imu_yaml_path);
  const Eigen::Matrix4d T_cam_imu = T_B_cam.inverse() * T_B_imu;
  cam.T_cam_imu.matrix() = T_cam_imu;
  // Re-orthonormalise the rotation (EuRoC prints it with limited precision).
  const Eigen::JacobiSVD<Mat3> svd(cam.T_cam_imu.linear(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  cam.T_cam_imu.linear() = svd.matrixU() * svd.matrixV().transpose();
  return cam;
}

ImuNoiseParams eurocImuNoise(const std::string& path) {
  const YAML::Node root = loadYamlLenient(path);
  ImuNoiseParams n;
  const auto get = [&](const char* key, double* out) {
    if (root[key]) *out = root[key].as<double>();
  };
  get("gyroscope_noise_density", &n.gyro_noise_density);
  get("gyroscope_random_walk", &n.gyro_random_walk);
  get("accelerometer_noise_density", &n.accel_noise_density);
  get("accelerometer_random_walk", &n.accel_random_walk);
  get("rate_hz", &n.rate_hz);
  return n;
}

struct ImageEntry {
  std::int64_t t_ns = 0;
  std::string path;
};
struct PoseEntry {
  std::int64_t t_ns = 0;
  Mat3 R = Mat3::Identity();
  Vec3 p = Vec3::Zero();
};
struct ImuEntry {
  std::int64_t t_ns = 0;
  Vec3 a = Vec3::Zero(), w = Vec3::Zero();
};

void requireIncreasing(const std::string& path, const std::vector<CsvRow>& rows) {
  for (std::size_t i = 1; i < rows.size(); ++i)
    if (!(rows[i].v[0] > rows[i - 1].v[0]))
      throw std::runtime_error(path + ":" + std::to_string(rows[i].line) + ": timestamp not increasing");
}

/// Writes the merged streams in stamp order.
ImportSummary writeSequence(const ImportOptions& opt, const CameraModel& cam, const ImuNoiseParams& noise,
                            const std::vector<ImuEntry>& imu, const std::vector<PoseEntry>& poses,
                            const std::vector<ImageEntry>& images) {
  fs::create_directories(opt.output_dir);
  ImportSummary sum;
  TopicNames topics;
  writeCamchainYaml((fs::path(opt.output_dir) / "camchain.yaml").string(), cam, topics.image);
  writeImuYaml((fs::path(opt.output_dir) / "imu.yaml").string(), noise, topics.imu);
  sum.bag_path = (fs::path(opt.output_dir) / "sequence.bag").string();
  SequenceBagWriter bag(sum.bag_path, topics, opt.lz4);
  std::size_t i_imu = 0, i_pose = 0;
  const auto flushUntil = [&](std::int64_t t_ns) {
    while (true) {
      const std::int64_t ti = i_imu < imu.size() ? imu[i_imu].t_ns : INT64_MAX;
      const std::int64_t tp = i_pose < poses.size() ? poses[i_pose].t_ns : INT64_MAX;
      const std::int64_t tn = std::min(ti, tp);
      if (tn == INT64_MAX || tn > t_ns) break;
      if (ti <= tp) {
        bag.writeImu(ti, imu[i_imu].a, imu[i_imu].w, static_cast<std::uint32_t>(i_imu));
        ++i_imu;
      } else {
        bag.writePose(tp, poses[i_pose].R, poses[i_pose].p, static_cast<std::uint32_t>(i_pose));
        ++i_pose;
      }
    }
  };
  for (std::size_t k = 0; k < images.size(); ++k) {
    flushUntil(images[k].t_ns);
    const cv::Mat im = readMono8(images[k].path);
    if (im.cols != cam.K.width || im.rows != cam.K.height)
      sum.notes.push_back("image size " + std::to_string(im.cols) + "x" + std::to_string(im.rows) + " of '" +
                          images[k].path + "' differs from the calibration resolution");
    bag.writeImage(images[k].t_ns, im, static_cast<std::uint32_t>(k));
  }
  flushUntil(INT64_MAX);
  bag.close();
  sum.images = images.size();
  sum.imu = imu.size();
  sum.poses = poses.size();
  // Keep only the first size note.
  if (sum.notes.size() > 1) sum.notes.resize(1);
  return sum;
}

/// Calibration precedence: explicit option, file in the dataset, default.
CameraModel chooseCamera(const ImportOptions& opt, const std::string& dataset_camchain, CameraModel fallback,
                         std::vector<std::string>* notes, const std::string& fallback_note) {
  if (!opt.camchain.empty()) return CameraModel::fromKalibrYaml(opt.camchain);
  if (!dataset_camchain.empty() && fs::exists(dataset_camchain)) return CameraModel::fromKalibrYaml(dataset_camchain);
  if (!fallback_note.empty()) notes->push_back(fallback_note);
  return fallback;
}

ImportSummary importMynteye(const ImportOptions& opt) {
  const fs::path in(opt.input_dir);
  const std::string imu_csv = (in / "imu0.csv").string();
  if (!fs::exists(imu_csv)) throw std::runtime_error("missing IMU file '" + imu_csv + "'");
  const fs::path left = in / "left";
  if (!fs::is_directory(left)) throw std::runtime_error("missing image folder '" + left.string() + "'");
  const auto rows = readNumericCsv(imu_csv, 7, 7);
  requireIncreasing(imu_csv, rows);
  std::vector<ImuEntry> imu;
  for (const CsvRow& r : rows) {
    ImuEntry e;
    e.t_ns = static_cast<std::int64_t>(std::llround(r.v[0] * 1000.0));
    e.a = Vec3(r.v[1], r.v[2], r.v[3]);
    e.w = Vec3(r.v[4], r.v[5], r.v[6]);
    imu.push_back(e);
  }
  std::vector<ImageEntry> images;
  for (const auto& de : fs::directory_iterator(left)) {
    if (!de.is_regular_file()) continue;
    const std::string ext = de.path().extension().string();
    if (ext != ".png" && ext != ".PNG") continue;
    const std::string stem = de.path().stem().string();
    double t_us = 0;
    if (!toDouble(stem, &t_us) || t_us < 0)
      throw std::runtime_error("image name '" + de.path().string() + "' is not <t_us>.png");
    images.push_back({static_cast<std::int64_t>(std::llround(t_us * 1000.0)), de.path().string()});
  }
  if (images.empty()) throw std::runtime_error("no <t_us>.png image in '" + left.string() + "'");
  std::sort(images.begin(), images.end(), [](const ImageEntry& a, const ImageEntry& b) { return a.t_ns < b.t_ns; });
  std::vector<std::string> notes;
  const CameraModel cam = chooseCamera(opt, (in / "camchain.yaml").string(), myntEyeDefaultCamera(), &notes,
                                       "no camchain.yaml given or in the folder: wrote typical MYNT EYE S values");
  ImuNoiseParams noise;
  if (!opt.imu_yaml.empty()) noise = readImuYaml(opt.imu_yaml);
  else if (fs::exists(in / "imu.yaml")) noise = readImuYaml((in / "imu.yaml").string());
  else if (imu.size() > 1)
    noise.rate_hz = std::round(1e9 * (imu.size() - 1) / static_cast<double>(imu.back().t_ns - imu.front().t_ns));
  ImportSummary s = writeSequence(opt, cam, noise, imu, {}, images);
  s.notes.insert(s.notes.begin(), notes.begin(), notes.end());
  return s;
}

ImportSummary importEuroc(const ImportOptions& opt) {
  fs::path mav = fs::path(opt.input_dir) / "mav0";
  if (!fs::is_directory(mav)) {
    if (fs::is_directory(fs::path(opt.input_dir) / "imu0")) mav = fs::path(opt.input_dir);  // given mav0 itself
    else throw std::runtime_error("missing EuRoC folder '" + mav.string() + "'");
  }
  const std::string imu_csv = (mav / "imu0" / "data.csv").string();
  const std::string cam_csv = (mav / "cam0" / "data.csv").string();
  const std::string gt_csv = (mav / "state_groundtruth_estimate0" / "data.csv").string();
  if (!fs::exists(imu_csv)) throw std::runtime_error("missing IMU file '" + imu_csv + "'");
  if (!fs::exists(cam_csv)) throw std::runtime_error("missing image list '" + cam_csv + "'");

  const auto rows = readNumericCsv(imu_csv, 7, 7);
  requireIncreasing(imu_csv, rows);
  std::vector<ImuEntry> imu;
  for (const CsvRow& r : rows) {  // t_ns, w_x, w_y, w_z, a_x, a_y, a_z
    ImuEntry e;
    e.t_ns = static_cast<std::int64_t>(r.v[0]);
    e.w = Vec3(r.v[1], r.v[2], r.v[3]);
    e.a = Vec3(r.v[4], r.v[5], r.v[6]);
    imu.push_back(e);
  }
  // cam0/data.csv: "t_ns,filename" -- the second field is a name, parse it by hand.
  std::vector<ImageEntry> images;
  {
    std::ifstream f(cam_csv);
    if (!f) throw std::runtime_error("cannot open '" + cam_csv + "'");
    std::string line;
    std::size_t ln = 0;
    bool first = true;
    while (std::getline(f, line)) {
      ++ln;
      const std::string t = trim(line);
      if (t.empty() || t[0] == '#') continue;
      const auto fields = splitCsv(t);
      double ts = 0;
      if (fields.size() != 2 || !toDouble(fields[0], &ts) || fields[1].empty()) {
        if (first && fields.size() == 2 && !toDouble(fields[0], &ts)) {
          first = false;
          continue;  // header
        }
        throw std::runtime_error(cam_csv + ":" + std::to_string(ln) + ": expected 'timestamp_ns,filename', got '" +
                                 shorten(t) + "'");
      }
      first = false;
      const std::string p = (mav / "cam0" / "data" / fields[1]).string();
      if (!fs::exists(p)) throw std::runtime_error(cam_csv + ":" + std::to_string(ln) + ": image '" + p + "' not found");
      images.push_back({static_cast<std::int64_t>(ts), p});
    }
  }
  if (images.empty()) throw std::runtime_error("no image listed in '" + cam_csv + "'");
  std::sort(images.begin(), images.end(), [](const ImageEntry& a, const ImageEntry& b) { return a.t_ns < b.t_ns; });

  std::vector<PoseEntry> poses;
  std::vector<std::string> notes;
  if (fs::exists(gt_csv)) {
    const auto g = readNumericCsv(gt_csv, 8, 64);
    requireIncreasing(gt_csv, g);
    for (const CsvRow& r : g) {  // t_ns, p(3), q(w, x, y, z), ...
      PoseEntry e;
      e.t_ns = static_cast<std::int64_t>(r.v[0]);
      e.p = Vec3(r.v[1], r.v[2], r.v[3]);
      Eigen::Quaterniond q(r.v[4], r.v[5], r.v[6], r.v[7]);
      if (!(q.norm() > 0.5 && q.norm() < 1.5))
        throw std::runtime_error(gt_csv + ":" + std::to_string(r.line) + ": quaternion is not unit");
      e.R = q.normalized().toRotationMatrix();
      poses.push_back(e);
    }
  } else {
    notes.push_back("no ground truth ('" + gt_csv + "' missing): bag has no /mocap/pose");
  }
  const std::string cam_yaml = (mav / "cam0" / "sensor.yaml").string();
  const std::string imu_yaml = (mav / "imu0" / "sensor.yaml").string();
  CameraModel cam;
  if (!opt.camchain.empty()) {
    cam = CameraModel::fromKalibrYaml(opt.camchain);
  } else if (fs::exists(cam_yaml)) {
    cam = eurocCamera(cam_yaml, imu_yaml);
  } else {
    throw std::runtime_error("no camera calibration: '" + cam_yaml + "' missing and no --camchain given");
  }
  ImuNoiseParams noise;
  if (!opt.imu_yaml.empty()) noise = readImuYaml(opt.imu_yaml);
  else if (fs::exists(imu_yaml)) noise = eurocImuNoise(imu_yaml);
  ImportSummary s = writeSequence(opt, cam, noise, imu, poses, images);
  s.notes.insert(s.notes.begin(), notes.begin(), notes.end());
  return s;
}

}  // namespace

std::vector<CsvRow> readNumericCsv(const std::string& path, std::size_t min_fields, std::size_t max_fields) {
  std::ifstream f(path);
  if (!f) throw std::runtime_error("cannot open '" + path + "'");
  std::vector<CsvRow> rows;
  std::string line;
  std::size_t ln = 0;
  bool seen_data_or_header = false;
  while (std::getline(f, line)) {
    ++ln;
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    const auto fields = splitCsv(t);
    CsvRow row;
    row.line = ln;
    bool numeric = true;
    for (const std::string& s : fields) {
      double v = 0;
      if (!toDouble(s, &v)) {
        numeric = false;
        break;
      }
      row.v.push_back(v);
    }
    if (!numeric) {
      if (!seen_data_or_header) {  // header line
        seen_data_or_header = true;
        continue;
      }
      throw std::runtime_error(path + ":" + std::to_string(ln) + ": non-numeric field in '" + shorten(t) + "'");
    }
    seen_data_or_header = true;
    if (row.v.size() < min_fields || row.v.size() > max_fields) {
      std::ostringstream os;
      os << path << ":" << ln << ": expected " << min_fields;
      if (max_fields != min_fields) os << ".." << max_fields;
      os << " fields, got " << row.v.size();
      throw std::runtime_error(os.str());
    }
    rows.push_back(std::move(row));
  }
  if (rows.empty()) throw std::runtime_error("'" + path + "' holds no data row");
  return rows;
}

CameraModel myntEyeDefaultCamera() {
  CameraModel cam;
  cam.K.fx = 364.91;
  cam.K.fy = 364.97;
  cam.K.cx = 379.91;
  cam.K.cy = 245.53;
  cam.K.width = 752;
  cam.K.height = 480;
  cam.distortion = DistortionModel::kRadTan;
  cam.distortion_coeffs = Vec4(-0.3178, 0.0962, -0.00011, 0.00033);
  Mat3 R;
  R << 0, 1, 0, -1, 0, 0, 0, 0, 1;  // x_C = y_I, y_C = -x_I, z_C = z_I (IMU in the camera module)
  cam.T_cam_imu.linear() = R;
  cam.T_cam_imu.translation() = Vec3(0.048, -0.004, -0.012);
  cam.rostopic = "/mynteye/left/image_raw";
  return cam;
}

ImportSummary runImport(const ImportOptions& opt) {
  if (opt.format == "mynteye-folder") return importMynteye(opt);
  if (opt.format == "euroc") return importEuroc(opt);
  throw std::runtime_error("unknown format '" + opt.format + "' (mynteye-folder or euroc)");
}

std::string importUsage() {
  return "usage: diekf_import --format mynteye-folder|euroc --input DIR --output DIR [--camchain FILE]\n"
         "                    [--imu-yaml FILE] [--lz4]\n"
         "  -> DIR/sequence.bag (docs/conventions.md topics), DIR/camchain.yaml, DIR/imu.yaml\n"
         "mynteye-folder: DIR/imu0.csv (t_us, ax, ay, az, gx, gy, gz; header line allowed) and DIR/left/<t_us>.png;\n"
         "                calibration from --camchain, DIR/camchain.yaml, or typical MYNT EYE S values.\n"
         "euroc:          DIR/mav0/{imu0,cam0}/data.csv, cam0/data/*.png, state_groundtruth_estimate0/data.csv\n"
         "                (-> /mocap/pose), cam0/sensor.yaml (-> camchain.yaml), imu0/sensor.yaml (-> imu.yaml).\n";
}

int parseImportArgs(const std::vector<std::string>& args, ImportOptions* opt, std::string* error) {
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a == "--help" || a == "-h") return 1;
    if (a == "--lz4") {
      opt->lz4 = true;
      continue;
    }
    std::string* target = a == "--format"     ? &opt->format
                          : a == "--input"    ? &opt->input_dir
                          : a == "--output"   ? &opt->output_dir
                          : a == "--camchain" ? &opt->camchain
                          : a == "--imu-yaml" ? &opt->imu_yaml
                                              : nullptr;
    if (!target) {
      *error = "unknown argument '" + a + "' (see --help)";
      return -1;
    }
    if (i + 1 >= args.size()) {
      *error = "missing value after " + a;
      return -1;
    }
    *target = args[++i];
  }
  if (opt->format != "mynteye-folder" && opt->format != "euroc") {
    *error = opt->format.empty() ? "--format is required (mynteye-folder or euroc)"
                                 : "unknown format '" + opt->format + "' (mynteye-folder or euroc)";
    return -1;
  }
  if (opt->input_dir.empty() || opt->output_dir.empty()) {
    *error = "--input DIR and --output DIR are required";
    return -1;
  }
  return 0;
}

}  // namespace sim
}  // namespace diekf
