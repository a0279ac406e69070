// Ray-table renderer for a camera over a textured plane.
#include "diekf/sim/renderer.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <thread>

#include <opencv2/imgproc.hpp>

namespace diekf {
namespace sim {
namespace {

/// Inverts the camera's distortion by Gauss-Newton on distort(xn) = xd (numerical Jacobian).
Vec2 invertDistortion(const CameraModel& cam, const Vec2& xd) {
  Vec2 xn = xd;
  for (int it = 0; it < 30; ++it) {
    const Vec2 r = cam.distort(xn) - xd;
    if (r.norm() < 1e-13) break;
    const double h = 1e-7;
    Mat2 J;
    J.col(0) = (cam.distort(xn + Vec2(h, 0)) - cam.distort(xn - Vec2(h, 0))) / (2 * h);
    J.col(1) = (cam.distort(xn + Vec2(0, h)) - cam.distort(xn - Vec2(0, h))) / (2 * h);
    xn -= J.partialPivLu().solve(r);
  }
  return xn;
}

/// Cheap per-row hash for noise offsets (splitmix64).
std::uint64_t mix(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

constexpr int kNoiseTableSize = 1 << 20;

/// The ground plane seen from one sub-frame pose (renderRowsT, renderRowsClutter), everything in level-0 texel
/// units: the ray r = (x, y, 1) in C meets the plane at X(r) = p + lambda R r, lambda = -dist / (n_C . r).
struct GroundView {
  float nx, ny, nz;              // the plane's normal in C
  float ax, ay, az, bx, by, bz;  // the texture's axes in C, per texel
  float uc, vc;                  // the camera centre's texel coordinates (modulo the tile)
  float fdist, fp_scale;         // distance to the plane (> 0 on the normal's side); texels per metre of footprint
  bool above;                    // the camera on the normal's side
  // Specular patches (with `spec`): plane coordinates in metres (modulo the mask period) and the light in C.
  float mu = 0.f, mv = 0.f, t1x = 0.f, t1y = 0.f, t1z = 0.f, t2x = 0.f, t2y = 0.f, t2z = 0.f;
  float lx = 0.f, ly = 0.f, lz = 0.f, nl2 = 0.f, spec_gain = 0.f;

  GroundView(const CameraPose& P, const Plane& plane, const Texture& tex, const SpecularPatches* spec) {
    Eigen::Vector3d t1, t2;
    plane.basis(&t1, &t2);
    const Eigen::Vector3d origin = -plane.e_m * plane.n;  // a point on the plane (texture origin)
    const double isu = 1.0 / tex.texelU(), isv = 1.0 / tex.texelV();
    const Eigen::Vector3d nC = P.R_WC.transpose() * plane.n;
    const Eigen::Vector3d aC = P.R_WC.transpose() * t1 * isu, bC = P.R_WC.transpose() * t2 * isv;
    const double dist = plane.n.dot(P.p_WC) + plane.e_m;
    uc = static_cast<float>(std::fmod(t1.dot(P.p_WC - origin), tex.tileU()) * isu);
    vc = static_cast<float>(std::fmod(t2.dot(P.p_WC - origin), tex.tileV()) * isv);
    nx = static_cast<float>(nC.x()), ny = static_cast<float>(nC.y()), nz = static_cast<float>(nC.z());
    ax = static_cast<float>(aC.x()), ay = static_cast<float>(aC.y()), az = static_cast<float>(aC.z());
    bx = static_cast<float>(bC.x()), by = static_cast<float>(bC.y()), bz = static_cast<float>(bC.z());
    fdist = static_cast<float>(dist), fp_scale = tex.invTexelGeo();
    above = dist > 0.0;
    if (spec != nullptr) {
      const Eigen::Vector3d t1C = P.R_WC.transpose() * t1, t2C = P.R_WC.transpose() * t2;
      const Eigen::Vector3d lC = P.R_WC.transpose() * spec->lightW();
      mu = static_cast<float>(std::fmod(t1.dot(P.p_WC - origin), SpecularPatches::kPeriodM));
      mv = static_cast<float>(std::fmod(t2.dot(P.p_WC - origin), SpecularPatches::kPeriodM));
      t1x = static_cast<float>(t1C.x()), t1y = static_cast<float>(t1C.y()), t1z = static_cast<float>(t1C.z());
      t2x = static_cast<float>(t2C.x()), t2y = static_cast<float>(t2C.y()), t2z = static_cast<float>(t2C.z());
      lx = static_cast<float>(lC.x()), ly = static_cast<float>(lC.y()), lz = static_cast<float>(lC.z());
      nl2 = static_cast<float>(2.0 * nC.dot(lC));
      spec_gain = static_cast<float>(spec->amplitude() * tex.mean());
    }
  }

  /// n . r for the ray r = (x, y, 1); the ray meets the ground in front of the camera where it is below -1e-6 and
  /// the camera is above.
  float dn(float x, float y) const { return nx * x + ny * y + nz; }

  /// The ground's radiance along r = (x, y, 1) with `dn` = n . r < 0, `footprint` |r| times the pixel's angular
  /// size and `inv_norm` 1 / |r| (the renderer's ray table).
  template <bool kSpecular>
  float shade(float x, float y, float footprint, float inv_norm, float dn, const Texture& tex,
              const SpecularPatches* spec) const {
    const float lambda = -fdist / dn;
    const float xt = uc + lambda * (ax * x + ay * y + az);
    const float yt = vc + lambda * (bx * x + by * y + bz);
    // Footprint: distance x angular size, stretched by 1/sqrt(cos incidence) (area-equivalent side).
    const float fp = lambda * footprint * fp_scale / std::sqrt(-dn * inv_norm);
    float val = tex.sampleTexel(xt, yt, fastLog2(fp));
    if (kSpecular) {
      // Viewing ray (X -> camera) reflected about n, against the light: (r.l - 2 (n.r)(n.l)) / |r|.
      float c = inv_norm * (lx * x + ly * y + lz - dn * nl2);
      if (c > 0.f) {
        c *= c;  // power 16 by four squarings (kShininess)
        c *= c;
        c *= c;
        c *= c;
        if (c > 1e-4f) {
          const float pu = mu + lambda * (t1x * x + t1y * y + t1z);
          const float pv = mv + lambda * (t2x * x + t2y * y + t2z);
          val += spec_gain * c * spec->mask(pu, pv);
        }
      }
    }
    return val;
  }
};

}  // namespace

Renderer::Renderer(const CameraModel& cam, int threads) : cam_(cam), threads_(std::max(1, threads)) {
  width_ = cam.K.width;
  height_ = cam.K.height;
  if (width_ <= 0 || height_ <= 0 || !(cam.K.fx > 0) || !(cam.K.fy > 0))
    throw std::invalid_argument("Renderer: camera needs a resolution and positive focal lengths");
  // Unit rays at pixel centres plus one extra column/row for the angular pixel size.
  const int W = width_ + 1, H = height_ + 1;
  std::vector<Vec3> unit(static_cast<std::size_t>(W) * H);
  std::vector<Vec2> xy(unit.size());
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) {
      const Vec2 xd((u - cam.K.cx) / cam.K.fx, (v - cam.K.cy) / cam.K.fy);
      const Vec2 xn = invertDistortion(cam, xd);
      xy[static_cast<std::size_t>(v) * W + u] = xn;
      unit[static_cast<std::size_t>(v) * W + u] = Vec3(xn.x(), xn.y(), 1.0).normalized();
    }
  rays_.resize(static_cast<std::size_t>(width_) * height_);
  vignette_r2_.resize(rays_.size());
  const double rmax2 = std::max(cam.K.cx * cam.K.cx, (width_ - 1 - cam.K.cx) * (width_ - 1 - cam.K.cx)) +
                       std::max(cam.K.cy * cam.K.cy, (height_ - 1 - cam.K.cy) * (height_ - 1 - cam.K.cy));
  for (int v = 0; v < height_; ++v)
    for (int u = 0; u < width_; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * W + u;
      const Vec2& xn = xy[i];
      const double norm = std::sqrt(xn.squaredNorm() + 1.0);
      const double du = std::acos(std::clamp(unit[i].dot(unit[i + 1]), -1.0, 1.0));
      const double dv = std::acos(std::clamp(unit[i].dot(unit[i + W]), -1.0, 1.0));
      RayEntry& e = rays_[static_cast<std::size_t>(v) * width_ + u];
      e.x = static_cast<float>(xn.x());
      e.y = static_cast<float>(xn.y());
      e.footprint = static_cast<float>(norm * std::sqrt(du * dv));
      e.inv_norm = static_cast<float>(1.0 / norm);
      const double r2 = ((u - cam.K.cx) * (u - cam.K.cx) + (v - cam.K.cy) * (v - cam.K.cy)) / rmax2;
      vignette_r2_[static_cast<std::size_t>(v) * width_ + u] = static_cast<float>(r2);
    }
  ray_xmin_ = ray_ymin_ = 1e30f;
  ray_xmax_ = ray_ymax_ = -1e30f;
  for (const RayEntry& e : rays_) {
    ray_xmin_ = std::min(ray_xmin_, e.x);
    ray_xmax_ = std::max(ray_xmax_, e.x);
    ray_ymin_ = std::min(ray_ymin_, e.y);
    ray_ymax_ = std::max(ray_ymax_, e.y);
  }
  std::mt19937_64 rng(12345);
  std::normal_distribution<float> nd(0.f, 1.f);
  noise_table_.resize(kNoiseTableSize);
  for (float& x : noise_table_) x = nd(rng);
}

Eigen::Vector3d Renderer::ray(int u, int v) const {
  const RayEntry& e = rays_.at(static_cast<std::size_t>(v) * width_ + u);
  return Eigen::Vector3d(e.x, e.y, 1.0);
}

void Renderer::renderRows(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex, float* out,
                          int row0, int row1) const {
  renderRowsT<false>(poses, plane, tex, nullptr, out, row0, row1);
}

template <bool kSpecular>
void Renderer::renderRowsT(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex,
                           const SpecularPatches* spec, float* out, int row0, int row1) const {
  const float inv_n = 1.0f / static_cast<float>(poses.size());
  const float miss = tex.mean();
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const GroundView g(poses[k], plane, tex, kSpecular ? spec : nullptr);
    for (int v = row0; v < row1; ++v) {
      const RayEntry* re = &rays_[static_cast<std::size_t>(v) * width_];
      float* o = out + static_cast<std::size_t>(v) * width_;
      for (int u = 0; u < width_; ++u) {
        const RayEntry& e = re[u];
        const float dn = g.dn(e.x, e.y);
        const float val =
            g.above && dn < -1e-6f ? g.shade<kSpecular>(e.x, e.y, e.footprint, e.inv_norm, dn, tex, spec) : miss;
        if (k == 0)
          o[u] = val * inv_n;
        else
          o[u] += val * inv_n;
      }
    }
  }
}

namespace {

/// One object as seen from one sub-frame pose: the camera centre and the ray rotation in the object frame, and
/// the object's bounding box in normalised image coordinates (to skip the pixels it cannot cover).
struct ObjectView {
  float ox, oy, oz;  // camera centre in O
  float m[9];        // R_OC (row-major): ray direction in O = m * (x, y, 1)
  float xmin, xmax, ymin, ymax;
  float hx, hy, z0, z1;
  float u0, v0;      // texture coordinates (m) of the corner (-hx, -hy)
  float isu, isv, igeo, side_gain;
  const Texture* tex;
  bool flat, mover;
};

}  // namespace

ClutterMask* Renderer::prepareClutter(const std::vector<RowBand>& bands, const RenderEffects& fx,
                                      ClutterMask* own) const {
  if (!fx.clutter) return nullptr;
  if (fx.clutter->hasMovers())
    for (const RowBand& b : bands)
      if (b.times.size() != b.poses.size())
        throw std::invalid_argument("renderBands: moving objects need a time per pose (RowBand::times)");
  ClutterMask* m = fx.mask ? fx.mask : own;
  m->width = width_;
  m->height = height_;
  m->mover.assign(static_cast<std::size_t>(width_) * height_, 0.f);
  m->box.assign(m->mover.size(), 0.f);
  return m;
}

template <bool kSpecular>
void Renderer::renderRowsClutter(const RowBand& band, const Plane& plane, const Texture& tex,
                                 const SpecularPatches* spec, const Clutter& clutter, float* out, float* mask_mover,
                                 float* mask_box, int row0, int row1) const {
  // The ground exactly as renderRowsT draws it; then every object whose image box holds the pixel is ray cast
  // and the nearest hit (smallest ray parameter lambda along r = (x, y, 1)) is drawn instead.
  const std::vector<CameraPose>& poses = band.poses;
  const float inv_n = 1.0f / static_cast<float>(poses.size());
  const float miss = tex.mean();
  std::vector<ObjectView> views;
  views.reserve(clutter.objects().size());
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const CameraPose& P = poses[k];
    const double t_k = band.times.empty() ? 0.0 : band.times[k];
    const GroundView g(P, plane, tex, kSpecular ? spec : nullptr);
    // The objects this sub-frame can see, at the sub-frame's time.
    views.clear();
    for (const SceneObject& ob : clutter.objects()) {
      const Eigen::Vector3d p_WO = ob.positionAt(t_k);
      const Eigen::Matrix3d R_CO = P.R_WC.transpose() * ob.R_WO;
      const Eigen::Vector3d o_C = P.R_WC.transpose() * (p_WO - P.p_WC);
      ObjectView w;
      bool any_front = false, all_front = true;
      double xmin = 1e30, xmax = -1e30, ymin = 1e30, ymax = -1e30;
      for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3d X_O((c & 1) ? ob.hx : -ob.hx, (c & 2) ? ob.hy : -ob.hy, (c & 4) ? ob.z1 : ob.z0);
        const Eigen::Vector3d X = o_C + R_CO * X_O;
        if (X.z() > 1e-6) {
          any_front = true;
          xmin = std::min(xmin, X.x() / X.z());
          xmax = std::max(xmax, X.x() / X.z());
          ymin = std::min(ymin, X.y() / X.z());
          ymax = std::max(ymax, X.y() / X.z());
        } else {
          all_front = false;
        }
      }
      if (!any_front) continue;
      if (!all_front) xmin = ymin = -1e30, xmax = ymax = 1e30;  // partly behind the camera: test every pixel
      if (xmax < ray_xmin_ || xmin > ray_xmax_ || ymax < ray_ymin_ || ymin > ray_ymax_) continue;
      const Eigen::Matrix3d R_OC = R_CO.transpose();
      const Eigen::Vector3d o_O = -R_OC * o_C;  // camera centre in O
      w.ox = static_cast<float>(o_O.x()), w.oy = static_cast<float>(o_O.y()), w.oz = static_cast<float>(o_O.z());
      for (int i = 0; i < 9; ++i) w.m[i] = static_cast<float>(R_OC(i / 3, i % 3));
      w.xmin = static_cast<float>(std::max(xmin, -1e30)), w.xmax = static_cast<float>(std::min(xmax, 1e30));
      w.ymin = static_cast<float>(std::max(ymin, -1e30)), w.ymax = static_cast<float>(std::min(ymax, 1e30));
      w.hx = static_cast<float>(ob.hx), w.hy = static_cast<float>(ob.hy);
      w.z0 = static_cast<float>(ob.z0), w.z1 = static_cast<float>(ob.z1);
      w.tex = clutter.textures()[ob.texture].get();
      w.u0 = static_cast<float>(ob.u0_m), w.v0 = static_cast<float>(ob.v0_m);
      w.isu = static_cast<float>(1.0 / w.tex->texelU()), w.isv = static_cast<float>(1.0 / w.tex->texelV());
      w.igeo = w.tex->invTexelGeo();
      w.side_gain = ob.side_gain;
      w.flat = ob.flat;
      w.mover = ob.mover;
      views.push_back(w);
    }
    for (int v = row0; v < row1; ++v) {
      const RayEntry* re = &rays_[static_cast<std::size_t>(v) * width_];
      float* o = out + static_cast<std::size_t>(v) * width_;
      float* mm = mask_mover + static_cast<std::size_t>(v) * width_;
      float* mb = mask_box + static_cast<std::size_t>(v) * width_;
      for (int u = 0; u < width_; ++u) {
        const RayEntry& e = re[u];
        // Nearest object hit, if any.
        const ObjectView* hit = nullptr;
        float best = 3.0e38f, cos_hit = 1.f, su = 0.f, sv = 0.f, gain = 1.f;
        for (const ObjectView& w : views) {
          if (e.x < w.xmin || e.x > w.xmax || e.y < w.ymin || e.y > w.ymax) continue;
          const float dx = w.m[0] * e.x + w.m[1] * e.y + w.m[2];
          const float dy = w.m[3] * e.x + w.m[4] * e.y + w.m[5];
          const float dz = w.m[6] * e.x + w.m[7] * e.y + w.m[8];
          if (w.flat) {
            if (!(dz < -1e-9f)) continue;
            const float lam = (w.z1 - w.oz) / dz;
            if (!(lam > 0.f) || lam >= best) continue;
            const float px = w.ox + lam * dx, py = w.oy + lam * dy;
            if (px < -w.hx || px > w.hx || py < -w.hy || py > w.hy) continue;
            best = lam, hit = &w;
            su = px + w.hx, sv = py + w.hy, cos_hit = -dz * e.inv_norm, gain = 1.f;
            continue;
          }
          // Slab test of the box [-hx, hx] x [-hy, hy] x [z0, z1]; entry face 0 (x), 1 (y) or 2 (z).
          float tmin = -3.0e38f, tmax = 3.0e38f;
          int face = -1;
          const float d3[3] = {dx, dy, dz}, o3[3] = {w.ox, w.oy, w.oz};
          const float lo[3] = {-w.hx, -w.hy, w.z0}, hi[3] = {w.hx, w.hy, w.z1};
          bool miss_box = false;
          for (int a = 0; a < 3 && !miss_box; ++a) {
            if (std::fabs(d3[a]) < 1e-12f) {
              miss_box = o3[a] < lo[a] || o3[a] > hi[a];
              continue;
            }
            const float inv = 1.0f / d3[a];
            float ta = (lo[a] - o3[a]) * inv, tb = (hi[a] - o3[a]) * inv;
            if (ta > tb) std::swap(ta, tb);
            if (ta > tmin) tmin = ta, face = a;
            tmax = std::min(tmax, tb);
            miss_box = tmin > tmax;
          }
          if (miss_box || face < 0 || !(tmin > 0.f) || tmin >= best) continue;
          const float px = w.ox + tmin * dx, py = w.oy + tmin * dy, pz = w.oz + tmin * dz;
          best = tmin, hit = &w;
          if (face == 2) {
            su = px + w.hx, sv = py + w.hy, cos_hit = std::fabs(dz) * e.inv_norm, gain = 1.f;
          } else if (face == 0) {
            su = py + w.hy, sv = pz - w.z0, cos_hit = std::fabs(dx) * e.inv_norm, gain = w.side_gain;
          } else {
            su = px + w.hx, sv = pz - w.z0, cos_hit = std::fabs(dy) * e.inv_norm, gain = 0.5f * (1.f + w.side_gain);
          }
        }
        const float dn = g.dn(e.x, e.y);
        float val = miss;
        bool ground = g.above && dn < -1e-6f;
        if (ground && hit && best < -g.fdist / dn) ground = false;
        if (hit && !ground) {
          // The object's face: same footprint rule as the ground (distance x angle / sqrt(cos incidence)).
          const float fp = best * e.footprint * hit->igeo / std::sqrt(std::max(cos_hit, 1e-3f));
          val = gain * hit->tex->sampleTexel((hit->u0 + su) * hit->isu, (hit->v0 + sv) * hit->isv, fastLog2(fp));
        } else if (ground) {
          val = g.shade<kSpecular>(e.x, e.y, e.footprint, e.inv_norm, dn, tex, spec);
        }
        const bool seen = hit && !ground;
        const float wm = seen && hit->mover ? inv_n : 0.f, wb = seen && !hit->mover ? inv_n : 0.f;
        if (k == 0) {
          o[u] = val * inv_n;
          mm[u] = wm;
          mb[u] = wb;
        } else {
          o[u] += val * inv_n;
          mm[u] += wm;
          mb[u] += wb;
        }
      }
    }
  }
}

