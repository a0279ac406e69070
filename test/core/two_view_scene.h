// Test helper: a reference and a current view of a textured ground plane, 1/30 s apart, with the true filter
// quantities at the current image (the time the filter state refers to).
#pragma once

#include "render_plane.h"

namespace diekf {
namespace test_util {

struct TwoViewScene {
  PinholeK K;
  double dt_s = 1.0 / 30.0;
  Vec3 v_W = Vec3::Zero();       ///< camera velocity, m/s
  Vec3 w_C = Vec3::Zero();       ///< camera angular rate in C (gyro, bias-free), rad/s
  PlaneTruth truth;              ///< at the current image
  PreprocessedFrame ref, cur;
};

/// Camera about 1 m above level ground, slightly tilted, moving at a few dm/s and turning slowly.
inline TwoViewScene makeTwoViewScene(int width_px, int height_px, int supersample = 3, unsigned seed = 7) {
  TwoViewScene s;
  s.K = makeK(width_px, height_px);
  s.v_W = Vec3(0.30, -0.20, 0.05);
  s.w_C = Vec3(0.10, -0.05, 0.20);
  const PlaneTexture texture(seed);
  const Plane ground;
  const CameraPose cur = lookDownPose(Vec3(0.1, -0.2, 1.0), 0.3, 0.15);
  const CameraPose ref = propagate(cur, s.v_W, s.w_C, -s.dt_s);
  s.truth = planeTruth(ground, cur, s.v_W);
  s.ref = makeFrame(toGray8(renderPlane(texture, ground, s.K, ref, supersample)), 0.0);
  s.cur = makeFrame(toGray8(renderPlane(texture, ground, s.K, cur, supersample)), s.dt_s);
  return s;
}

}  // namespace test_util
}  // namespace diekf
