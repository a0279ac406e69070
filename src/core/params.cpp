#include "diekf/params.h"

#include <stdexcept>

namespace diekf {

UpdateMode parseUpdateMode(const std::string& name) {
  if (name == "iekf") return UpdateMode::kIterated;
  if (name == "ekf") return UpdateMode::kEkf;
  if (name == "lk") return UpdateMode::kFeature;
  throw std::invalid_argument("unknown update mode '" + name + "' (expected iekf, ekf or lk)");
}

const char* toString(UpdateMode mode) {
  switch (mode) {
    case UpdateMode::kIterated:
      return "iekf";
    case UpdateMode::kEkf:
      return "ekf";
    case UpdateMode::kFeature:
      return "lk";
  }
  return "unknown";
}

}  // namespace diekf
