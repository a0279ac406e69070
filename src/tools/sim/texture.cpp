// Texture pyramid construction and the procedural textures (checkerboard, vegetation-like).
#include "diekf/sim/texture.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace diekf {
namespace sim {
namespace {

bool isPow2(int v) { return v > 0 && (v & (v - 1)) == 0; }

int nearestPow2(int v, int lo, int hi) {
  int p = lo;
  while (p < hi && p * 2 <= v + v / 2) p *= 2;  // round to the nearest power (geometric midpoint ~ 1.5x)
  return p;
}

/// Periodic smooth value noise on a w x h tile with `cells` lattice cells across the tile (power of two).
void addValueNoise(std::vector<float>* img, int w, int h, int cells, float amplitude, std::mt19937_64* rng) {
  std::normal_distribution<float> nd(0.f, 1.f);
  std::vector<float> lattice(static_cast<std::size_t>(cells) * cells);
  for (float& v : lattice) v = nd(*rng);
  const double sx = static_cast<double>(cells) / w, sy = static_cast<double>(cells) / h;
  const int m = cells - 1;
  for (int y = 0; y < h; ++y) {
    const double fy = (y + 0.5) * sy;
    const int y0 = static_cast<int>(std::floor(fy));
    double ty = fy - y0;
    ty = ty * ty * ty * (ty * (ty * 6 - 15) + 10);  // smootherstep
    const float* l0 = &lattice[static_cast<std::size_t>(y0 & m) * cells];
    const float* l1 = &lattice[static_cast<std::size_t>((y0 + 1) & m) * cells];
    float* row = &(*img)[static_cast<std::size_t>(y) * w];
    for (int x = 0; x < w; ++x) {
      const double fx = (x + 0.5) * sx;
      const int x0 = static_cast<int>(std::floor(fx));
      double tx = fx - x0;
      tx = tx * tx * tx * (tx * (tx * 6 - 15) + 10);
      const int a = x0 & m, b = (x0 + 1) & m;
      const double top = l0[a] + tx * (l0[b] - l0[a]);
      const double bot = l1[a] + tx * (l1[b] - l1[a]);
      row[x] += amplitude * static_cast<float>(top + ty * (bot - top));
    }
  }
}

/// Soft-edged stamp painted with wrap-around: value `delta` blended in by coverage(dx, dy) in [0, 1].
template <typename Coverage>
void stamp(std::vector<float>* img, int w, int h, double cx, double cy, double radius_px, float delta, Coverage cov) {
  const int r = static_cast<int>(std::ceil(radius_px)) + 2;
  const int ix = static_cast<int>(std::floor(cx)), iy = static_cast<int>(std::floor(cy));
  for (int y = iy - r; y <= iy + r; ++y) {
    for (int x = ix - r; x <= ix + r; ++x) {
      const float c = cov(x + 0.5 - cx, y + 0.5 - cy);
      if (c <= 0.f) continue;
      float& p = (*img)[static_cast<std::size_t>(y & (h - 1)) * w + (x & (w - 1))];
      p += c * delta;
    }
  }
}

float smoothEdge(double inside_px) {  // coverage from signed distance inside the shape (pixels)
  if (inside_px >= 0.75) return 1.f;
  if (inside_px <= -0.75) return 0.f;
  const double t = (inside_px + 0.75) / 1.5;
  return static_cast<float>(t * t * (3 - 2 * t));
}

}  // namespace

Texture::Level Texture::makeLevel(const std::vector<float>& linear, int w, int h, float sx, float sy) {
  Level L;
  L.w = w;
  L.h = h;
  L.W = std::max(w, 4);
  L.H = std::max(h, 4);
  L.blocks_per_row = L.W / 4;
  L.sx = sx;
  L.sy = sy;
  L.quads.resize(static_cast<std::size_t>(L.W) * L.H);
  const auto fixed = [&](int x, int y) -> std::uint64_t {
    const float v = linear[static_cast<std::size_t>(y & (h - 1)) * w + (x & (w - 1))];
    return static_cast<std::uint64_t>(std::clamp(std::lround(v * 256.0f), 0L, 65535L));
  };
  for (int y = 0; y < L.H; ++y)
    for (int x = 0; x < L.W; ++x)
      L.quads[blockIndex(L, x, y)] = fixed(x, y) | (fixed(x + 1, y) << 16) | (fixed(x, y + 1) << 32) | (fixed(x + 1, y + 1) << 48);
  return L;
}

float Texture::at(int level, int x, int y) const {
  const Level& L = levels_.at(static_cast<std::size_t>(level));
  return static_cast<float>(L.quads[blockIndex(L, x & (L.W - 1), y & (L.H - 1))] & 0xFFFF) / 256.0f;
}

Texture::Texture(const std::vector<float>& level0, int width, int height, double texel_u_m, double texel_v_m)
    : texel_u_m_(texel_u_m), texel_v_m_(texel_v_m) {
  if (!isPow2(width) || !isPow2(height) || level0.size() != static_cast<std::size_t>(width) * height)
    throw std::invalid_argument("Texture: dimensions must be powers of two matching the data");
  if (!(texel_u_m > 0.0) || !(texel_v_m > 0.0)) throw std::invalid_argument("Texture: texel size must be > 0");
  inv_texel_geo_m_ = static_cast<float>(1.0 / std::sqrt(texel_u_m * texel_v_m));
  mean_ = static_cast<float>(std::accumulate(level0.begin(), level0.end(), 0.0) / level0.size());
  // 2x2 box reduction down to 1x1 (an axis already at 1 texel stays).
  std::vector<float> cur = level0;
  int w = width, h = height;
  float sx = 1.f, sy = 1.f;
  levels_.push_back(makeLevel(cur, w, h, sx, sy));
  while (w > 1 || h > 1) {
    const int fx = w > 1 ? 2 : 1, fy = h > 1 ? 2 : 1;
    const int nw = w / fx, nh = h / fy;
    std::vector<float> next(static_cast<std::size_t>(nw) * nh);
    for (int y = 0; y < nh; ++y)
      for (int x = 0; x < nw; ++x) {
        float s = 0.f;
        for (int dy = 0; dy < fy; ++dy)
          for (int dx = 0; dx < fx; ++dx) s += cur[static_cast<std::size_t>(y * fy + dy) * w + x * fx + dx];
        next[static_cast<std::size_t>(y) * nw + x] = s / (fx * fy);
      }
    cur.swap(next);
    w = nw;
    h = nh;
    sx /= fx;
    sy /= fy;
    levels_.push_back(makeLevel(cur, w, h, sx, sy));
  }
}

Texture Texture::checkerboard(double square_m, int squares_per_tile, int texels_per_square, float dark, float bright) {
  if (!(square_m > 0.0) || !isPow2(texels_per_square) || !isPow2(squares_per_tile) || squares_per_tile < 2)
    throw std::invalid_argument("checkerboard: square size > 0, powers of two for tile/texel counts");
  const int n = squares_per_tile * texels_per_square;
  std::vector<float> px(static_cast<std::size_t>(n) * n);
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x)
      px[static_cast<std::size_t>(y) * n + x] = (((x / texels_per_square) + (y / texels_per_square)) & 1) ? bright : dark;
  const double texel = square_m / texels_per_square;
  return Texture(px, n, n, texel, texel);
}

