// Standalone node: loads diekf/EstimatorNodelet into this process (same parameters, topics and services as the
// nodelet, under the node's private namespace).
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "diekf");
  nodelet::Loader loader;
  const nodelet::M_string remappings(ros::names::getRemappings());
  const nodelet::V_string nodelet_argv;
  if (!loader.load(ros::this_node::getName(), "diekf/EstimatorNodelet", remappings, nodelet_argv)) {
    ROS_FATAL("diekf_node: could not load diekf/EstimatorNodelet");
    return 1;
  }
  ros::spin();
  return 0;
}
