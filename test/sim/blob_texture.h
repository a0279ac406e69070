// Helper for the renderer tests: a dark texture tile with one bright Gaussian blob, and where that blob lies on a
// plane, so that a test can check where (and how) the renderer draws a known world point.
#pragma once

#include <cmath>
#include <vector>

#include <Eigen/Core>

#include "diekf/sim/texture.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {
namespace simtest {

constexpr int kBlobTex = 256;          // texture tile (texels)
constexpr double kBlobTexel_m = 0.007; // texel size (m)
constexpr int kBlobI = 100, kBlobJ = 60;

/// Dark tile with one bright Gaussian blob of `sigma_texels` centred on texel (kBlobI, kBlobJ).
inline Texture blobTexture(double sigma_texels) {
  std::vector<float> px(kBlobTex * kBlobTex, 20.f);
  for (int j = 0; j < kBlobTex; ++j)
    for (int i = 0; i < kBlobTex; ++i) {
      const double d2 = (i - kBlobI) * (i - kBlobI) + (j - kBlobJ) * (j - kBlobJ);
      px[j * kBlobTex + i] += static_cast<float>(200.0 * std::exp(-0.5 * d2 / (sigma_texels * sigma_texels)));
    }
  return Texture(px, kBlobTex, kBlobTex, kBlobTexel_m, kBlobTexel_m);
}

/// World position of the blob centre on `plane` (texel centres at (i + 0.5) texel).
inline Eigen::Vector3d blobWorld(const Plane& plane) {
  Eigen::Vector3d t1, t2;
  plane.basis(&t1, &t2);
  return -plane.e_m * plane.n + (kBlobI + 0.5) * kBlobTexel_m * t1 + (kBlobJ + 0.5) * kBlobTexel_m * t2;
}

}  // namespace simtest
}  // namespace sim
}  // namespace diekf
