#include "diekf/eval/io.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace diekf {
namespace eval {

namespace {

/// Shortest round-trip-safe text of a double ("nan"/"inf" for non-finite values).
std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.10g", v);
  return buf;
}

std::string jsonNum(double v) { return std::isfinite(v) ? num(v) : std::string("null"); }

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

std::vector<std::string> splitCsv(const std::string& line) {
  std::vector<std::string> fields;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) fields.push_back(field);
  if (!line.empty() && line.back() == ',') fields.emplace_back();
  return fields;
}

double parseDouble(const std::string& text, const std::string& where) {
  // strtod accepts "nan" and "inf", which a diverged run may legitimately contain.
  const char* begin = text.c_str();
  char* end = nullptr;
  const double v = std::strtod(begin, &end);
  if (end == begin || *end != '\0') throw std::runtime_error(where + ": not a number: '" + text + "'");
  return v;
}

}  // namespace

const char* estimatesCsvHeader() {
  return "t,d,h,vx,vy,vz,mux,muy,muz,gx,gy,gz,sigma_d,sigma_vx,sigma_vy,sigma_vz,iterations,update_ms,status";
}

const char* groundTruthCsvHeader() { return "t,d,h,vx,vy,vz,mux,muy,muz,gx,gy,gz"; }

std::string formatEstimateRow(const EstimateRow& r) {
  char t[64];
  std::snprintf(t, sizeof(t), "%.9f", r.t_s);
  std::string s = t;
  const double values[] = {r.d_m,  r.h_m,  r.v_mps.x(), r.v_mps.y(), r.v_mps.z(), r.mu.x(),
                           r.mu.y(), r.mu.z(), r.g.x(),  r.g.y(),    r.g.z(),    r.sigma_d_m,
                           r.sigma_v_mps.x(), r.sigma_v_mps.y(), r.sigma_v_mps.z()};
  for (double v : values) s += "," + num(v);
  s += "," + std::to_string(r.iterations);
  char ms[64];
  std::snprintf(ms, sizeof(ms), "%.4f", r.update_ms);
  s += ",";
  s += ms;
  s += "," + r.status;
  return s;
}

std::string formatTruthRow(const TruthSample& tr) {
  char t[64];
  std::snprintf(t, sizeof(t), "%.9f", tr.t_s);
  std::string s = t;
  const double values[] = {tr.d_m,     tr.h_m,     tr.v_C_mps.x(), tr.v_C_mps.y(), tr.v_C_mps.z(), tr.mu_C.x(),
                           tr.mu_C.y(), tr.mu_C.z(), tr.g_C.x(),    tr.g_C.y(),     tr.g_C.z()};
  for (double v : values) s += "," + num(v);
  return s;
}

EstimatesCsvWriter::EstimatesCsvWriter(const std::string& path) : path_(path), out_(path) {
  if (!out_) throw std::runtime_error("cannot write " + path_);
  out_ << estimatesCsvHeader() << '\n';
}

void EstimatesCsvWriter::write(const EstimateRow& row) {
  out_ << formatEstimateRow(row) << '\n';
  if (!out_) throw std::runtime_error("write error on " + path_);
}

void EstimatesCsvWriter::close() {
  if (!out_.is_open()) return;
  out_.flush();
  if (!out_) throw std::runtime_error("write error on " + path_);
  out_.close();
}

