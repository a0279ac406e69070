// Moving objects and boxes on the ground for the simulator (generation; the renderer ray casts them).
#include "diekf/sim/clutter.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <stdexcept>

namespace diekf {
namespace sim {

Clutter::Clutter(std::vector<SceneObject> objects, std::vector<std::shared_ptr<const Texture>> textures)
    : objects_(std::move(objects)), textures_(std::move(textures)) {
  for (const SceneObject& o : objects_) {
    if (o.texture < 0 || o.texture >= static_cast<int>(textures_.size()) || !textures_[o.texture])
      throw std::invalid_argument("Clutter: object without a texture");
    if (!(o.hx > 0.0) || !(o.hy > 0.0) || o.z1 < o.z0 || (!o.flat && !(o.z1 > o.z0)))
      throw std::invalid_argument("Clutter: object with an empty extent");
  }
}

bool Clutter::hasMovers() const {
  return std::any_of(objects_.begin(), objects_.end(), [](const SceneObject& o) { return o.mover; });
}

double Clutter::maxBoxHeight() const {
  double h = 0.0;
  for (const SceneObject& o : objects_)
    if (!o.mover) h = std::max(h, o.z1);
  return h;
}

std::shared_ptr<const Texture> clutterTexture(const std::string& name, std::uint64_t seed) {
  if (name == "leaves") return std::make_shared<const Texture>(Texture::leaves(seed, 0.001, 1024));
  if (name == "grass") return std::make_shared<const Texture>(Texture::grass(seed, 0.001, 1024));
  if (name == "dirt") return std::make_shared<const Texture>(Texture::dirt(seed, 0.001, 1024));
  if (name == "natural") return std::make_shared<const Texture>(Texture::natural(seed, 0.002, 512));
  if (name == "checkerboard") return std::make_shared<const Texture>(Texture::checkerboard());
  return std::make_shared<const Texture>(Texture::fromImage(name, 1.0));
}

Clutter makeClutter(const ClutterOptions& opt, const Plane& plane,
                    const std::function<Eigen::Vector3d(double)>& look_at, double duration_s, std::uint64_t seed) {
  std::vector<SceneObject> objects;
  std::vector<std::shared_ptr<const Texture>> textures;
  if (!opt.any()) return Clutter();
  Eigen::Vector3d t1, t2;
  plane.basis(&t1, &t2);
  const Eigen::Vector3d& n = plane.n;
  const auto frame = [&](double yaw) {
    Eigen::Matrix3d R;
    R.col(0) = std::cos(yaw) * t1 + std::sin(yaw) * t2;
    R.col(2) = n;
    R.col(1) = n.cross(R.col(0));
    return R;
  };
  const auto onPlane = [&](const Eigen::Vector3d& X) { return X - (n.dot(X) + plane.e_m) * n; };
  // Separate streams for movers and boxes: adding boxes does not move the movers and vice versa.
  const int mover_tex = opt.movers > 0 ? 0 : -1;
  if (opt.movers > 0) textures.push_back(clutterTexture(opt.mover_texture, seed * 31 + 7));
  const int box_tex = opt.boxes > 0 ? static_cast<int>(textures.size()) : -1;
  if (opt.boxes > 0) textures.push_back(clutterTexture(opt.box_texture, seed * 31 + 11));

  if (opt.movers > 0) {
    std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 0x40BE5ull);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    const double tile_u = textures[mover_tex]->tileU(), tile_v = textures[mover_tex]->tileV();
    int count = 0;
    for (int k = 0; k < opt.movers; ++k)
      for (int i = 0;; ++i) {
        const double tc = opt.mover_interval_s * (i + (k + 0.5) / opt.movers);
        if (tc > duration_s + 0.5 * opt.mover_interval_s) break;
        const double yaw = 2.0 * M_PI * uni(rng);
        const double speed = opt.mover_speed_mps * (0.8 + 0.4 * uni(rng));
        const double side = 0.3 * (uni(rng) - 0.5);
        SceneObject o;
        o.R_WO = frame(yaw);
        o.p0_W = onPlane(look_at(tc)) + side * o.R_WO.col(1);
        o.v_W = speed * o.R_WO.col(0);
        o.t0_s = tc;
        o.hx = 0.5 * opt.mover_size_m;
        o.hy = 0.5 * opt.mover_size_m * opt.mover_aspect;
        o.z0 = o.z1 = 0.01 + 0.001 * (count % 8);
        o.flat = true;
        o.mover = true;
        o.texture = mover_tex;
        o.u0_m = tile_u * uni(rng);
        o.v0_m = tile_v * uni(rng);
        objects.push_back(o);
        ++count;
      }
  }
  if (opt.boxes > 0) {
    std::mt19937_64 rng(seed * 0xD1B54A32D192ED03ull + 0xB0C5ull);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    const double tile_u = textures[box_tex]->tileU(), tile_v = textures[box_tex]->tileV();
    std::vector<std::pair<Eigen::Vector3d, double>> placed;  // centre, radius of the footprint
    for (int b = 0; b < opt.boxes; ++b) {
      for (int attempt = 0; attempt < 500; ++attempt) {
        const double t = duration_s * uni(rng);
        const double du = 1.2 * (uni(rng) - 0.5), dv = 1.2 * (uni(rng) - 0.5);
        const double yaw = M_PI * uni(rng);
        const double sx = opt.box_size_m * (0.75 + 0.5 * uni(rng)), sy = opt.box_size_m * (0.75 + 0.5 * uni(rng));
        const Eigen::Vector3d c = onPlane(look_at(t)) + du * t1 + dv * t2;
        const double r = 0.5 * std::hypot(sx, sy);
        bool free = true;
        for (const auto& p : placed) free = free && (c - p.first).norm() > r + p.second + 0.05;
        if (!free) continue;
        placed.emplace_back(c, r);
        SceneObject o;
        o.R_WO = frame(yaw);
        o.p0_W = c;
        o.hx = 0.5 * sx;
        o.hy = 0.5 * sy;
        o.z0 = 0.0;
        o.z1 = opt.box_height_m;
        o.texture = box_tex;
        o.u0_m = tile_u * uni(rng);
        o.v0_m = tile_v * uni(rng);
        objects.push_back(o);
        break;
      }
    }
  }
  return Clutter(std::move(objects), std::move(textures));
}

double ClutterMask::moverFraction() const {
  return mover.empty() ? 0.0 : std::accumulate(mover.begin(), mover.end(), 0.0) / mover.size();
}

double ClutterMask::boxFraction() const {
  return box.empty() ? 0.0 : std::accumulate(box.begin(), box.end(), 0.0) / box.size();
}

double ClutterMask::anyFraction() const { return moverFraction() + boxFraction(); }

}  // namespace sim
}  // namespace diekf