void Renderer::checkBands(const std::vector<RowBand>& bands) const {
  int next = 0;
  for (const RowBand& b : bands) {
    if (b.row0 != next || b.row1 <= b.row0 || b.poses.empty())
      throw std::invalid_argument("renderBands: bands must cover the rows in order, each with a pose");
    next = b.row1;
  }
  if (next != height_) throw std::invalid_argument("renderBands: bands must cover all rows");
}

void Renderer::renderBandRows(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex,
                              const SpecularPatches* spec, float* out, int row0, int row1, const Clutter* clutter,
                              ClutterMask* mask) const {
  for (const RowBand& b : bands) {
    const int r0 = std::max(b.row0, row0), r1 = std::min(b.row1, row1);
    if (r0 >= r1) continue;
    if (clutter) {
      if (spec)
        renderRowsClutter<true>(b, plane, tex, spec, *clutter, out, mask->mover.data(), mask->box.data(), r0, r1);
      else
        renderRowsClutter<false>(b, plane, tex, nullptr, *clutter, out, mask->mover.data(), mask->box.data(), r0,
                                 r1);
    } else if (spec)
      renderRowsT<true>(b.poses, plane, tex, spec, out, r0, r1);
    else
      renderRowsT<false>(b.poses, plane, tex, nullptr, out, r0, r1);
  }
}