std::vector<EstimateRow> readEstimatesCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::string line;
  if (!std::getline(in, line)) throw std::runtime_error(path + ": empty file");
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != estimatesCsvHeader()) throw std::runtime_error(path + ": unexpected header '" + line + "'");
  std::vector<EstimateRow> rows;
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    const std::string where = path + ":" + std::to_string(line_no);
    const std::vector<std::string> f = splitCsv(line);
    if (f.size() != 19) {
      throw std::runtime_error(where + ": expected 19 fields, got " + std::to_string(f.size()));
    }
    EstimateRow r;
    double v[18];
    for (int i = 0; i < 18; ++i) v[i] = parseDouble(f[static_cast<std::size_t>(i)], where);
    r.t_s = v[0];
    r.d_m = v[1];
    r.h_m = v[2];
    r.v_mps = Eigen::Vector3d(v[3], v[4], v[5]);
    r.mu = Eigen::Vector3d(v[6], v[7], v[8]);
    r.g = Eigen::Vector3d(v[9], v[10], v[11]);
    r.sigma_d_m = v[12];
    r.sigma_v_mps = Eigen::Vector3d(v[13], v[14], v[15]);
    if (v[16] != std::floor(v[16])) throw std::runtime_error(where + ": iterations is not an integer");
    r.iterations = static_cast<int>(v[16]);
    r.update_ms = v[17];
    r.status = f[18];
    if (r.status != "initializing" && r.status != "tracking" && r.status != "degraded" && r.status != "reset") {
      throw std::runtime_error(where + ": unknown status '" + r.status + "'");
    }
    rows.push_back(r);
  }
  return rows;
}

void writeGroundTruthCsv(const std::string& path, const std::vector<TruthSample>& truth) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << groundTruthCsvHeader() << '\n';
  for (const TruthSample& t : truth) out << formatTruthRow(t) << '\n';
  out.flush();
  if (!out) throw std::runtime_error("write error on " + path);
}

std::string evaluationToJson(const Evaluation& e) {
  std::ostringstream o;
  o << "{\n"
    << "  \"sequence\": " << jsonString(e.sequence) << ",\n"
    << "  \"frames\": " << e.frames << ",\n"
    << "  \"duration_s\": " << jsonNum(e.duration_s) << ",\n"
    << "  \"rmse_distance_m\": " << jsonNum(e.rmse_distance_m) << ",\n"
    << "  \"rmse_height_m\": " << jsonNum(e.rmse_height_m) << ",\n"
    << "  \"rmse_velocity_mps\": " << jsonNum(e.rmse_velocity_mps) << ",\n"
    << "  \"rms_normal_deg\": " << jsonNum(e.rms_normal_deg) << ",\n"
    << "  \"rms_gravity_deg\": " << jsonNum(e.rms_gravity_deg) << ",\n"
    << "  \"max_normal_deg\": " << jsonNum(e.max_normal_deg) << ",\n"
    << "  \"max_gravity_deg\": " << jsonNum(e.max_gravity_deg) << ",\n"
    << "  \"coverage2_d\": " << jsonNum(e.coverage2_d) << ",\n"
    << "  \"coverage2_v\": " << jsonNum(e.coverage2_v) << ",\n"
    << "  \"nees_mean\": " << jsonNum(e.nees_mean) << ",\n"
    << "  \"diverged\": " << (e.diverged ? "true" : "false") << ",\n"
    << "  \"update_ms_mean\": " << jsonNum(e.update_ms_mean) << ",\n"
    << "  \"update_ms_median\": " << jsonNum(e.update_ms_median) << ",\n"
    << "  \"update_ms_p99\": " << jsonNum(e.update_ms_p99) << ",\n"
    << "  \"realtime_factor\": " << jsonNum(e.realtime_factor) << ",\n"
    << "  \"frames_total\": " << e.frames_total << ",\n"
    << "  \"eval_start_s\": " << jsonNum(e.eval_start_s) << ",\n"
    << "  \"wall_time_s\": " << jsonNum(e.wall_time_s) << ",\n"
    << "  \"nees_median\": " << jsonNum(e.nees_median) << ",\n"
    << "  \"coverage2_d_last_half\": " << jsonNum(e.coverage2_d_last_half) << ",\n"
    << "  \"coverage2_v_last_half\": " << jsonNum(e.coverage2_v_last_half) << ",\n"
    << "  \"nees_mean_last_half\": " << jsonNum(e.nees_mean_last_half) << ",\n"
    << "  \"consistency_frames\": " << e.consistency_frames << ",\n"
    << "  \"consistency_frames_excluded\": " << e.consistency_frames_excluded << ",\n"
    << "  \"tracking_frames\": " << e.tracking_frames << ",\n"
    << "  \"tracking_beyond3_d\": " << e.tracking_beyond3_d << ",\n"
    << "  \"max_abs_z_d_tracking\": " << jsonNum(e.max_abs_z_d_tracking) << ",\n"
    << "  \"tracking_beyond3_v\": " << e.tracking_beyond3_v << ",\n"
    << "  \"max_abs_z_v_tracking\": " << jsonNum(e.max_abs_z_v_tracking) << ",\n"
    << "  \"divergence_reason\": " << jsonString(e.divergence_reason) << "\n"
    << "}\n";
  return o.str();
}