Texture Texture::natural(std::uint64_t seed, double texel_m, int tile_px) {
  if (!isPow2(tile_px) || tile_px < 64) throw std::invalid_argument("natural texture: tile_px a power of two >= 64");
  const int n = tile_px;
  std::mt19937_64 rng(seed ^ 0x9E3779B97F4A7C15ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<float> img(static_cast<std::size_t>(n) * n, 0.f);

  // Soil / dirt: value-noise octaves with feature sizes from ~0.5 m down to a few texels; the centimetre
  // scales carry most of the energy (the patterns the camera tracks), the large scales give gentle shading.
  for (int cells = 8; cells <= n / 2; cells *= 2) {
    const double feature_m = texel_m * n / cells;
    const float amp = feature_m > 0.12 ? 0.3f : feature_m > 0.012 ? 0.5f : feature_m > 0.005 ? 0.3f : 0.15f;
    addValueNoise(&img, n, n, cells, amp, &rng);
  }
  const double tile_m = n * texel_m;
  const double px_per_m = 1.0 / texel_m;

  // Leaf blobs: soft ellipses 1-6 cm, darker or lighter than the soil, with a midrib.
  const int n_leaves = static_cast<int>(450.0 * tile_m * tile_m);
  for (int i = 0; i < n_leaves; ++i) {
    const double cx = uni(rng) * n, cy = uni(rng) * n;
    const double a = (0.02 + 0.06 * uni(rng) * uni(rng)) * px_per_m * 0.5;  // semi-major (px)
    const double b = a * (0.3 + 0.4 * uni(rng));
    const double th = uni(rng) * 2.0 * M_PI, c = std::cos(th), s = std::sin(th);
    const float delta = static_cast<float>((uni(rng) < 0.6 ? -1.0 : 1.0) * (0.6 + 0.9 * uni(rng)));
    stamp(&img, n, n, cx, cy, a, delta, [&](double dx, double dy) {
      const double u = c * dx + s * dy, v = -s * dx + c * dy;
      const double r = std::sqrt((u * u) / (a * a) + (v * v) / (b * b));
      float cov = smoothEdge((1.0 - r) * b);
      if (cov > 0.f && std::abs(v) < 0.6) cov *= 0.6f;  // midrib
      return cov;
    });
  }
  // Grass blades: thin strokes 2-8 cm, mostly lighter, 1-2 texels wide.
  const int n_blades = static_cast<int>(1500.0 * tile_m * tile_m);
  for (int i = 0; i < n_blades; ++i) {
    const double cx = uni(rng) * n, cy = uni(rng) * n;
    const double len = (0.02 + 0.06 * uni(rng)) * px_per_m;
    const double half_w = 0.5 + 0.7 * uni(rng);
    const double th = uni(rng) * 2.0 * M_PI, c = std::cos(th), s = std::sin(th);
    const float delta = static_cast<float>((uni(rng) < 0.7 ? 1.0 : -1.0) * (0.4 + 0.8 * uni(rng)));
    stamp(&img, n, n, cx, cy, 0.5 * len + half_w, delta, [&](double dx, double dy) {
      const double u = c * dx + s * dy, v = -s * dx + c * dy;
      const double along = 0.5 * len - std::abs(u);
      const double taper = half_w * std::min(1.0, std::max(0.0, along / (0.3 * len)) + 0.3);
      return std::min(smoothEdge(along), smoothEdge(taper - std::abs(v)));
    });
  }
  // Normalise to mean 110, std 30 grey levels and soft-clip into [5, 250].
  double mean = 0.0, var = 0.0;
  for (float v : img) mean += v;
  mean /= img.size();
  for (float v : img) var += (v - mean) * (v - mean);
  const double sd = std::sqrt(var / img.size());
  for (float& v : img) {
    const double z = (v - mean) / sd;
    v = static_cast<float>(std::clamp(110.0 + 30.0 * z, 5.0, 250.0));
  }
  return Texture(img, n, n, texel_m, texel_m);
}

namespace {

// Helpers of the grass, leaves and dirt textures. All sizes handed to them are in texels; the texture functions
// convert from metres, so the textures keep their physical scale whatever the texel size.

constexpr double kTwoPi = 6.283185307179586;

/// Power-of-two lattice cell count whose cells are closest to `feature_m` on a tile of `tile_m`, within [2, n/2].
int cellsFor(double tile_m, double feature_m, int n) {
  int cells = 2;
  while (cells < n / 2 && tile_m / (cells * 2) >= feature_m / 1.41421356) cells *= 2;
  return cells;
}

/// Interval of dx with lo <= a dx <= hi (a = 0: everything or nothing).
bool slab(double a, double lo, double hi, double* x0, double* x1) {
  if (std::abs(a) < 1e-12) {
    *x0 = -1e300;
    *x1 = 1e300;
    return lo <= 0.0 && 0.0 <= hi;
  }
  *x0 = (a > 0 ? lo : hi) / a;
  *x1 = (a > 0 ? hi : lo) / a;
  return true;
}

/// Calls f(pixel, u, v) for every texel centre (wrapped into the n x n tile) inside the rectangle
/// u in [u0, u1], v in [v0, v1] of the local frame centred at (cx, cy) (texels) with axes
/// u = (c, s), v = (-s, c): u = c dx + s dy, v = -s dx + c dy. Scans only the rectangle's rows and spans.
template <typename F>
void forEachInRect(std::vector<float>* img, int n, double cx, double cy, double c, double s, double u0, double u1,
                   double v0, double v1, F f) {
  double ymin = 1e300, ymax = -1e300;
  for (double u : {u0, u1})
    for (double v : {v0, v1}) {
      const double y = cy + s * u + c * v;
      ymin = std::min(ymin, y);
      ymax = std::max(ymax, y);
    }
  for (int y = static_cast<int>(std::ceil(ymin - 0.5)); y <= static_cast<int>(std::floor(ymax - 0.5)); ++y) {
    const double dy = y + 0.5 - cy;
    double a0, a1, b0, b1;
    if (!slab(c, u0 - s * dy, u1 - s * dy, &a0, &a1) || !slab(-s, v0 - c * dy, v1 - c * dy, &b0, &b1)) continue;
    const double lo = std::max(a0, b0), hi = std::min(a1, b1);
    if (lo > hi) continue;
    float* row = &(*img)[static_cast<std::size_t>(y & (n - 1)) * n];
    for (int x = static_cast<int>(std::ceil(cx + lo - 0.5)); x <= static_cast<int>(std::floor(cx + hi - 0.5)); ++x) {
      const double dx = x + 0.5 - cx;
      f(row[x & (n - 1)], c * dx + s * dy, -s * dx + c * dy);
    }
  }
}

/// Soft coverage over a wider edge than smoothEdge (shadows): 0 at -width, 1 at +width.
float softEdge(double inside_px, double width_px) {
  const double t = std::clamp((inside_px + width_px) / (2.0 * width_px), 0.0, 1.0);
  return static_cast<float>(t * t * (3 - 2 * t));
}

/// Shifts and scales to the given mean and standard deviation, then clamps into [lo, hi] grey levels.
void normalise(std::vector<float>* img, double mean_target, double sd_target, double lo, double hi) {
  double mean = 0.0, var = 0.0;
  for (float v : *img) mean += v;
  mean /= img->size();
  for (float v : *img) var += (v - mean) * (v - mean);
  const double sd = std::max(1e-9, std::sqrt(var / img->size()));
  for (float& v : *img) v = static_cast<float>(std::clamp(mean_target + sd_target * (v - mean) / sd, lo, hi));
}

void checkProceduralArgs(const char* what, double texel_m, int tile_px) {
  if (!isPow2(tile_px) || tile_px < 64 || !(texel_m > 0.0))
    throw std::invalid_argument(std::string(what) + " texture: texel size > 0 and tile_px a power of two >= 64");
}

}  // namespace

Texture Texture::grass(std::uint64_t seed, double texel_m, int tile_px, double direction_deg) {
  checkProceduralArgs("grass", texel_m, tile_px);
  const int n = tile_px;
  const double tile_m = n * texel_m, px = 1.0 / texel_m;  // px: texels per metre
  std::mt19937_64 rng(seed ^ 0x6772617373000001ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> nd(0.0, 1.0);

  // Gaps: the shadowed bottom of the sward (dead thatch, soil), dark with centimetre mottling.
  std::vector<float> img(static_cast<std::size_t>(n) * n, 0.f);
  addValueNoise(&img, n, n, cellsFor(tile_m, 0.02, n), 6.f, &rng);
  for (float& v : img) v += 35.f;

  struct Blade {
    double cx, cy, th, len, hw, bow, bright;
  };
  // Blade sizes (m): length 4-12 cm, width 2-5 mm, bend up to +-6 mm; area coverage 3.5 layers.
  const double mean_area_m2 = 0.08 * 0.0035 * 0.8;
  const int n_blades = static_cast<int>(3.5 * tile_m * tile_m / mean_area_m2);
  const double th0 = direction_deg * M_PI / 180.0;
  std::vector<std::pair<double, Blade>> blades;  // (depth 0 = bottom .. 1 = top, blade)
  blades.reserve(n_blades);
  for (int i = 0; i < n_blades; ++i) {
    Blade b;
    b.cx = uni(rng) * n;
    b.cy = uni(rng) * n;
    const bool aligned = uni(rng) < 0.75;
    const double spread = nd(rng);
    b.th = aligned ? th0 + 0.26 * spread + (uni(rng) < 0.5 ? 0.0 : M_PI) : kTwoPi * uni(rng);
    b.len = (0.04 + 0.08 * uni(rng)) * px;
    b.hw = 0.5 * (0.002 + 0.003 * uni(rng)) * px;
    b.bow = (uni(rng) - 0.5) * 0.012 * px;
    const double depth = uni(rng);
    const bool dry = uni(rng) < 0.15;  // dry, greyer blades are lighter
    b.bright = 55.0 + 110.0 * depth + 12.0 * nd(rng) + (dry ? 40.0 : 0.0);
    blades.emplace_back(depth, b);
  }
  std::sort(blades.begin(), blades.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& db : blades) {
    const Blade& b = db.second;
    const double c = std::cos(b.th), s = std::sin(b.th), half = 0.5 * b.len;
    forEachInRect(&img, n, b.cx, b.cy, c, s, -half - 1.0, half + 1.0, std::min(0.0, b.bow) - b.hw - 1.0,
                  std::max(0.0, b.bow) + b.hw + 1.0, [&](float& p, double u, double v) {
                    const double t = u / half;                       // -1 base .. 1 tip
                    const double w = b.hw * std::min(1.0, (1.0 - t) / 0.6);  // tapers over the last 30 %
                    const double off = std::abs(v - b.bow * t * t);  // distance from the bent midline
                    const float cov = std::min(smoothEdge(half - std::abs(u)), smoothEdge(w - off));
                    if (cov <= 0.f) return;
                    const double rel = off / std::max(w, 0.5);
                    const double shade = (0.85 + 0.15 * (t + 1.0)) * (rel < 0.35 ? 1.08 : 1.0 - 0.12 * rel);
                    p += cov * (static_cast<float>(b.bright * shade) - p);
                  });
  }
  // Patchy growth and soil moisture: slow multiplicative brightness changes.
  std::vector<float> patches(img.size(), 0.f);
  addValueNoise(&patches, n, n, cellsFor(tile_m, 0.4, n), 0.12f, &rng);
  addValueNoise(&patches, n, n, cellsFor(tile_m, 0.1, n), 0.06f, &rng);
  for (std::size_t i = 0; i < img.size(); ++i) img[i] *= 1.f + patches[i];
  normalise(&img, 105.0, 32.0, 5.0, 250.0);
  return Texture(img, n, n, texel_m, texel_m);
}

Texture Texture::leaves(std::uint64_t seed, double texel_m, int tile_px) {
  checkProceduralArgs("leaves", texel_m, tile_px);
  const int n = tile_px;
  const double tile_m = n * texel_m, px = 1.0 / texel_m;
  std::mt19937_64 rng(seed ^ 0x6c65617665000002ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);

  // Dark gaps: shadowed soil between the leaves.
  std::vector<float> img(static_cast<std::size_t>(n) * n, 0.f);
  addValueNoise(&img, n, n, cellsFor(tile_m, 0.01, n), 5.f, &rng);
  for (float& v : img) v += 30.f;

  // Leaves 3-8 cm long, width 35-60 % of the length; mean area ~ 0.75 L W; 2.2 layers on average.
  const double mean_area_m2 = 0.75 * 0.055 * 0.055 * 0.475;
  const int n_leaves = static_cast<int>(2.2 * tile_m * tile_m / mean_area_m2);
  const double shadow_dx = 0.003 * px, shadow_dy = 0.0025 * px;  // light from one side: 4 mm shadow offset
  for (int i = 0; i < n_leaves; ++i) {
    const double cx = uni(rng) * n, cy = uni(rng) * n;
    const double len = (0.03 + 0.05 * uni(rng)) * px, half = 0.5 * len;
    const double hw_max = 0.5 * len * (0.35 + 0.25 * uni(rng));
    const double th = kTwoPi * uni(rng), c = std::cos(th), s = std::sin(th);
    const double bright = 70.0 + 120.0 * uni(rng);           // wet/dark to dry/light leaves
    const double tilt_u = 0.4 * (uni(rng) - 0.5), tilt_v = 0.4 * (uni(rng) - 0.5);  // shading by leaf tilt
    const double rib = uni(rng) < 0.5 ? 0.82 : 1.15;         // darker or lighter midrib
    const double rim_px = 0.001 * px;
    // Ovate outline: half-width hw(t) = hw_max (1 - t^2)(1 - 0.25 t) / 1.03, t = u / half in [-1, 1].
    const auto inside = [&](double u, double v) {
      const double t = std::clamp(u / half, -1.0, 1.0);
      const double hw = hw_max * (1.0 - t * t) * (1.0 - 0.25 * t) / 1.03;
      return std::min(half - std::abs(u), hw - std::abs(v));
    };
    // Soft shadow on what lies below.
    const double shadow_soft = 0.0015 * px;
    forEachInRect(&img, n, cx + shadow_dx, cy + shadow_dy, c, s, -half - 2 * shadow_soft, half + 2 * shadow_soft,
                  -hw_max - 2 * shadow_soft, hw_max + 2 * shadow_soft, [&](float& p, double u, double v) {
                    const float cov = softEdge(inside(u, v), shadow_soft);
                    p *= 1.f - 0.45f * cov;
                  });
    forEachInRect(&img, n, cx, cy, c, s, -half - 1.0, half + 1.0, -hw_max - 1.0, hw_max + 1.0,
                  [&](float& p, double u, double v) {
                    const double in = inside(u, v);
                    const float cov = smoothEdge(in);
                    if (cov <= 0.f) return;
                    double shade = 1.0 + tilt_u * u / half + tilt_v * v / hw_max;
                    if (in < rim_px) shade *= 0.85;
                    if (std::abs(v) < 0.0006 * px + 0.5 && u < 0.9 * half) shade *= rib;
                    p += cov * (static_cast<float>(bright * shade) - p);
                  });
  }
  normalise(&img, 95.0, 40.0, 5.0, 250.0);
  return Texture(img, n, n, texel_m, texel_m);
}

Texture Texture::dirt(std::uint64_t seed, double texel_m, int tile_px) {
  checkProceduralArgs("dirt", texel_m, tile_px);
  const int n = tile_px;
  const double tile_m = n * texel_m, px = 1.0 / texel_m;
  std::mt19937_64 rng(seed ^ 0x6469727400000003ull);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> nd(0.0, 1.0);
  std::vector<float> img(static_cast<std::size_t>(n) * n, 0.f);

  // Moisture patches (0.3-1 m) and centimetre mottling (relative units; normalised at the end).
  addValueNoise(&img, n, n, cellsFor(tile_m, 1.0, n), 0.25f, &rng);
  addValueNoise(&img, n, n, cellsFor(tile_m, 0.3, n), 0.2f, &rng);
  addValueNoise(&img, n, n, cellsFor(tile_m, 0.03, n), 0.2f, &rng);
  addValueNoise(&img, n, n, cellsFor(tile_m, 0.012, n), 0.15f, &rng);

  const double lx = 0.6, ly = 0.8;  // direction the light comes from (tile axes)
  // Round, slightly irregular bumps with a flat offset and lit/shaded sides (dome shading).
  const auto bump = [&](double cx, double cy, double r, double offset, double shade_amp) {
    const double a1 = kTwoPi * uni(rng), a2 = kTwoPi * uni(rng);
    const double r_out = r * 1.3 + 1.0;
    forEachInRect(&img, n, cx, cy, 1.0, 0.0, -r_out, r_out, -r_out, r_out, [&](float& p, double u, double v) {
      const double rho = std::sqrt(u * u + v * v), phi = std::atan2(v, u);
      const double rr = r * (1.0 + 0.15 * std::sin(3 * phi + a1) + 0.1 * std::sin(5 * phi + a2));
      const float cov = smoothEdge(rr - rho);
      if (cov <= 0.f) return;
      const double q = std::min(1.0, rho / rr);
      const double lit = (u * lx + v * ly) / std::max(rho, 1e-9) * q;  // -1 shaded side .. 1 lit side
      p += cov * static_cast<float>(offset + shade_amp * lit);
    });
  };
  // Clods: radius 0.8-3 cm, 30 % of the area.
  const int n_clods = static_cast<int>(0.3 * tile_m * tile_m / (M_PI * 0.019 * 0.019 * 1.1));
  for (int i = 0; i < n_clods; ++i) {
    const double r = (0.008 + 0.022 * uni(rng)) * px;
    bump(uni(rng) * n, uni(rng) * n, r, 0.15 * nd(rng) + 0.05, 0.5);
  }
  // Gravel: stones of radius 1.5-5 mm, 12 % of the area, mostly lighter than the soil.
  const int n_stones = static_cast<int>(0.12 * tile_m * tile_m / (M_PI * 0.0033 * 0.0033 * 1.1));
  for (int i = 0; i < n_stones; ++i) {
    const double r = (0.0015 + 0.0035 * uni(rng)) * px;
    bump(uni(rng) * n, uni(rng) * n, r, (uni(rng) < 0.7 ? 1.0 : -1.0) * (0.3 + 0.4 * uni(rng)), 0.3);
  }
  // Fine grain (1-2 mm): white noise blurred over about 1.5 mm.
  std::vector<float> grain(img.size());
  for (float& g : grain) g = static_cast<float>(nd(rng));
  const int gr = std::max(1, static_cast<int>(std::lround(0.0007 * px)));
  std::vector<float> tmp(img.size());
  const float norm = 1.f / (2 * gr + 1);
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      float acc = 0.f;
      for (int k = -gr; k <= gr; ++k) acc += grain[static_cast<std::size_t>(y) * n + ((x + k) & (n - 1))];
      tmp[static_cast<std::size_t>(y) * n + x] = acc * norm;
    }
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      float acc = 0.f;
      for (int k = -gr; k <= gr; ++k) acc += tmp[static_cast<std::size_t>((y + k) & (n - 1)) * n + x];
      img[static_cast<std::size_t>(y) * n + x] += 0.3f * acc * norm * (2 * gr + 1);
    }
  normalise(&img, 120.0, 14.0, 5.0, 250.0);
  return Texture(img, n, n, texel_m, texel_m);
}

