// Tiled ground textures with a box-filtered mip pyramid, sampled trilinearly by the pixel footprint.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace diekf {
namespace sim {

/// A periodic (tiled) grey texture on the plane. Level-0 texel (i, j) covers
/// u in [i su, (i+1) su), v in [j sv, (j+1) sv) (metres, plane coordinates); its value applies at its centre.
/// Tile width and height are powers of two so wrapping is a bit mask. Levels are stored in 4x4 blocks
/// of texel quads: each entry packs texels (x, y), (x+1, y), (x, y+1), (x+1, y+1) as 8.8 fixed point, so a
/// bilinear lookup is one 8-byte load, and the blocks keep lookups along any image direction cache friendly.
class Texture {
 public:
  /// Builds the pyramid from a level-0 image (row-major, `width` x `height`, powers of two, grey 0..255).
  Texture(const std::vector<float>& level0, int width, int height, double texel_u_m, double texel_v_m);

  /// Procedural checkerboard: squares of `square_m`, dark/bright grey levels, `texels_per_square` (power of 2).
  /// The pattern repeats every 2 squares, so the default tile is 2 x 2 squares (small, cache resident).
  static Texture checkerboard(double square_m = 0.05, int squares_per_tile = 2, int texels_per_square = 64,
                              float dark = 40.f, float bright = 200.f);
  /// Procedural vegetation-like texture (multi-octave noise, dirt, leaf blobs, grass blades), seedable.
  /// Moderate contrast: mean 110, standard deviation 30 grey levels. `tile_px` a power of two.
  static Texture natural(std::uint64_t seed, double texel_m = 0.002, int tile_px = 2048);
  /// Procedural grass seen from above: dense thin blades (4-12 cm long, 2-5 mm wide, tapered, slightly bent),
  /// 75 % of them within about 15 deg of `direction_deg` (from the tile's u axis), painted over each other from
  /// the shadowed bottom of the sward (dark) to the top (light), over a dark gap layer; patchy large-scale
  /// brightness (40 cm and 10 cm). Normalised to mean 105, standard deviation 32 grey levels at 1 mm.
  /// Physically scaled (sizes in metres; `texel_m` only sets the sampling), deterministic per seed.
  static Texture grass(std::uint64_t seed, double texel_m = 0.001, int tile_px = 4096, double direction_deg = 30.0);
  /// Procedural leaf litter / ground cover: overlapping ovate leaves 3-8 cm long (width 35-60 % of the length,
  /// random orientation and brightness), each shaded by its tilt, with a darker rim and a midrib, casting a soft
  /// shadow (4 mm offset) on what lies below; dark gaps between. Mean 95, standard deviation 40 at 1 mm.
  static Texture leaves(std::uint64_t seed, double texel_m = 0.001, int tile_px = 4096);
  /// Procedural bare soil: low contrast. Fine grain (1-2 mm), gravel (3-10 mm stones), clods (1.6-6 cm, lit
  /// from one side), centimetre mottling and large-scale (0.3-1 m) moisture patches. Mean 120, standard
  /// deviation 14 grey levels at 1 mm (RMS contrast 0.12 against 0.67 for the checkerboard).
  static Texture dirt(std::uint64_t seed, double texel_m = 0.001, int tile_px = 4096);
  /// The names `byName` builds procedurally: checkerboard, natural, grass, leaves, dirt.
  static bool isProcedural(const std::string& name);
  /// A procedural texture by name (seeded; `square_m` for the checkerboard), else an image file whose tile is
  /// `image_tile_width_m` wide.
  static Texture byName(const std::string& name, std::uint64_t seed, double square_m, double image_tile_width_m);
  /// Any image file (read as grey), resampled to power-of-two dimensions, tile width `tile_width_m` metres.
  /// Throws std::runtime_error naming the file when it cannot be read.
  static Texture fromImage(const std::string& path, double tile_width_m);

  /// Trilinear sample at plane coordinates (u, v) in metres for a pixel footprint `footprint_m` (metres).
  inline float sample(double u_m, double v_m, float footprint_m) const;
  /// Fast path: trilinear sample at level-0 texel coordinates (xt = u / texelU, yt = v / texelV; texel i's
  /// centre at i + 0.5) and level of detail `lod` = log2(footprint / texel size).
  inline float sampleTexel(float xt, float yt, float lod) const;