void Renderer::renderRadianceBands(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex,
                                   std::vector<float>* out, const RenderEffects& fx) const {
  checkBands(bands);
  out->resize(static_cast<std::size_t>(width_) * height_);
  const SpecularPatches* spec = fx.specular && fx.specular->amplitude() > 0.0 ? fx.specular : nullptr;
  ClutterMask own_mask;
  ClutterMask* mask = prepareClutter(bands, fx, &own_mask);
  const Clutter* clutter = mask ? fx.clutter : nullptr;
  const int n = std::min(threads_, height_);
  std::vector<std::thread> pool;
  for (int i = 1; i < n; ++i) {
    const int r0 = height_ * i / n, r1 = height_ * (i + 1) / n;
    pool.emplace_back([&, r0, r1] { renderBandRows(bands, plane, tex, spec, out->data(), r0, r1, clutter, mask); });
  }
  renderBandRows(bands, plane, tex, spec, out->data(), 0, height_ / std::max(n, 1), clutter, mask);
  for (auto& t : pool) t.join();
}

cv::Mat Renderer::renderBands(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex,
                              double gain, const SensorOptions& opt, std::uint64_t noise_seed,
                              const RenderEffects& fx) const {
  checkBands(bands);
  cv::Mat img(height_, width_, CV_8UC1);
  std::vector<float> rad(static_cast<std::size_t>(width_) * height_);
  const SpecularPatches* spec = fx.specular && fx.specular->amplitude() > 0.0 ? fx.specular : nullptr;
  ClutterMask own_mask;
  ClutterMask* mask = prepareClutter(bands, fx, &own_mask);
  const Clutter* clutter = mask ? fx.clutter : nullptr;
  const bool defocus = fx.defocus_sigma_px > 0.0;
  const int n = std::min(threads_, height_);
  const auto run = [&](const std::function<void(int, int)>& work) {
    std::vector<std::thread> pool;
    for (int i = 1; i < n; ++i) pool.emplace_back(work, height_ * i / n, height_ * (i + 1) / n);
    work(0, height_ / std::max(n, 1));
    for (auto& t : pool) t.join();
  };
  if (!defocus) {
    run([&](int r0, int r1) {
      renderBandRows(bands, plane, tex, spec, rad.data(), r0, r1, clutter, mask);
      sensorRows(rad.data(), gain, opt, noise_seed, &img, r0, r1);
    });
    return img;
  }
  run([&](int r0, int r1) { renderBandRows(bands, plane, tex, spec, rad.data(), r0, r1, clutter, mask); });
  // Defocus: Gaussian point spread on the radiance (before gain, vignetting and noise).
  cv::Mat r(height_, width_, CV_32FC1, rad.data());
  cv::GaussianBlur(r, r, cv::Size(0, 0), fx.defocus_sigma_px, fx.defocus_sigma_px, cv::BORDER_REFLECT);
  run([&](int r0, int r1) { sensorRows(rad.data(), gain, opt, noise_seed, &img, r0, r1); });
  return img;
}