void writeEvaluationJson(const std::string& path, const Evaluation& evaluation) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << evaluationToJson(evaluation);
  out.flush();
  if (!out) throw std::runtime_error("write error on " + path);
}

std::string evaluationSummary(const Evaluation& e) {
  auto f = [](double v, double scale, int decimals) {
    if (!std::isfinite(v)) return std::string("n/a");
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.*f", decimals, v * scale);
    return std::string(buf);
  };
  std::ostringstream o;
  o << "sequence " << e.sequence << ": " << e.frames << " frames evaluated of " << e.frames_total << ", "
    << f(e.duration_s, 1.0, 1) << " s\n"
    << "  distance RMSE " << f(e.rmse_distance_m, 100.0, 2) << " cm, height RMSE " << f(e.rmse_height_m, 100.0, 2)
    << " cm, velocity RMSE " << f(e.rmse_velocity_mps, 100.0, 2) << " cm/s\n"
    << "  normal error RMS " << f(e.rms_normal_deg, 1.0, 2) << " deg (max " << f(e.max_normal_deg, 1.0, 2)
    << "), gravity error RMS " << f(e.rms_gravity_deg, 1.0, 2) << " deg (max " << f(e.max_gravity_deg, 1.0, 2)
    << ")\n"
    << "  consistency over " << e.consistency_frames << " frames";
  if (e.consistency_frames_excluded > 0) o << " (" << e.consistency_frames_excluded << " left out: a sigma not finite and positive)";
  o << ": within 2 sigma d " << f(e.coverage2_d, 100.0, 1) << " %, v " << f(e.coverage2_v, 100.0, 1)
    << " %, NEES mean " << f(e.nees_mean, 1.0, 2) << " (median " << f(e.nees_median, 1.0, 2)
    << "); consistent: 95 %, 4\n"
    << "  consistency, last half: within 2 sigma d " << f(e.coverage2_d_last_half, 100.0, 1) << " %, v "
    << f(e.coverage2_v_last_half, 100.0, 1) << " %, NEES mean " << f(e.nees_mean_last_half, 1.0, 2) << "\n"
    << "  status tracking (whole run, start included): " << e.tracking_frames << " frames, |z_d| above 3 on "
    << e.tracking_beyond3_d << ", largest " << f(e.max_abs_z_d_tracking, 1.0, 1) << "; largest |z_v,i| above 3 on "
    << e.tracking_beyond3_v << ", largest " << f(e.max_abs_z_v_tracking, 1.0, 1) << "\n"
    << "  update time mean " << f(e.update_ms_mean, 1.0, 3) << " ms, median " << f(e.update_ms_median, 1.0, 3)
    << " ms, p99 " << f(e.update_ms_p99, 1.0, 3) << " ms; real-time factor " << f(e.realtime_factor, 1.0, 3)
    << "\n"
    << "  diverged: " << (e.diverged ? "yes (" + e.divergence_reason + ")" : std::string("no")) << "\n";
  return o.str();
}

}  // namespace eval
}  // namespace diekf