  int levels() const { return static_cast<int>(levels_.size()); }
  int width(int level = 0) const { return levels_[level].w; }
  int height(int level = 0) const { return levels_[level].h; }
  /// Texel (x, y) of a level (indices wrap).
  float at(int level, int x, int y) const;
  double texelU() const { return texel_u_m_; }
  double texelV() const { return texel_v_m_; }
  double tileU() const { return texel_u_m_ * levels_[0].w; }  ///< tile period along u (m)
  double tileV() const { return texel_v_m_ * levels_[0].h; }  ///< tile period along v (m)
  float mean() const { return mean_; }
  float invTexelGeo() const { return inv_texel_geo_m_; }  ///< 1 / sqrt(texelU texelV) (1/m)

 private:
  struct Level {
    int w = 0, h = 0;        // logical size (texels)
    int W = 0, H = 0;        // stored size: max(w, 4) x max(h, 4), periodic replication of small levels
    int blocks_per_row = 0;  // W / 4
    float sx = 1.f, sy = 1.f;  // level-0 texel coordinates -> this level's
    std::vector<std::uint64_t> quads;  // 4x4 blocks of packed 2x2 texel quads (8.8 fixed point each)
  };
  static inline std::size_t blockIndex(const Level& L, int x, int y) {
    return (static_cast<std::size_t>((y >> 2) * L.blocks_per_row + (x >> 2)) << 4) | ((y & 3) << 2) | (x & 3);
  }
  inline float bilinearTexel(const Level& L, float xt, float yt) const;
  static Level makeLevel(const std::vector<float>& linear, int w, int h, float sx, float sy);

  std::vector<Level> levels_;
  double texel_u_m_ = 0.0, texel_v_m_ = 0.0;
  float inv_texel_geo_m_ = 0.f;  // 1 / sqrt(su sv)
  float mean_ = 0.f;
};

/// Fast log2 for positive floats (about 0.01 accuracy), used to pick mip levels.
inline float fastLog2(float x) {
  union {
    float f;
    std::uint32_t i;
  } v{x};
  const float e = static_cast<float>(static_cast<int>((v.i >> 23) & 255) - 128);
  v.i = (v.i & 0x007FFFFF) | 0x3F800000;  // mantissa in [1, 2)
  const float m = v.f;
  return e + (-0.34484843f * m + 2.02466578f) * m - 0.67487759f;  // ~ 1 + log2(m) on [1, 2)
}

inline float Texture::bilinearTexel(const Level& L, float xt, float yt) const {
  float x = xt * L.sx - 0.5f, y = yt * L.sy - 0.5f;
  x = x < -1e9f ? -1e9f : (x > 1e9f ? 1e9f : x);
  y = y < -1e9f ? -1e9f : (y > 1e9f ? 1e9f : y);
  int ix = static_cast<int>(x), iy = static_cast<int>(y);
  ix -= (x < static_cast<float>(ix));  // floor
  iy -= (y < static_cast<float>(iy));
  const float fx = x - static_cast<float>(ix), fy = y - static_cast<float>(iy);
  const int x0 = ix & (L.W - 1), y0 = iy & (L.H - 1);
  const std::uint64_t q = L.quads[blockIndex(L, x0, y0)];
  const float a00 = static_cast<float>(q & 0xFFFF), a10 = static_cast<float>((q >> 16) & 0xFFFF);
  const float a01 = static_cast<float>((q >> 32) & 0xFFFF), a11 = static_cast<float>(q >> 48);
  const float a = a00 + fx * (a10 - a00);
  const float b = a01 + fx * (a11 - a01);
  return (a + fy * (b - a)) * (1.0f / 256.0f);
}

inline float Texture::sampleTexel(float xt, float yt, float lod) const {
  if (!(lod > 0.f)) return bilinearTexel(levels_[0], xt, yt);
  const int top = static_cast<int>(levels_.size()) - 1;
  if (lod >= static_cast<float>(top)) return bilinearTexel(levels_[top], xt, yt);
  const int l0 = static_cast<int>(lod);
  const float f = lod - static_cast<float>(l0);
  const float a = bilinearTexel(levels_[l0], xt, yt);
  if (f < 1.f / 64.f) return a;
  const float b = bilinearTexel(levels_[l0 + 1], xt, yt);
  return a + f * (b - a);
}

inline float Texture::sample(double u_m, double v_m, float footprint_m) const {
  const float xt = static_cast<float>(std::fmod(u_m, tileU()) / texel_u_m_);
  const float yt = static_cast<float>(std::fmod(v_m, tileV()) / texel_v_m_);
  return sampleTexel(xt, yt, footprint_m > 0.f ? fastLog2(footprint_m * inv_texel_geo_m_) : 0.f);
}

}  // namespace sim
}  // namespace diekf
