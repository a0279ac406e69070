// The camera driver's IR projector, judged from its parameters (diekf/ros/driver_settings.h).
#include <map>
#include <string>

#include <gtest/gtest.h>

#include "diekf/ros/driver_settings.h"

namespace {

using diekf_ros::irProjectorMayBeOn;

const std::string kNs = "/mynteye/mynteye_wrapper_node";

TEST(DriverSettings, IrProjector) {
  std::string text;
  // The driver's stock files: standard/ir_control 80 (S1030) and standard2/ir_control 80.
  EXPECT_TRUE(irProjectorMayBeOn({{"standard/ir_control", 80}, {"standard2/ir_control", 80}}, kNs, &text));
  EXPECT_NE(text.find(kNs + "/standard/ir_control = 80"), std::string::npos) << text;
  EXPECT_NE(text.find("brightness constancy"), std::string::npos) << text;
  EXPECT_NE(text.find("to 0"), std::string::npos) << "says what to set: " << text;
  // Switched off for the S1030.
  EXPECT_FALSE(irProjectorMayBeOn({{"standard/ir_control", 0}, {"standard2/ir_control", 80}}, kNs, &text));
  EXPECT_EQ(text, "IR projector off");
  // The S2's key as the wrapper reads it.
  EXPECT_TRUE(irProjectorMayBeOn({{"STANDARD/ir_control", 20}}, kNs, &text));
  EXPECT_FALSE(irProjectorMayBeOn({{"STANDARD/ir_control", 0}}, kNs, &text));
  // -1 leaves the device's stored intensity; standard2/ir_control alone is never applied by the wrapper.
  EXPECT_TRUE(irProjectorMayBeOn({{"standard/ir_control", -1}}, kNs, &text));
  EXPECT_NE(text.find("unknown"), std::string::npos) << text;
  EXPECT_TRUE(irProjectorMayBeOn({{"standard2/ir_control", 0}}, kNs, &text));
  EXPECT_NE(text.find("does not read"), std::string::npos) << text;
  // Another driver: nothing to say.
  EXPECT_FALSE(irProjectorMayBeOn({}, kNs, &text));
  EXPECT_NE(text.find("no IR parameter"), std::string::npos) << text;
}

}  // namespace
