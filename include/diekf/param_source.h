// One table of parameter keys for every front end: the ROS layer reads them from the parameter server, the
// offline tools from the same YAML file (config/*.yaml). Kalibr camchain / IMU files are read as they are.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "diekf/params.h"

namespace diekf {

/// A source of named values. get() returns false when the key is absent; it throws std::runtime_error naming
/// the key (and file) when the key exists with the wrong type.
class ParamSource {
 public:
  virtual ~ParamSource() = default;
  virtual bool get(const std::string& key, double* value) const = 0;
  virtual bool get(const std::string& key, int* value) const = 0;
  virtual bool get(const std::string& key, bool* value) const = 0;
  virtual bool get(const std::string& key, std::string* value) const = 0;
  virtual bool get(const std::string& key, std::vector<double>* value) const = 0;
  /// Where the values come from, for error messages (a file name or a ROS namespace).
  virtual std::string origin() const = 0;
  /// Every key the source holds ("a/b" for nested maps), for the unknown-key check of loadEstimatorParams;
  /// empty when the source cannot list its keys (the check then finds nothing).
  virtual std::vector<std::string> keys() const { return {}; }
};

/// Values from a YAML map (a ROS-parameter-style config file); nested keys as "a/b". Throws naming the file
/// when it cannot be read or parsed.
class YamlParamSource : public ParamSource {
 public:
  explicit YamlParamSource(const std::string& path);
  ~YamlParamSource() override;
  bool get(const std::string& key, double* value) const override;
  bool get(const std::string& key, int* value) const override;
  bool get(const std::string& key, bool* value) const override;
  bool get(const std::string& key, std::string* value) const override;
  bool get(const std::string& key, std::vector<double>* value) const override;
  std::string origin() const override { return path_; }
  /// The leaf keys of the file's maps ("a/b"; a list or a scalar is a leaf), in file order.
  std::vector<std::string> keys() const override;

 private:
  struct Impl;
  std::string path_;
  Impl* impl_;
};

/// Receives one warning: a single line naming the origin and the key.
using ParamWarningFn = std::function<void(const std::string& warning)>;

/// A key of a parameter source that no parameter reads (a typo, a key of another version): it is ignored.
struct UnknownParamKey {
  std::string origin;   ///< the source's origin() (file or ROS namespace)
  std::string key;      ///< as the source holds it ("a/b")
  std::string closest;  ///< the known key nearest to it (edit distance, see unknownParamKeys)
  /// "<origin>: unknown parameter key 'k' ignored (closest known key: 'c')".
  std::string message() const;
};

/// The keys of `source` (ParamSource::keys) that are neither estimator keys (estimatorParamKeys) nor in
/// `other_known` (e.g. a front end's own settings in the same namespace), in the source's order, each with the
/// closest known key: the smallest Levenshtein distance between the whole keys or, plus one, between their
/// last components (so that a key written without its group, "max_passes", finds "photometric/max_passes");
/// ties go to the earlier key of the table. A key that is a group of known keys ("photometric" with an empty
/// value) is not reported.
std::vector<UnknownParamKey> unknownParamKeys(const ParamSource& source,
                                              const std::vector<std::string>& other_known = {});

/// Fills `params` from every key `source` has (absent keys keep their value); validates ranges and throws
/// std::runtime_error naming the origin and key of a bad value. `params` is unchanged when it throws.
/// Keys mirror the struct: "mode", "init/alpha0_inv_m", "imu/lowpass_cutoff_hz", ..., "max_queued_images"
/// (the full list: estimatorParamKeys(); documented with units in config/estimator.yaml).
/// Keys of the source that no parameter reads are ignored with a warning (unknownParamKeys, before any value
/// is read): this overload writes it to std::cerr ("warning: ..."); the next one hands it to `warn`.
void loadEstimatorParams(const ParamSource& source, EstimatorParams* params);
/// As above, with each unknown-key warning passed to `warn` (may be empty: no check); keys in `other_known`
/// are the caller's own and not reported.
void loadEstimatorParams(const ParamSource& source, EstimatorParams* params, const ParamWarningFn& warn,
                         const std::vector<std::string>& other_known = {});

/// Every key loadEstimatorParams reads, in table order (one per field of EstimatorParams).
std::vector<std::string> estimatorParamKeys();

/// Noise densities and rate from a Kalibr IMU YAML (imu0 or top-level keys). Throws naming file and key. The
/// decimation factor is re-derived for the file's rate so that the prediction keeps the rate `imu` had
/// (input_rate_hz / decimation_factor: 100 Hz by default).
void loadKalibrImuYaml(const std::string& path, ImuParams* imu);

}  // namespace diekf
