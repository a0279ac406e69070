// Exported sequences (docs/conventions.md section 7): what the writer stores is what the reader returns, exactly.
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>

#include "diekf/eval/sequence_files.h"

namespace diekf {
namespace eval {
namespace {

namespace fs = std::filesystem;

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("diekf_seq_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

TEST(SequenceFiles, RoundTripIsExact) {
  TempDir tmp;
  const fs::path calib = tmp.path / "calib.yaml";
  std::ofstream(calib) << "cam0:\n  intrinsics: [1.0, 2.0, 3.0, 4.0]\n";
  const fs::path dir = tmp.path / "seq";
  ImuSample a;
  a.t_s = 1600000000.0 + 1.0 / 3.0;
  a.accel_mps2 = Vec3(0.1, -9.80665, 1e-300);
  a.gyro_radps = Vec3(-0.0, std::nextafter(1.0, 2.0), -123456.789e-7);
  ImuSample b = a;
  b.t_s += 0.002;
  cv::Mat img(7, 13, CV_8UC1);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) img.at<uint8_t>(y, x) = static_cast<uint8_t>((31 * x + 17 * y) % 256);
  {
    SequenceWriter w(dir.string(), calib.string());
    w.addImu(a);
    w.addImage(a.t_s + 0.001, img);
    w.addImu(b);
    w.addImage(b.t_s + 0.001, img(cv::Rect(2, 1, 5, 4)));  // a view: rows are not contiguous
    EXPECT_EQ(w.images(), 2u);
    w.close();
  }
  SequenceReader r(dir.string());
  EXPECT_TRUE(fs::is_regular_file(r.camchainPath()));
  SequenceEvent e;
  ASSERT_TRUE(r.next(&e));
  ASSERT_EQ(e.kind, SequenceEvent::Kind::kImu);
  EXPECT_TRUE(sameBits(e.imu.t_s, a.t_s));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(sameBits(e.imu.accel_mps2[i], a.accel_mps2[i])) << i;
    EXPECT_TRUE(sameBits(e.imu.gyro_radps[i], a.gyro_radps[i])) << i;
  }
  ASSERT_TRUE(r.next(&e));
  ASSERT_EQ(e.kind, SequenceEvent::Kind::kImage);
  EXPECT_TRUE(sameBits(e.image_t_s, a.t_s + 0.001));
  const cv::Mat back = readPgm(e.image_path);
  ASSERT_EQ(back.size(), img.size());
  EXPECT_EQ(cv::norm(back, img, cv::NORM_INF), 0.0);
  ASSERT_TRUE(r.next(&e));
  EXPECT_EQ(e.kind, SequenceEvent::Kind::kImu);
  EXPECT_TRUE(sameBits(e.imu.t_s, b.t_s));
  ASSERT_TRUE(r.next(&e));
  ASSERT_EQ(e.kind, SequenceEvent::Kind::kImage);
  const cv::Mat roi = readPgm(e.image_path);
  ASSERT_EQ(roi.size(), cv::Size(5, 4));
  EXPECT_EQ(cv::norm(roi, img(cv::Rect(2, 1, 5, 4)), cv::NORM_INF), 0.0);
  EXPECT_FALSE(r.next(&e));
}

TEST(SequenceFiles, ErrorsNameTheFileAndLine) {
  TempDir tmp;
  auto expectError = [](auto&& f, const std::string& needle) {
    try {
      f();
      ADD_FAILURE() << "no error, expected one naming " << needle;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expectError([&] { SequenceReader r((tmp.path / "missing").string()); }, "events.csv");
  std::ofstream(tmp.path / "events.csv") << "# something else\n";
  expectError([&] { SequenceReader r(tmp.path.string()); }, "events.csv:1");
  std::ofstream(tmp.path / "events.csv") << "# diekf sequence 1\nimu,1,2,3,4,5,6,7\nimu,1,2,x,4,5,6,7\n";
  SequenceReader r(tmp.path.string());
  SequenceEvent e;
  EXPECT_TRUE(r.next(&e));
  expectError([&] { r.next(&e); }, "events.csv:3");
  std::ofstream(tmp.path / "events.csv") << "# diekf sequence 1\nimage,1\n";
  SequenceReader r2(tmp.path.string());
  expectError([&] { r2.next(&e); }, "events.csv:2");
  // PGM: comments in the header are fine; other formats are not.
  std::ofstream(tmp.path / "c.pgm", std::ios::binary) << "P5\n# comment\n2 1\n255\n" << '\x07' << '\xff';
  const cv::Mat c = readPgm((tmp.path / "c.pgm").string());
  ASSERT_EQ(c.size(), cv::Size(2, 1));
  EXPECT_EQ(c.at<uint8_t>(0, 1), 255);
  std::ofstream(tmp.path / "p2.pgm") << "P2\n2 1\n255\n7 255\n";
  expectError([&] { readPgm((tmp.path / "p2.pgm").string()); }, "p2.pgm");
  std::ofstream(tmp.path / "short.pgm", std::ios::binary) << "P5\n4 4\n255\nab";
  expectError([&] { readPgm((tmp.path / "short.pgm").string()); }, "truncated");
}

}  // namespace
}  // namespace eval
}  // namespace diekf
