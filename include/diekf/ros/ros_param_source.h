// ParamSource over a ros::NodeHandle (the nodelet's private namespace), so the nodelet reads exactly the keys
// of diekf::loadEstimatorParams that the offline tools read from config/estimator.yaml.
#pragma once

#include <string>
#include <vector>

#include <ros/node_handle.h>

#include "diekf/param_source.h"

namespace diekf_ros {

class RosParamSource : public diekf::ParamSource {
 public:
  explicit RosParamSource(const ros::NodeHandle& nh) : nh_(nh) {}
  bool get(const std::string& key, double* value) const override;
  bool get(const std::string& key, int* value) const override;
  bool get(const std::string& key, bool* value) const override;
  bool get(const std::string& key, std::string* value) const override;
  bool get(const std::string& key, std::vector<double>* value) const override;
  std::string origin() const override { return "ROS namespace " + nh_.getNamespace(); }
  /// Every parameter under the namespace, relative to it ("photometric/max_passes").
  std::vector<std::string> keys() const override;

 private:
  template <typename T>
  bool getTyped(const std::string& key, T* value, const char* type_name) const;
  ros::NodeHandle nh_;
};

}  // namespace diekf_ros
