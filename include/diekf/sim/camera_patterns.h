// Photometric patterns that travel with the camera (docs/simulator.md, "Camera-fixed patterns"): the drone's own
// shadow on sunny ground, an IR projector's dot pattern, dirt on the lens. They enter the sensor model as a
// per-pixel gain and offset (SensorOptions::fixed_gain, fixed_add).
#pragma once

#include <cstdint>
#include <vector>

#include "diekf/sim/renderer.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {

struct CameraPatternOptions {
  bool shadow = false;              ///< the drone's shadow on the ground (sun fixed in W)
  double sun_elevation_deg = 65.0;  ///< sun above the horizon (deg); the shadow is in view above ~50 deg
  double sun_azimuth_deg = 30.0;    ///< sun's azimuth in W, from +x toward +y (deg)
  double shadow_size_m = 0.6;       ///< quadrotor span, rotor tip to rotor tip (m)
  double shadow_darkness = 0.55;    ///< brightness lost in the full shadow of the body (0..1; skylight remains)
  double shadow_softness_m = 0.02;  ///< edge width of the shadow on the ground beyond the sun's penumbra (m)
  /// The shadow cast as if the camera stayed level and kept its first yaw, at the current height: fixed in the
  /// image but for its size (a hovering drone; the held-out case of issue 13). Else it follows the attitude.
  bool shadow_fixed = false;
  int projector_dots = 0;           ///< IR projector dots, fixed in the image (0 = off; the MYNT EYE: ~1500)
  double projector_strength = 1.5;  ///< dot irradiance at its peak relative to the ambient light
  double projector_dot_px = 1.2;    ///< Gaussian sigma of a dot at full (752x480) resolution (px)
  int lens_dirt = 0;                ///< number of out-of-focus dirt blobs on the lens (0 = off)
  double lens_dirt_opacity = 0.5;   ///< light a blob's centre blocks (0..1)
  std::uint64_t seed = 1;           ///< dot and dirt placement
  bool any() const { return shadow || projector_dots > 0 || lens_dirt > 0; }
};

/// The fixed gain and offset of one frame, per pixel of `renderer`'s image.
class CameraPatterns {
 public:
  CameraPatterns(const CameraPatternOptions& opt, const Renderer& renderer, double scale);
  /// Fills gain() and offset() for a camera at `pose` over `plane` (the shadow moves with the attitude and the
  /// height; the dots and the dirt stay where they are). `mean_radiance` (grey levels) scales the dirt's glare.
  void update(const CameraPose& pose, const Plane& plane, double mean_radiance);
  const std::vector<float>& gain() const { return gain_; }
  const std::vector<float>& offset() const { return offset_; }
  /// The part of the gain that never moves: projector dots and lens dirt (1 elsewhere).
  const std::vector<float>& staticGain() const { return static_gain_; }
  /// Share of the image whose gain is below 0.9 or above 1.1 in the last update (how much the patterns cover).
  double coverage() const { return coverage_; }
  /// Share of the image in the drone's shadow (gain below 0.9 from the shadow) in the last update.
  double shadowCoverage() const { return shadow_coverage_; }

 private:
  CameraPatternOptions opt_;
  const Renderer& renderer_;
  int width_ = 0, height_ = 0;
  std::vector<float> static_gain_;  // projector dots and dirt
  std::vector<float> static_add_;   // dirt glare per unit of mean radiance
  std::vector<float> gain_, offset_;
  double coverage_ = 0.0, shadow_coverage_ = 0.0;
  bool have_first_ = false;
  Eigen::Matrix3d first_R_WC_ = Eigen::Matrix3d::Identity();  // level camera with the first yaw (shadow_fixed)
};

}  // namespace sim
}  // namespace diekf