std::vector<RowBand> rollingShutterBands(const std::function<CameraPose(double)>& pose_at, double t_mid_s,
                                         int height, double readout_s, double exposure_s, int n_sub,
                                         int rows_per_band) {
  if (height <= 0 || n_sub < 1 || rows_per_band < 1) throw std::invalid_argument("rollingShutterBands: bad sizes");
  std::vector<RowBand> bands;
  const auto subposes = [&](double t, RowBand* b) {
    for (int j = 0; j < n_sub; ++j) {
      const double ts = n_sub == 1 ? t : t + exposure_s * ((j + 0.5) / n_sub - 0.5);
      b->poses.push_back(pose_at(ts));
      b->times.push_back(ts);
    }
  };
  if (!(readout_s > 0.0)) {
    RowBand b;
    b.row0 = 0;
    b.row1 = height;
    subposes(t_mid_s, &b);
    bands.push_back(std::move(b));
    return bands;
  }
  for (int r0 = 0; r0 < height; r0 += rows_per_band) {
    RowBand b;
    b.row0 = r0;
    b.row1 = std::min(height, r0 + rows_per_band);
    // Time of the band's middle (row index may be half-integer for an even band).
    const double v_mid = 0.5 * (b.row0 + b.row1 - 1);
    const double dt = height > 1 ? readout_s * (v_mid / (height - 1) - 0.5) : 0.0;
    subposes(t_mid_s + dt, &b);
    bands.push_back(std::move(b));
  }
  return bands;
}

