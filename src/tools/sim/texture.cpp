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
