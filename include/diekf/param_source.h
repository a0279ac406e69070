// One table of parameter keys for every front end: the ROS layer reads them from the parameter server, the
// offline tools from the same YAML file (config/*.yaml). Kalibr camchain / IMU files are read as they are.
#pragma once

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

 private:
  struct Impl;
  std::string path_;
  Impl* impl_;
};

/// Fills `params` from every key `source` has (absent keys keep their value); validates ranges and throws
/// std::runtime_error naming the origin and key of a bad value. `params` is unchanged when it throws.
/// Keys mirror the struct: "mode", "init/alpha0_inv_m", "imu/lowpass_cutoff_hz", ..., "max_queued_images"
/// (the full list: estimatorParamKeys(); documented with units in config/estimator.yaml).
void loadEstimatorParams(const ParamSource& source, EstimatorParams* params);

/// Every key loadEstimatorParams reads, in table order (one per field of EstimatorParams).
std::vector<std::string> estimatorParamKeys();

/// Noise densities and rate from a Kalibr IMU YAML (imu0 or top-level keys). Throws naming file and key.
void loadKalibrImuYaml(const std::string& path, ImuParams* imu);

}  // namespace diekf
