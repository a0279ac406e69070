// Outliers of the single-plane model for the simulator: textured objects moving across the ground on their own
// (flat "movers": cars/people seen from above) and static boxes standing on the ground (a second plane per box
// top, with sides). The ground truth stays the ground plane; the renderer ray casts the objects with the ground
// (nearest hit) and reports per pixel which of them it saw.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "diekf/sim/texture.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {

/// Options of --movers / --boxes (all off by default).
struct ClutterOptions {
  int movers = 0;                   ///< moving objects; each crosses the view once per mover_interval_s
  double mover_size_m = 0.8;        ///< length along the motion (m); width = length * mover_aspect
  double mover_aspect = 0.6;        ///< width / length
  double mover_speed_mps = 0.5;     ///< mean speed over the ground (each crossing 0.8-1.2 x this)
  double mover_interval_s = 6.0;    ///< time between two crossings of one mover (s)
  std::string mover_texture = "leaves";
  int boxes = 0;                    ///< static boxes standing on the ground along the flight's ground track
  double box_size_m = 0.25;         ///< mean side of a box's footprint (m; each side 0.75-1.25 x this)
  double box_height_m = 0.15;       ///< height of the box tops above the ground (m)
  std::string box_texture = "grass";
  bool any() const { return movers > 0 || boxes > 0; }
};

/// One object in the object frame O: x along its length, z along the plane normal, origin on the ground plane
/// (below the centre of its footprint). Occupies [-hx, hx] x [-hy, hy] x [z0, z1]; a flat object (a mover)
/// is the rectangle z = z1 only. Its origin moves with constant velocity: p_WO(t) = p0_W + v_W (t - t0).
struct SceneObject {
  Eigen::Matrix3d R_WO = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p0_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_W = Eigen::Vector3d::Zero();
  double t0_s = 0.0;
  double hx = 0.1, hy = 0.1, z0 = 0.0, z1 = 0.1;
  bool flat = false;   ///< a mover (top face only)
  bool mover = false;  ///< counted as a mover (else a box) in the coverage
  int texture = 0;     ///< index into Clutter::textures()
  double u0_m = 0.0, v0_m = 0.0;  ///< texture offset of the object's corner (-hx, -hy) (m)
  float side_gain = 0.7f;         ///< brightness of the sides against the top (light from above)
  Eigen::Vector3d positionAt(double t_s) const { return p0_W + v_W * (t_s - t0_s); }
};

/// The objects of a scene and their textures.
class Clutter {
 public:
  Clutter() = default;
  Clutter(std::vector<SceneObject> objects, std::vector<std::shared_ptr<const Texture>> textures);
  const std::vector<SceneObject>& objects() const { return objects_; }
  const std::vector<std::shared_ptr<const Texture>>& textures() const { return textures_; }
  bool empty() const { return objects_.empty(); }
  bool hasMovers() const;
  /// Height of the tallest box top above the ground (0 without boxes).
  double maxBoxHeight() const;

 private:
  std::vector<SceneObject> objects_;
  std::vector<std::shared_ptr<const Texture>> textures_;
};

/// A texture for the objects: leaves, grass and dirt on a 1.024 m tile (1 mm texels), natural on 1.024 m
/// (2 mm), checkerboard (5 cm squares), or an image file one metre wide.
std::shared_ptr<const Texture> clutterTexture(const std::string& name, std::uint64_t seed);

/// Generates the objects for a flight (deterministic for `seed`). `look_at(t)` is the point of the ground the
/// camera's optical axis hits at time t. Mover k crosses the view at t = interval (i + (k + 0.5) / movers),
/// i = 0, 1, ... up to the end of the flight: a straight path at constant speed in a random direction through
/// look_at(t) (offset sideways by up to +-0.15 m), 1 cm (+ 1 mm per crossing modulo 8, so that overlapping
/// movers have an order) above the ground. Boxes: centred on look_at at random times of the flight (offset by up
/// to +-0.6 m), random yaw, sides 0.75-1.25 x box_size_m; a candidate overlapping an earlier box (with 5 cm of
/// clearance) is drawn again.
Clutter makeClutter(const ClutterOptions& opt, const Plane& plane,
                    const std::function<Eigen::Vector3d(double)>& look_at, double duration_s, std::uint64_t seed);

/// Per-pixel coverage of one rendered image: the fraction of its motion-blur sub-frames in which the nearest
/// hit of the pixel's ray was a mover / a box (row-major, width x height).
struct ClutterMask {
  int width = 0, height = 0;
  std::vector<float> mover, box;
  double moverFraction() const;  ///< mean of `mover` over the image
  double boxFraction() const;
  double anyFraction() const;    ///< mean of mover + box
};

}  // namespace sim
}  // namespace diekf
