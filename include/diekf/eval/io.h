// Files of the offline evaluation: estimates.csv (docs/conventions.md section 4), groundtruth.csv (same columns as the
// estimates for the true quantities) and evaluation.json (section 5). ROS-free.
#pragma once

#include <fstream>
#include <string>
#include <vector>

#include "diekf/eval/ground_truth.h"
#include "diekf/eval/metrics.h"

namespace diekf {
namespace eval {

/// "t,d,h,vx,vy,vz,mux,muy,muz,gx,gy,gz,sigma_d,sigma_vx,sigma_vy,sigma_vz,iterations,update_ms,status"
const char* estimatesCsvHeader();
/// "t,d,h,vx,vy,vz,mux,muy,muz,gx,gy,gz"
const char* groundTruthCsvHeader();

/// Streams rows one at a time (the runner writes as it goes, so a long run leaves a usable file if killed).
class EstimatesCsvWriter {
 public:
  /// Opens `path` and writes the header; throws std::runtime_error naming the file when it cannot.
  explicit EstimatesCsvWriter(const std::string& path);
  EstimatesCsvWriter(const EstimatesCsvWriter&) = delete;
  EstimatesCsvWriter& operator=(const EstimatesCsvWriter&) = delete;
  /// Appends one row; throws std::runtime_error naming the file on a write error.
  void write(const EstimateRow& row);
  /// Flushes and closes; throws std::runtime_error naming the file on a write error.
  void close();

 private:
  std::string path_;
  std::ofstream out_;
};

/// One estimates.csv row (no newline), `t` with 9 decimals.
std::string formatEstimateRow(const EstimateRow& row);
/// One groundtruth.csv row (no newline).
std::string formatTruthRow(const TruthSample& truth);

/// Reads an estimates.csv; throws std::runtime_error naming file and line on a wrong header or malformed row.
std::vector<EstimateRow> readEstimatesCsv(const std::string& path);

/// Writes groundtruth.csv; throws std::runtime_error naming the file when it cannot.
void writeGroundTruthCsv(const std::string& path, const std::vector<TruthSample>& truth);

/// evaluation.json text (NaN / inf written as null).
std::string evaluationToJson(const Evaluation& evaluation);
/// Writes evaluation.json; throws std::runtime_error naming the file when it cannot.
void writeEvaluationJson(const std::string& path, const Evaluation& evaluation);
/// Short human-readable summary (several lines) for the console.
std::string evaluationSummary(const Evaluation& evaluation);

}  // namespace eval
}  // namespace diekf
