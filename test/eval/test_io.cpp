// estimates.csv / groundtruth.csv / evaluation.json formats (docs/conventions.md sections 4 and 5).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <unistd.h>

#include "diekf/eval/io.h"

namespace diekf {
namespace eval {
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() / ("diekf_eval_io_" + std::to_string(::getpid()) + "_" +
                                         ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  fs::path path_;
};

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

EstimateRow sampleRow(double t) {
  EstimateRow r;
  r.t_s = t;
  r.d_m = 1.2345678;
  r.h_m = 1.25;
  r.v_mps = Eigen::Vector3d(0.1, -0.2, 0.003);
  r.mu = Eigen::Vector3d(0.1, 0.0, 0.995);
  r.g = Eigen::Vector3d(0.0, 0.0, 1.0);
  r.sigma_d_m = 0.01;
  r.sigma_v_mps = Eigen::Vector3d(0.02, 0.03, 0.04);
  r.iterations = 3;
  r.update_ms = 1.4321;
  r.status = "tracking";
  return r;
}

TEST(EvalIo, HeaderIsTheConventionsOne) {
  EXPECT_STREQ(estimatesCsvHeader(),
               "t,d,h,vx,vy,vz,mux,muy,muz,gx,gy,gz,sigma_d,sigma_vx,sigma_vy,sigma_vz,iterations,update_ms,status");
}

TEST(EvalIo, RowHasNineDecimalStampAndNineteenFields) {
  const std::string row = formatEstimateRow(sampleRow(1600000000.123456789));
  EXPECT_EQ(std::count(row.begin(), row.end(), ','), 18);
  const std::string t = row.substr(0, row.find(','));
  ASSERT_NE(t.find('.'), std::string::npos);
  EXPECT_EQ(t.size() - t.find('.') - 1, 9u);
  EXPECT_EQ(t.substr(0, 14), "1600000000.123");
  EXPECT_EQ(row.substr(row.rfind(',') + 1), "tracking");
}

TEST(EvalIo, EstimatesRoundTrip) {
  TempDir dir;
  const std::string path = dir.file("estimates.csv");
  {
    EstimatesCsvWriter w(path);
    w.write(sampleRow(10.0));
    EstimateRow r = sampleRow(10.033333333);
    r.iterations = 0;
    r.status = "initializing";
    w.write(r);
    r.status = "degraded";  // every status the estimator writes reads back
    w.write(r);
    w.close();
  }
  const std::vector<EstimateRow> rows = readEstimatesCsv(path);
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[2].status, "degraded");
  EXPECT_NEAR(rows[1].t_s, 10.033333333, 1e-9);
  EXPECT_NEAR(rows[0].d_m, 1.2345678, 1e-9);
  EXPECT_NEAR(rows[0].v_mps.z(), 0.003, 1e-12);
  EXPECT_NEAR(rows[0].sigma_v_mps.y(), 0.03, 1e-12);
  EXPECT_EQ(rows[0].iterations, 3);
  EXPECT_NEAR(rows[0].update_ms, 1.4321, 1e-9);
  EXPECT_EQ(rows[1].status, "initializing");
  EXPECT_FALSE(rows[1].updateApplied());
}

TEST(EvalIo, ReadRejectsWrongHeaderAndBadRows) {
  TempDir dir;
  const std::string bad_header = dir.file("a.csv");
  std::ofstream(bad_header) << "t,d\n1,2\n";
  EXPECT_THROW(readEstimatesCsv(bad_header), std::runtime_error);
  const std::string bad_row = dir.file("b.csv");
  std::ofstream(bad_row) << estimatesCsvHeader() << "\n" << formatEstimateRow(sampleRow(1.0)) << ",extra\n";
  EXPECT_THROW(readEstimatesCsv(bad_row), std::runtime_error);
  const std::string bad_status = dir.file("c.csv");
  EstimateRow unknown = sampleRow(1.0);
  unknown.status = "lost";
  std::ofstream(bad_status) << estimatesCsvHeader() << "\n" << formatEstimateRow(unknown) << "\n";
  EXPECT_THROW(readEstimatesCsv(bad_status), std::runtime_error);
  EXPECT_THROW(readEstimatesCsv(dir.file("missing.csv")), std::runtime_error);
  EXPECT_THROW(EstimatesCsvWriter(dir.file("no/such/dir/x.csv")), std::runtime_error);
}

TEST(EvalIo, GroundTruthCsv) {
  TempDir dir;
  TruthSample t;
  t.t_s = 5.5;
  t.d_m = 0.75;
  t.h_m = 0.8;
  writeGroundTruthCsv(dir.file("gt.csv"), {t, t});
  const std::string text = slurp(dir.file("gt.csv"));
  EXPECT_EQ(text.substr(0, text.find('\n')), groundTruthCsvHeader());
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 3);
  EXPECT_NE(text.find("5.500000000,0.75,0.8,"), std::string::npos);
}

TEST(EvalIo, JsonHasEveryKeyAndNullForNaN) {
  Evaluation e;
  e.sequence = "flight\"4";
  e.frames = 12;
  e.rmse_distance_m = 0.029;
  e.rmse_velocity_mps = std::nan("");
  e.diverged = true;
  e.coverage2_d = 0.9;
  e.nees_mean = std::nan("");
  const std::string json = evaluationToJson(e);
  for (const char* key : {"sequence", "frames", "duration_s", "rmse_distance_m", "rmse_height_m", "rmse_velocity_mps",
                          "rms_normal_deg", "rms_gravity_deg", "max_normal_deg", "max_gravity_deg", "diverged",
                          "update_ms_mean", "update_ms_median", "update_ms_p99", "realtime_factor", "coverage2_d",
                          "coverage2_v", "nees_mean", "nees_median", "coverage2_d_last_half",
                          "coverage2_v_last_half", "nees_mean_last_half", "consistency_frames",
                          "consistency_frames_excluded", "tracking_frames", "tracking_beyond3_d",
                          "max_abs_z_d_tracking", "tracking_beyond3_v", "max_abs_z_v_tracking"}) {
    EXPECT_NE(json.find("\"" + std::string(key) + "\":"), std::string::npos) << key;
  }
  EXPECT_NE(json.find("\"rmse_velocity_mps\": null"), std::string::npos);
  EXPECT_NE(json.find("\"rmse_distance_m\": 0.029"), std::string::npos);
  EXPECT_NE(json.find("\"diverged\": true"), std::string::npos);
  EXPECT_NE(json.find("\"flight\\\"4\""), std::string::npos);
  EXPECT_EQ(json.find("nan"), std::string::npos);
  EXPECT_NE(json.find("\"coverage2_d\": 0.9,"), std::string::npos);
  EXPECT_NE(json.find("\"nees_mean\": null"), std::string::npos);
  EXPECT_NE(evaluationSummary(e).find("2.90 cm"), std::string::npos);
  EXPECT_NE(evaluationSummary(e).find("d 90.0 %"), std::string::npos);
}

}  // namespace
}  // namespace eval
}  // namespace diekf
