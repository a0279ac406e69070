// Importers from recorded datasets to the project's bag layout (docs/conventions.md §2, §3).
#pragma once

#include <string>
#include <vector>

#include "diekf/camera_model.h"
#include "diekf/sim/imu_sim.h"

namespace diekf {
namespace sim {

struct ImportOptions {
  std::string format;        ///< "mynteye-folder" or "euroc"
  std::string input_dir;
  std::string output_dir;
  std::string camchain;      ///< optional camchain to use instead of the dataset's / the default
  std::string imu_yaml;      ///< optional Kalibr IMU YAML to use instead of the dataset's / the default
  bool lz4 = false;
};

struct ImportSummary {
  std::size_t images = 0, imu = 0, poses = 0;
  std::string bag_path;
  std::vector<std::string> notes;  ///< e.g. "no calibration found, wrote MYNT EYE S defaults"
};

/// One CSV row split into numbers; `line` is 1-based in `path`.
struct CsvRow {
  std::size_t line = 0;
  std::vector<double> v;
};

/// Reads a numeric CSV file: '#' comments and blank lines skipped, one header line (first non-comment line
/// that does not parse as numbers) allowed, each row needs at least `min_fields` numbers (and at most
/// `max_fields`). Throws std::runtime_error "path:line: reason" on a malformed row, "cannot open 'path'"
/// if unreadable.
std::vector<CsvRow> readNumericCsv(const std::string& path, std::size_t min_fields, std::size_t max_fields);

/// Typical MYNT EYE S left camera with its built-in IMU (the sample calibration shipped in config/).
CameraModel myntEyeDefaultCamera();

/// Runs the import; writes output_dir/{sequence.bag, camchain.yaml, imu.yaml}. Throws std::runtime_error
/// with a one-line reason naming the offending file (and line for CSV rows).
ImportSummary runImport(const ImportOptions& opt);

/// diekf_import's command line (without argv[0]). Returns 0 ok, 1 help, -1 error (`error` set).
int parseImportArgs(const std::vector<std::string>& args, ImportOptions* opt, std::string* error);
std::string importUsage();

}  // namespace sim
}  // namespace diekf
