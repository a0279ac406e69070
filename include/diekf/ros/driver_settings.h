// Settings of the camera driver that matter to diekf, read from the driver's parameters (docs/ros.md, "IR
// projector").
#pragma once

#include <map>
#include <string>

namespace diekf_ros {

/// The MYNT EYE driver's IR projector parameters, in its private namespace: standard/ir_control (S1030),
/// STANDARD/ir_control (the key the wrapper reads for the S2 models), standard2/ir_control (the key its S2 file
/// sets, which the wrapper does not read). Intensity 0..160; -1 leaves the device's stored setting.
extern const char* const kIrControlKeys[3];

/// Judges the IR projector from the values found (key -> value; keys not set are absent). Returns true when it is
/// or may be on (then `text` says so and what to set), false when it is off or the driver has no such parameter
/// (`text` says which).
bool irProjectorMayBeOn(const std::map<std::string, int>& found, const std::string& driver_ns, std::string* text);

}  // namespace diekf_ros
