// mynteye_standin_node: the process layout of the MYNT EYE S wrapper's node (mynteye_wrapper_node), with the
// stand-in nodelet diekf/MyntEyeStandin in place of the driver's. Like the wrapper's node it creates a nodelet
// loader with the ROS API (services ~load_nodelet, ~unload_nodelet, ~list) and loads the nodelet in process
// before spinning; the nodelet's onInit() runs until shutdown, so ros::spin() is only reached at shutdown and
// those services are advertised but never answered (docs/ros.md, "The MYNT EYE S driver and its stand-in").
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "mynteye_wrapper_node");
  nodelet::Loader loader;  // with the ROS API, as the wrapper's node has it
  const nodelet::M_string remappings(ros::names::getRemappings());
  const nodelet::V_string nodelet_argv;
  if (!loader.load(ros::this_node::getName(), "diekf/MyntEyeStandin", remappings, nodelet_argv)) {
    ROS_FATAL("mynteye_standin_node: could not load diekf/MyntEyeStandin");
    return 1;
  }
  ros::spin();
  return 0;
}
