#include "diekf/params.h"

#include "diekf/camera_model.h"

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

BrightnessModel parseBrightnessModel(const std::string& name) {
  if (name == "normalised") return BrightnessModel::kNormalised;
  if (name == "gain") return BrightnessModel::kGain;
  if (name == "affine") return BrightnessModel::kAffine;
  if (name == "rows") return BrightnessModel::kRows;
  if (name == "auto") return BrightnessModel::kAuto;
  if (name == "levels") return BrightnessModel::kLevels;
  throw std::invalid_argument("unknown brightness model '" + name +
                              "' (expected normalised, gain, affine, rows, auto or levels)");
}

const char* toString(BrightnessModel model) {
  switch (model) {
    case BrightnessModel::kNormalised:
      return "normalised";
    case BrightnessModel::kGain:
      return "gain";
    case BrightnessModel::kAffine:
      return "affine";
    case BrightnessModel::kRows:
      return "rows";
    case BrightnessModel::kAuto:
      return "auto";
    case BrightnessModel::kLevels:
      return "levels";
  }
  return "?";
}

ImageStamp parseImageStamp(const std::string& name) {
  if (name == "middle") return ImageStamp::kMiddle;
  if (name == "start") return ImageStamp::kStart;
  if (name == "end") return ImageStamp::kEnd;
  throw std::invalid_argument("unknown image stamp convention '" + name + "' (expected middle, start or end)");
}

const char* toString(ImageStamp stamp) {
  switch (stamp) {
    case ImageStamp::kMiddle:
      return "middle";
    case ImageStamp::kStart:
      return "start";
    case ImageStamp::kEnd:
      return "end";
  }
  return "unknown";
}

double imageStampShift(ImageStamp stamp, double exposure_time_s, double readout_s) {
  // The middle row's mid-exposure is half an exposure and half a readout after the first row's start.
  const double half = 0.5 * (exposure_time_s + readout_s);
  switch (stamp) {
    case ImageStamp::kMiddle:
      return 0.0;
    case ImageStamp::kStart:
      return half;
    case ImageStamp::kEnd:
      return -half;
  }
  return 0.0;
}

double configuredLineDelay_s(const EstimatorParams& p, const CameraModel& cam) {
  return p.line_delay_s > 0.0 ? p.line_delay_s : cam.line_delay_s;
}

}  // namespace diekf
