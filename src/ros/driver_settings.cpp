#include "diekf/ros/driver_settings.h"

namespace diekf_ros {

const char* const kIrControlKeys[3] = {"standard/ir_control", "STANDARD/ir_control", "standard2/ir_control"};

bool irProjectorMayBeOn(const std::map<std::string, int>& found, const std::string& driver_ns, std::string* text) {
  const std::string fix = "its pattern is fixed to the camera, not to the ground, and breaks the brightness "
                          "constancy of the photometric update: set " + driver_ns + "/standard/ir_control to 0 "
                          "(S1030; " + driver_ns + "/STANDARD/ir_control on the S2 models), or, with the "
                          "projector needed, set diekf's preprocess/dot_removal_px to 5, docs/ros.md";
  if (found.empty()) {
    *text = "no IR parameter of the driver under " + driver_ns;
    return false;
  }
  // The wrapper applies standard/ir_control (S1030) or STANDARD/ir_control (S2); standard2/ir_control alone is
  // never applied, so the device keeps its stored intensity.
  std::string on, unknown;
  for (const auto& kv : found) {
    const std::string key = driver_ns + "/" + kv.first;
    if (kv.first == "standard2/ir_control") continue;
    if (kv.second > 0) on += (on.empty() ? "" : ", ") + key + " = " + std::to_string(kv.second);
    if (kv.second < 0) unknown += (unknown.empty() ? "" : ", ") + key + " = " + std::to_string(kv.second);
  }
  const bool only_s2_file_key = found.size() == 1 && found.count("standard2/ir_control");
  if (!on.empty()) {
    *text = "IR projector on (" + on + "): " + fix;
    return true;
  }
  if (!unknown.empty() || only_s2_file_key) {
    *text = "IR projector unknown (" + (unknown.empty() ? driver_ns + "/standard2/ir_control, which the driver "
                                                          "does not read" : unknown) +
            ": the device keeps its stored intensity): if it is on, " + fix;
    return true;
  }
  *text = "IR projector off";
  return false;
}

}  // namespace diekf_ros
