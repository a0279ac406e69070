#include "diekf/ros/ros_param_source.h"

#include <stdexcept>

#include <ros/param.h>

namespace diekf_ros {

template <typename T>
bool RosParamSource::getTyped(const std::string& key, T* value, const char* type_name) const {
  if (!nh_.hasParam(key)) return false;
  T v{};
  if (!nh_.getParam(key, v)) {
    throw std::runtime_error(origin() + ": parameter '" + key + "' exists but is not a " + type_name);
  }
  *value = v;
  return true;
}

std::vector<std::string> RosParamSource::keys() const {
  std::vector<std::string> names, out;
  if (!ros::param::getParamNames(names)) return out;
  const std::string prefix = nh_.getNamespace() + "/";
  for (const std::string& n : names) {
    if (n.size() > prefix.size() && n.compare(0, prefix.size(), prefix) == 0) out.push_back(n.substr(prefix.size()));
  }
  return out;
}

bool RosParamSource::get(const std::string& key, double* value) const { return getTyped(key, value, "number"); }
bool RosParamSource::get(const std::string& key, int* value) const { return getTyped(key, value, "integer"); }
bool RosParamSource::get(const std::string& key, bool* value) const { return getTyped(key, value, "boolean"); }
bool RosParamSource::get(const std::string& key, std::string* value) const {
  return getTyped(key, value, "string");
}
bool RosParamSource::get(const std::string& key, std::vector<double>* value) const {
  return getTyped(key, value, "list of numbers");
}

}  // namespace diekf_ros
