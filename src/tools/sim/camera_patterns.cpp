// Camera-fixed photometric patterns: see include/diekf/sim/camera_patterns.h.
#include "diekf/sim/camera_patterns.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace diekf {
namespace sim {

namespace {

/// Coverage of a soft shape from its signed distance d (m, negative inside) and edge width w (m).
double softInside(double d, double w) { return std::clamp(0.5 - d / std::max(w, 1e-6), 0.0, 1.0); }

double segmentDistance(double x, double y, double ax, double ay, double bx, double by) {
  const double vx = bx - ax, vy = by - ay;
  const double t = std::clamp(((x - ax) * vx + (y - ay) * vy) / (vx * vx + vy * vy), 0.0, 1.0);
  return std::hypot(x - ax - t * vx, y - ay - t * vy);
}

}  // namespace

CameraPatterns::CameraPatterns(const CameraPatternOptions& opt, const Renderer& renderer, double scale)
    : opt_(opt), renderer_(renderer), width_(renderer.width()), height_(renderer.height()) {
  const std::size_t n = static_cast<std::size_t>(width_) * height_;
  static_gain_.assign(n, 1.f);
  static_add_.assign(n, 0.f);
  gain_.assign(n, 1.f);
  offset_.assign(n, 0.f);
  std::mt19937_64 rng(opt.seed * 0x9E3779B97F4A7C15ull + 77);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  // Projector: reflected by the ground like the ambient light, so a gain 1 + strength * dot profile.
  if (opt.projector_dots > 0) {
    const double s = std::max(0.3, opt.projector_dot_px * scale);
    const int r = static_cast<int>(std::ceil(3.0 * s));
    std::vector<float> dots(n, 0.f);
    for (int k = 0; k < opt.projector_dots; ++k) {
      const double cx = uni(rng) * (width_ - 1), cy = uni(rng) * (height_ - 1);
      const double amp = 0.6 + 0.8 * uni(rng);  // dots differ in brightness
      for (int v = std::max(0, static_cast<int>(cy) - r); v <= std::min(height_ - 1, static_cast<int>(cy) + r); ++v)
        for (int u = std::max(0, static_cast<int>(cx) - r); u <= std::min(width_ - 1, static_cast<int>(cx) + r); ++u) {
          const double d2 = (u - cx) * (u - cx) + (v - cy) * (v - cy);
          dots[static_cast<std::size_t>(v) * width_ + u] += static_cast<float>(amp * std::exp(-0.5 * d2 / (s * s)));
        }
    }
    for (std::size_t i = 0; i < n; ++i) static_gain_[i] *= 1.f + static_cast<float>(opt.projector_strength) * dots[i];
  }
  // Lens dirt: out of focus, so large soft blobs that block part of the light and scatter some of it (glare).
  for (int k = 0; k < opt.lens_dirt; ++k) {
    const double cx = uni(rng) * (width_ - 1), cy = uni(rng) * (height_ - 1);
    const double rad = (0.03 + 0.05 * uni(rng)) * width_;
    const double op = opt.lens_dirt_opacity * (0.5 + 0.5 * uni(rng));
    for (int v = 0; v < height_; ++v)
      for (int u = 0; u < width_; ++u) {
        const double d2 = ((u - cx) * (u - cx) + (v - cy) * (v - cy)) / (rad * rad);
        if (d2 > 9.0) continue;
        const double b = std::exp(-0.5 * d2 * 2.0);
        const std::size_t i = static_cast<std::size_t>(v) * width_ + u;
        static_gain_[i] *= static_cast<float>(1.0 - op * b);
        static_add_[i] += static_cast<float>(0.15 * op * b);
      }
  }
}

void CameraPatterns::update(const CameraPose& pose_in, const Plane& plane, double mean_radiance) {
  const std::size_t n = gain_.size();
  CameraPose pose = pose_in;
  if (opt_.shadow_fixed) {
    if (!have_first_) {
      // Level camera looking down the plane's normal, its x axis the first image's x axis projected on the plane.
      const Eigen::Vector3d z = -plane.n;
      Eigen::Vector3d x = pose_in.R_WC.col(0) - pose_in.R_WC.col(0).dot(z) * z;
      x = x.norm() > 1e-9 ? Eigen::Vector3d(x.normalized()) : Eigen::Vector3d::UnitX();
      first_R_WC_.col(0) = x;
      first_R_WC_.col(1) = z.cross(x);
      first_R_WC_.col(2) = z;
      have_first_ = true;
    }
    pose.R_WC = first_R_WC_;
  }
  int covered = 0, shadowed = 0;
  const double el = opt_.sun_elevation_deg * M_PI / 180.0, az = opt_.sun_azimuth_deg * M_PI / 180.0;
  const Eigen::Vector3d sun(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  const Eigen::Vector3d n_body = pose.R_WC.col(2);  // the drone's plane: the camera's image plane at its centre
  const double span = opt_.shadow_size_m;
  const double rotor_r = 0.22 * span, body_r = 0.18 * span, arm_w = 0.04 * span;
  const double rotor_c = (0.5 * span - rotor_r) / std::sqrt(2.0);
  const double dist = plane.n.dot(pose.p_WC) + plane.e_m;
  const double sn = n_body.dot(sun);
  for (int v = 0; v < height_; ++v)
    for (int u = 0; u < width_; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * width_ + u;
      double g = static_gain_[i];
      if (opt_.shadow && std::abs(sn) > 1e-3 && dist > 0.0) {
        const Eigen::Vector3d rW = pose.R_WC * renderer_.ray(u, v);
        const double dn = plane.n.dot(rW);
        if (dn < -1e-9) {
          const Eigen::Vector3d X = pose.p_WC + (-dist / dn) * rW;  // ground point
          // Toward the sun from X, where the line meets the drone's plane.
          const double t = n_body.dot(pose.p_WC - X) / sn;
          if (t > 0.0) {
            const Eigen::Vector3d Pc = pose.R_WC.transpose() * (X + t * sun - pose.p_WC);
            const double x = Pc.x(), y = Pc.y();
            const double w = opt_.shadow_softness_m + t * 0.0093;  // + the sun's penumbra (0.53 deg)
            double occ = softInside(std::hypot(x, y) - body_r, w);
            for (int q = 0; q < 4; ++q) {
              const double rx = (q & 1 ? 1 : -1) * rotor_c, ry = (q & 2 ? 1 : -1) * rotor_c;
              occ = std::max(occ, softInside(segmentDistance(x, y, 0, 0, rx, ry) - 0.5 * arm_w, w));
              occ = std::max(occ, 0.5 * softInside(std::hypot(x - rx, y - ry) - rotor_r, w));  // spinning props
            }
            const double sg = 1.0 - opt_.shadow_darkness * occ;
            if (sg < 0.9) ++shadowed;
            g *= sg;
          }
        }
      }
      gain_[i] = static_cast<float>(g);
      offset_[i] = static_cast<float>(static_add_[i] * mean_radiance);
      if (g < 0.9 || g > 1.1) ++covered;
    }
  coverage_ = static_cast<double>(covered) / n;
  shadow_coverage_ = static_cast<double>(shadowed) / n;
}

}  // namespace sim
}  // namespace diekf
