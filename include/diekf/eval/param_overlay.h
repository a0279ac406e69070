// A ParamSource that layers command-line overrides ("--set key=value") over another source (the config file).
// Header-only use of the ParamSource interface; no ROS.
#pragma once

#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "diekf/param_source.h"
#include "diekf/params.h"

namespace diekf {
namespace eval {

class ParamOverlay : public ParamSource {
 public:
  /// `base` may be null (overrides only); it must outlive the overlay.
  explicit ParamOverlay(const ParamSource* base) : base_(base) {}

  /// Adds "key=value"; throws std::invalid_argument on text without '=' or with an empty key.
  void addAssignment(const std::string& assignment);
  void set(const std::string& key, const std::string& value) { overrides_[key] = value; }

  bool get(const std::string& key, double* value) const override;
  bool get(const std::string& key, int* value) const override;
  bool get(const std::string& key, bool* value) const override;
  bool get(const std::string& key, std::string* value) const override;
  bool get(const std::string& key, std::vector<double>* value) const override;
  std::string origin() const override;

  /// Override keys never asked for by a get() (typos, keys the loader does not know).
  std::vector<std::string> unusedOverrides() const;

 private:
  const std::string* find(const std::string& key) const;
  const ParamSource* base_;
  std::map<std::string, std::string> overrides_;
  mutable std::set<std::string> used_;
};

/// The runners' command-line overrides (diekf_bag_runner, diekf_replay) on parameters already loaded from the
/// config and IMU files, in this order: the `--set key=value` assignments (std::invalid_argument naming every key
/// the loader does not know), then `--mode` (empty: unchanged), then `--width` (0: unchanged; the working width of
/// the mode in use).
void applyCommandLine(const std::vector<std::string>& sets, const std::string& mode, int width_px,
                      EstimatorParams* params);

}  // namespace eval
}  // namespace diekf
