// A ParamSource that layers command-line overrides ("--set key=value") over another source (the config file).
// Header-only use of the ParamSource interface; no ROS.
#pragma once

#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "diekf/param_source.h"

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

}  // namespace eval
}  // namespace diekf