void Renderer::renderRadiance(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex,
                              std::vector<float>* out) const {
  if (poses.empty()) throw std::invalid_argument("renderRadiance: no pose");
  out->resize(static_cast<std::size_t>(width_) * height_);
  const int n = std::min(threads_, height_);
  if (n <= 1) {
    renderRows(poses, plane, tex, out->data(), 0, height_);
    return;
  }
  std::vector<std::thread> pool;
  for (int i = 1; i < n; ++i) {
    const int r0 = height_ * i / n, r1 = height_ * (i + 1) / n;
    pool.emplace_back([&, r0, r1] { renderRows(poses, plane, tex, out->data(), r0, r1); });
  }
  renderRows(poses, plane, tex, out->data(), 0, height_ / n);
  for (auto& t : pool) t.join();
}

cv::Mat Renderer::applySensor(const std::vector<float>& radiance, double gain, const SensorOptions& opt,
                              std::uint64_t noise_seed) const {
  cv::Mat img(height_, width_, CV_8UC1);
  sensorRows(radiance.data(), gain, opt, noise_seed, &img, 0, height_);
  return img;
}

void Renderer::sensorRows(const float* radiance, double gain, const SensorOptions& opt, std::uint64_t noise_seed,
                          cv::Mat* img, int row0, int row1) const {
  const float g = static_cast<float>(gain), vig = static_cast<float>(opt.vignetting);
  const float read2 = static_cast<float>(opt.read_noise_dn * opt.read_noise_dn);
  const float shot = static_cast<float>(opt.shot_noise_dn);
  const float black = static_cast<float>(opt.black_level_dn);
  const bool encode = opt.gamma != 1.0;
  const float inv_gamma = static_cast<float>(1.0 / opt.gamma);
  for (int v = row0; v < row1; ++v) {
    const std::size_t off = mix(noise_seed * 1000003ull + static_cast<std::uint64_t>(v)) % (kNoiseTableSize - width_);
    const float* nz = &noise_table_[off];
    const float* rad = radiance + static_cast<std::size_t>(v) * width_;
    const float* r2 = &vignette_r2_[static_cast<std::size_t>(v) * width_];
    unsigned char* row = img->ptr<unsigned char>(v);
    const float* fg = opt.fixed_gain ? opt.fixed_gain + static_cast<std::size_t>(v) * width_ : nullptr;
    const float* fa = opt.fixed_add ? opt.fixed_add + static_cast<std::size_t>(v) * width_ : nullptr;
    const float gv = opt.row_gain ? g * opt.row_gain[v] : g;
    for (int u = 0; u < width_; ++u) {
      float s = gv * (1.0f - vig * r2[u]) * rad[u];
      if (fg) s *= fg[u];
      if (fa) s += gv * fa[u];
      if (opt.noise) s += nz[u] * std::sqrt(read2 + shot * std::max(s, 0.0f));
      s = std::clamp(s + black, 0.0f, 255.0f);
      if (encode) s = 255.0f * std::pow(s * (1.0f / 255.0f), inv_gamma);
      row[u] = static_cast<unsigned char>(std::min(s + 0.5f, 255.0f));
    }
  }
}

