#include "diekf/eval/sequence_files.h"

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace diekf {
namespace eval {

namespace {

namespace fs = std::filesystem;

constexpr const char* kFirstLine = "# diekf sequence 1";

std::string num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

double parseNumber(const std::string& text, const std::string& where) {
  const char* begin = text.c_str();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(begin, &end);
  if (end == begin || *end != '\0' || errno == ERANGE) {
    throw std::runtime_error(where + ": not a number: '" + text + "'");
  }
  return v;
}

}  // namespace

void writePgm(const std::string& path, const cv::Mat& grey) {
  if (grey.empty() || grey.type() != CV_8UC1) throw std::runtime_error(path + ": PGM needs an 8-bit grey image");
  std::ofstream f(path, std::ios::binary);
  f << "P5\n" << grey.cols << ' ' << grey.rows << "\n255\n";
  for (int y = 0; y < grey.rows; ++y) f.write(grey.ptr<const char>(y), grey.cols);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
}

cv::Mat readPgm(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error("cannot read '" + path + "'");
  // Header: "P5", width, height, maxval, separated by whitespace (and '#' comments), then one whitespace byte.
  std::string magic;
  f >> magic;
  int values[3] = {0, 0, 0};
  for (int i = 0; i < 3 && f; ++i) {
    f >> std::ws;
    while (f.peek() == '#') {
      std::string comment;
      std::getline(f, comment);
      f >> std::ws;
    }
    f >> values[i];
  }
  const int w = values[0], h = values[1];
  if (!f || magic != "P5" || w <= 0 || h <= 0 || w > 100000 || h > 100000 || values[2] != 255) {
    throw std::runtime_error(path + ": not an 8-bit binary PGM (P5, maxval 255)");
  }
  f.get();  // the single whitespace byte before the pixels
  cv::Mat img(h, w, CV_8UC1);
  for (int y = 0; y < h; ++y) f.read(img.ptr<char>(y), w);
  if (!f) throw std::runtime_error(path + ": truncated PGM");
  return img;
}

SequenceWriter::SequenceWriter(const std::string& dir, const std::string& camchain_path) : dir_(dir) {
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "images", ec);
  if (!fs::is_directory(fs::path(dir) / "images")) throw std::runtime_error("cannot create '" + dir + "/images'");
  const fs::path calib = fs::path(dir) / "camchain.yaml";
  fs::copy_file(camchain_path, calib, fs::copy_options::overwrite_existing, ec);
  if (ec) throw std::runtime_error("cannot copy '" + camchain_path + "' to '" + calib.string() + "': " + ec.message());
  events_path_ = (fs::path(dir) / "events.csv").string();
  events_.open(events_path_);
  events_ << kFirstLine << '\n';
  if (!events_) throw std::runtime_error("cannot write '" + events_path_ + "'");
}

void SequenceWriter::addImu(const ImuSample& s) {
  events_ << "imu," << num(s.t_s) << ',' << num(s.accel_mps2.x()) << ',' << num(s.accel_mps2.y()) << ','
          << num(s.accel_mps2.z()) << ',' << num(s.gyro_radps.x()) << ',' << num(s.gyro_radps.y()) << ','
          << num(s.gyro_radps.z()) << '\n';
  if (!events_) throw std::runtime_error("cannot write '" + events_path_ + "'");
}

void SequenceWriter::addImage(double t_s, const cv::Mat& grey) {
  char name[32];
  std::snprintf(name, sizeof(name), "images/%06zu.pgm", images_);
  writePgm((fs::path(dir_) / name).string(), grey);
  ++images_;
  events_ << "image," << num(t_s) << ',' << name << '\n';
  if (!events_) throw std::runtime_error("cannot write '" + events_path_ + "'");
}

void SequenceWriter::close() {
  if (!events_.is_open()) return;
  events_.close();
  if (events_.fail()) throw std::runtime_error("cannot write '" + events_path_ + "'");
}

SequenceReader::SequenceReader(const std::string& dir) : dir_(dir) {
  events_path_ = (fs::path(dir) / "events.csv").string();
  events_.open(events_path_);
  if (!events_) throw std::runtime_error("cannot read '" + events_path_ + "' (not a sequence folder?)");
  std::string first;
  std::getline(events_, first);
  line_ = 1;
  if (first != kFirstLine) {
    throw std::runtime_error(events_path_ + ":1: expected '" + std::string(kFirstLine) + "', got '" + first + "'");
  }
}

std::string SequenceReader::camchainPath() const { return (fs::path(dir_) / "camchain.yaml").string(); }

bool SequenceReader::next(SequenceEvent* event) {
  std::string line;
  while (std::getline(events_, line)) {
    ++line_;
    if (line.empty() || line[0] == '#') continue;
    const std::string where = events_path_ + ":" + std::to_string(line_);
    std::vector<std::string> f;
    std::stringstream in(line);
    std::string field;
    while (std::getline(in, field, ',')) f.push_back(field);
    if (f[0] == "imu" && f.size() == 8) {
      double v[7];
      for (int i = 0; i < 7; ++i) v[i] = parseNumber(f[i + 1], where);
      event->kind = SequenceEvent::Kind::kImu;
      event->imu.t_s = v[0];
      event->imu.accel_mps2 = Vec3(v[1], v[2], v[3]);
      event->imu.gyro_radps = Vec3(v[4], v[5], v[6]);
      return true;
    }
    if (f[0] == "image" && f.size() == 3 && !f[2].empty()) {
      event->kind = SequenceEvent::Kind::kImage;
      event->image_t_s = parseNumber(f[1], where);
      event->image_path = (fs::path(dir_) / f[2]).string();
      return true;
    }
    throw std::runtime_error(where + ": expected 'imu,t,ax,ay,az,gx,gy,gz' or 'image,t,file', got '" + line + "'");
  }
  return false;
}

}  // namespace eval
}  // namespace diekf
