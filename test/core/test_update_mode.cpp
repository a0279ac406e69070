#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "diekf/params.h"

namespace diekf {
namespace {

TEST(Params, UpdateModeRoundTrip) {
  for (UpdateMode m : {UpdateMode::kIterated, UpdateMode::kEkf, UpdateMode::kFeature}) {
    EXPECT_EQ(parseUpdateMode(toString(m)), m);
  }
  EXPECT_EQ(parseUpdateMode("iekf"), UpdateMode::kIterated);
  EXPECT_STREQ(toString(UpdateMode::kFeature), "lk");
}

TEST(Params, UnknownUpdateModeThrowsNamingTheValue) {
  try {
    parseUpdateMode("ukf");
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("ukf"), std::string::npos);
  }
  EXPECT_THROW(parseUpdateMode("IEKF "), std::invalid_argument);
}

}  // namespace
}  // namespace diekf