cv::Mat Renderer::renderImage(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex,
                              double gain, const SensorOptions& opt, std::uint64_t noise_seed) const {
  if (poses.empty()) throw std::invalid_argument("renderImage: no pose");
  cv::Mat img(height_, width_, CV_8UC1);
  std::vector<float> rad(static_cast<std::size_t>(width_) * height_);
  const auto work = [&](int r0, int r1) {
    renderRows(poses, plane, tex, rad.data(), r0, r1);
    sensorRows(rad.data(), gain, opt, noise_seed, &img, r0, r1);
  };
  const int n = std::min(threads_, height_);
  std::vector<std::thread> pool;
  for (int i = 1; i < n; ++i) pool.emplace_back(work, height_ * i / n, height_ * (i + 1) / n);
  work(0, height_ / std::max(n, 1));
  for (auto& t : pool) t.join();
  return img;
}

double Renderer::motionPixels(const CameraPose& a, const CameraPose& b, const Plane& plane) const {
  double worst = 0.0;
  for (int gy = 0; gy < 3; ++gy)
    for (int gx = 0; gx < 3; ++gx) {
      const int u = (width_ - 1) * (1 + 3 * gx) / 7, v = (height_ - 1) * (1 + 3 * gy) / 7;  // inner 3x3 grid
      const Eigen::Vector3d rW = a.R_WC * ray(u, v);
      const double dn = plane.n.dot(rW), dist = plane.n.dot(a.p_WC) + plane.e_m;
      if (!(dn < -1e-9) || dist <= 0.0) continue;
      const Eigen::Vector3d X = a.p_WC + (-dist / dn) * rW;
      Vec2 px;
      if (!cam_.project(b.R_WC.transpose() * (X - b.p_WC), &px)) continue;
      worst = std::max(worst, (px - Vec2(u, v)).norm());
    }
  return worst;
}

}  // namespace sim
}  // namespace diekf