bool Texture::isProcedural(const std::string& name) {
  return name == "checkerboard" || name == "natural" || name == "grass" || name == "leaves" || name == "dirt";
}

Texture Texture::byName(const std::string& name, std::uint64_t seed, double square_m, double image_tile_width_m) {
  if (name == "checkerboard") return checkerboard(square_m);
  if (name == "natural") return natural(seed);
  if (name == "grass") return grass(seed);
  if (name == "leaves") return leaves(seed);
  if (name == "dirt") return dirt(seed);
  return fromImage(name, image_tile_width_m);
}

Texture Texture::fromImage(const std::string& path, double tile_width_m) {
  if (!(tile_width_m > 0.0)) throw std::invalid_argument("texture size must be > 0 m");
  cv::Mat im = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (im.empty()) throw std::runtime_error("cannot read texture image '" + path + "'");
  const int w = nearestPow2(im.cols, 4, 4096), h = nearestPow2(im.rows, 4, 4096);
  const double tile_height_m = tile_width_m * im.rows / im.cols;
  cv::Mat r;
  cv::resize(im, r, cv::Size(w, h), 0, 0, (w < im.cols || h < im.rows) ? cv::INTER_AREA : cv::INTER_CUBIC);
  std::vector<float> px(static_cast<std::size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) px[static_cast<std::size_t>(y) * w + x] = r.at<unsigned char>(y, x);
  return Texture(px, w, h, tile_width_m / w, tile_height_m / h);
}

}  // namespace sim
}  // namespace diekf
