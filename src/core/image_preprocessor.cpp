// Image preprocessing for the photometric update (see image_preprocessor.h for the working camera).
//
// Resampling (precomputed once): every working pixel p' maps to a raw pixel c = distortedPixel(K'^-1 p').
// Its footprint in the raw image is the image of a 1x1 working pixel under that map, with extents
// F_x = |d c / d p'_row 0| and F_y = |row 1| (raw px per working px, from central differences). The pixel's
// value is a separable weighted average over the footprint whose weighted tap centroid is exactly c (up to a
// 1/16 raw px quantisation that lets pixels share weight sets):
//   weights: a Gaussian of sigma s = antialias_sigma_px x F raw px about c (default 0.4 working px), taps
//     within +-2 s (n = ceil(4 s)); with antialias_sigma_px = 0 a box of n = round(F) taps. A linear tilt
//     w_i += e (x_i - m) / sum_k (x_k - m)^2 (m = mean tap position) then moves the centroid the rest of the way
//     to c (e: what truncation left; for the box all of c - m), keeping sum w_i = 1.
//   Along x: n <= 16 CONTIGUOUS raw columns, read as one window of 8 or 16 bytes (180 px: F_x ~ 4.2, 7 taps).
//   Along y: n <= 8 rows, contiguous while n covers the footprint (7 rows at 180 px), else 8 rows spread evenly
//     over it; padded to an even count with a zero-weight row; Q14. Footprints at least 2 raw px tall in sigma
//     (at 752 raw px: working widths up to about 146 px) read ROW PAIRS instead: the raw rows summed in pairs once
//     per image (16 bit), the taps on the pairs with the Gaussian narrowed to sqrt(s^2 - 1/4) (a pair is a box
//     of two rows), so the footprint's variance and centroid are the same: at 90 px 8 contiguous pairs (16 raw
//     rows over +-2 sigma) where 8 single rows 2 raw px apart were read.
//   Why a Gaussian: texture between the working and the raw Nyquist frequencies folds to low working
//   frequencies, where the photometric update reads it as motion the wrong way (pulling the flow toward whole
//   pixels). A box passes it through its sidelobes with the sign flipped; sparse rows (2 rows 2 raw px apart,
//   as before) pass raw texture of 4 px period almost unattenuated (docs/results.md "Anti-aliasing").
// With n = 2 taps 1 px apart this is bilinear interpolation. Per frame the resampling is one pass over a table
// of (destination, base offset, column-weight set, row set), 16 bytes per working pixel. Per pixel and pair of
// rows: two 8-byte loads widened to 16 bit (row pairs: two 16-byte loads), interleaved, and one 16-bit dot
// product per 4 columns against the two rows' Q14 weights (OpenCV universal intrinsics: SSE2 / NEON / scalar
// emulation); the column weights are applied in float at the end. Footprints wider than 16 raw px (working
// images narrower than ~47 px at 752 raw px) or raw images narrower than 16 px use a scalar path with up to
// 8 x 8 taps of single rows (the same rules).
//
// Then, at working resolution: separable Gaussian blur (radius ceil(3 sigma), replicated border; the
// resampler writes into a buffer with the border columns pre-allocated), brightness normalisation (zero mean,
// unit variance; a uniform image gives zeros; sums accumulated in the vertical blur pass), and central-difference
// gradients fused with the normalisation in one pass over the rows.
#include "diekf/image_preprocessor.h"
#include "diekf/fixed_pattern.h"
#include "morphology.h"
#include "dot_gain.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <sstream>
#include <stdexcept>
#include <tuple>

#include <opencv2/core/hal/intrin.hpp>

namespace diekf {
namespace {

std::string describe(const cv::Mat& m) {
  std::ostringstream os;
  os << cv::typeToString(m.type()) << " " << m.cols << "x" << m.rows;
  return os.str();
}

// Ensures `m` is rows x cols of `type`, allocating only when it is not.
void ensure(cv::Mat& m, int rows, int cols, int type) {
  if (m.rows != rows || m.cols != cols || m.type() != type || !m.isContinuous()) m.create(rows, cols, type);
}

inline uint8_t toGray8(float v) {
  const float r = v + 0.5f;
  return static_cast<uint8_t>(r <= 0.f ? 0 : (r >= 255.f ? 255 : static_cast<int>(r)));
}

constexpr int kQ14 = 1 << 14;

// The 8 columns at `p` of a source row as 16-bit lanes: raw bytes widened, or the row pairs' sums as they are.
inline cv::v_uint16x8 loadRow8(const uint8_t* p) { return cv::v_load_expand(p); }
inline cv::v_uint16x8 loadRow8(const uint16_t* p) { return cv::v_load(p); }
// The 16 columns at `p` as two 16-bit halves.
inline void loadRow16(const uint8_t* p, cv::v_uint16x8& lo, cv::v_uint16x8& hi) {
  cv::v_expand(cv::v_load(p), lo, hi);
}
inline void loadRow16(const uint16_t* p, cv::v_uint16x8& lo, cv::v_uint16x8& hi) {
  lo = cv::v_load(p);
  hi = cv::v_load(p + 8);
}

// Fast resampling: the 4 partial sums (float lanes) of one pixel, WIN contiguous columns (8 or 16), NY rows
// (even), see the file comment. The source: raw bytes, or the raw rows summed in pairs (at most 510: the 16-bit
// products with the Q14 weights and their sums stay within 32 bits).
template <int WIN, int NY, typename Src, typename Pix, typename Cols, typename Rows>
inline cv::v_float32x4 fastPixel(const Pix& p, const Cols* cols, const Rows* rows, const Src* src) {
  using namespace cv;
  const float* cw = cols[p.cols].w;
  const Rows& rt = rows[p.rows];
  const Src* b = src + p.base;
  if constexpr (WIN == 8) {
    v_int32x4 s0 = v_setzero_s32(), s1 = v_setzero_s32();
    for (int j = 0; j < NY; j += 2) {
      const v_uint16x8 r0 = loadRow8(b + rt.off[j]);
      const v_uint16x8 r1 = loadRow8(b + rt.off[j + 1]);
      v_uint16x8 z0, z1;
      v_zip(r0, r1, z0, z1);  // (r0[c], r1[c]) pairs: columns 0-3 in z0, 4-7 in z1
      const v_int16x8 w = v_load(rt.wpair[j / 2]);
      s0 = v_dotprod(v_reinterpret_as_s16(z0), w, s0);
      s1 = v_dotprod(v_reinterpret_as_s16(z1), w, s1);
    }
    return v_muladd(v_cvt_f32(s1), v_load(cw + 4), v_cvt_f32(s0) * v_load(cw));
  } else {
    v_int32x4 s0 = v_setzero_s32(), s1 = v_setzero_s32(), s2 = v_setzero_s32(), s3 = v_setzero_s32();
    for (int j = 0; j < NY; j += 2) {
      v_uint16x8 a0, a1, c0, c1;
      loadRow16(b + rt.off[j], a0, a1);
      loadRow16(b + rt.off[j + 1], c0, c1);
      v_uint16x8 z0, z1, z2, z3;
      v_zip(a0, c0, z0, z1);
      v_zip(a1, c1, z2, z3);
      const v_int16x8 w = v_load(rt.wpair[j / 2]);
      s0 = v_dotprod(v_reinterpret_as_s16(z0), w, s0);
      s1 = v_dotprod(v_reinterpret_as_s16(z1), w, s1);
      s2 = v_dotprod(v_reinterpret_as_s16(z2), w, s2);
      s3 = v_dotprod(v_reinterpret_as_s16(z3), w, s3);
    }
    return v_muladd(v_cvt_f32(s3), v_load(cw + 12),
                    v_muladd(v_cvt_f32(s2), v_load(cw + 8),
                             v_muladd(v_cvt_f32(s1), v_load(cw + 4), v_cvt_f32(s0) * v_load(cw))));
  }
}

// Fast resampling kernel: pixels in batches of 4 (one horizontal reduction and one rounding for 4 pixels).
template <int WIN, int NY, typename Src, typename Pix, typename Cols, typename Rows>
void fastKernel(const Pix* pix, std::size_t count, const Cols* cols, const Rows* rows, const Src* src,
                float* dst, uint8_t* g8) {
  using namespace cv;
  std::size_t k = 0;
  alignas(16) float v[4];
  alignas(16) int g[4];
  const v_int32x4 lo = v_setzero_s32(), hi = v_setall_s32(255);
  for (; k + 4 <= count; k += 4) {
    const v_float32x4 sums = v_reduce_sum4(
        fastPixel<WIN, NY>(pix[k], cols, rows, src), fastPixel<WIN, NY>(pix[k + 1], cols, rows, src),
        fastPixel<WIN, NY>(pix[k + 2], cols, rows, src), fastPixel<WIN, NY>(pix[k + 3], cols, rows, src));
    v_store_aligned(v, sums);
    v_store_aligned(g, v_min(v_max(v_round(sums), lo), hi));
    for (int i = 0; i < 4; ++i) {
      dst[pix[k + i].dst] = v[i];
      g8[pix[k + i].out8] = static_cast<uint8_t>(g[i]);
    }
  }
  for (; k < count; ++k) {
    const float s = v_reduce_sum(fastPixel<WIN, NY>(pix[k], cols, rows, src));
    dst[pix[k].dst] = s;
    g8[pix[k].out8] = toGray8(s);
  }
}

template <int WIN, int NY, typename Src, typename Pix, typename Cols, typename Rows>
bool tryFast(int win, int ny, const Pix* pix, std::size_t count, const Cols* cols, const Rows* rows,
             const Src* src, float* dst, uint8_t* g8) {
  if (win != WIN || ny != NY) return false;
  fastKernel<WIN, NY>(pix, count, cols, rows, src, dst, g8);
  return true;
}

// The kernels of one window width for every even row count up to kMaxRows (8).
template <int WIN, typename Src, typename Pix, typename Cols, typename Rows>
bool tryFastRows(int win, int ny, const Pix* pix, std::size_t count, const Cols* cols, const Rows* rows,
                 const Src* src, float* dst, uint8_t* g8) {
  return tryFast<WIN, 2>(win, ny, pix, count, cols, rows, src, dst, g8) ||
         tryFast<WIN, 4>(win, ny, pix, count, cols, rows, src, dst, g8) ||
         tryFast<WIN, 6>(win, ny, pix, count, cols, rows, src, dst, g8) ||
         tryFast<WIN, 8>(win, ny, pix, count, cols, rows, src, dst, g8);
}

// Raw rows summed in pairs: out row k = rows 2k and 2k + 1, k < h / 2 (an odd last row left out), 16 bit.
void sumRowPairs(const uint8_t* src, int w, int h, uint16_t* out) {
  using namespace cv;
  for (int k = 0; k < h / 2; ++k) {
    const uint8_t* a = src + static_cast<std::size_t>(2 * k) * w;
    const uint8_t* b = a + w;
    uint16_t* o = out + static_cast<std::size_t>(k) * w;
    int x = 0;
    for (; x + 16 <= w; x += 16) {
      v_uint16x8 a0, a1, b0, b1;
      v_expand(v_load(a + x), a0, a1);
      v_expand(v_load(b + x), b0, b1);
      v_store(o + x, a0 + b0);
      v_store(o + x + 8, a1 + b1);
    }
    for (; x < w; ++x) o[x] = static_cast<uint16_t>(a[x] + b[x]);
  }
}

// Horizontal blur of one row with a symmetric kernel of radius R (compile time): in[-R .. W-1+R] readable.
template <int R>
void blurRowH(const float* in, const float* kern, int W, float* out) {
  float k[R + 1];
  for (int i = 0; i <= R; ++i) k[i] = kern[i];
  for (int x = 0; x < W; ++x) {
    float s = k[0] * in[x];
    for (int i = 1; i <= R; ++i) s += k[i] * (in[x - i] + in[x + i]);
    out[x] = s;
  }
}
void blurRowHGeneric(const float* in, const float* kern, int R, int W, float* out) {
  for (int x = 0; x < W; ++x) out[x] = kern[0] * in[x];
  for (int i = 1; i <= R; ++i) {
    const float ki = kern[i];
    for (int x = 0; x < W; ++x) out[x] += ki * (in[x - i] + in[x + i]);
  }
}

// Vertical blur of row y (rows[i] = input row y + i - R, clamped), symmetric kernel of radius R.
template <int R>
void blurRowV(const float* const* rows, const float* kern, int W, float* out) {
  float k[R + 1];
  for (int i = 0; i <= R; ++i) k[i] = kern[i];
  const float* c = rows[R];
  for (int x = 0; x < W; ++x) {
    float s = k[0] * c[x];
    for (int i = 1; i <= R; ++i) s += k[i] * (rows[R - i][x] + rows[R + i][x]);
    out[x] = s;
  }
}
void blurRowVGeneric(const float* const* rows, const float* kern, int R, int W, float* out) {
  for (int x = 0; x < W; ++x) out[x] = kern[0] * rows[R][x];
  for (int i = 1; i <= R; ++i) {
    const float ki = kern[i];
    const float* a = rows[R - i];
    const float* b = rows[R + i];
    for (int x = 0; x < W; ++x) out[x] += ki * (a[x] + b[x]);
  }
}

// Sum and sum of squares of (r[x] - pivot) over one row, in float lanes (a row is <= a few hundred values).
void rowMoments(const float* r, int W, float pivot, double* sum, double* sum_sq) {
  using namespace cv;
  const v_float32x4 vp = v_setall_f32(pivot);
  v_float32x4 s1 = v_setzero_f32(), s2 = v_setzero_f32();
  int x = 0;
  for (; x + 4 <= W; x += 4) {
    const v_float32x4 v = v_load(r + x) - vp;
    s1 += v;
    s2 = v_muladd(v, v, s2);
  }
  float t1 = v_reduce_sum(s1), t2 = v_reduce_sum(s2);
  for (; x < W; ++x) {
    const float v = r[x] - pivot;
    t1 += v;
    t2 += v * v;
  }
  *sum += t1;
  *sum_sq += t2;
}

}  // namespace

ImagePreprocessor::ImagePreprocessor(const CameraModel& camera, const PreprocessParams& params)
    : params_(params), raw_K_(camera.K) {
  const int w = raw_K_.width, h = raw_K_.height;
  if (w < 2 || h < 2 || !(raw_K_.fx > 0.0) || !(raw_K_.fy > 0.0)) {
    throw std::invalid_argument("ImagePreprocessor: camera has no valid resolution / focal length");
  }
  if (params.working_width_px < 3 || params.working_width_px > 4 * w) {
    throw std::invalid_argument("ImagePreprocessor: working_width_px = " + std::to_string(params.working_width_px) +
                                " outside [3, 4 x calibration width]");
  }
  if (params.working_height_px < 0 || params.working_height_px > 4 * h ||
      (params.working_height_px > 0 && params.working_height_px < 3)) {
    throw std::invalid_argument("ImagePreprocessor: working_height_px = " +
                                std::to_string(params.working_height_px) +
                                " outside {0} or [3, 4 x calibration height]");
  }
  if (!(params.blur_sigma_px >= 0.0) || params.blur_sigma_px > 20.0) {
    throw std::invalid_argument("ImagePreprocessor: blur_sigma_px outside [0, 20]");
  }
  if (!(params.antialias_sigma_px >= 0.0) || params.antialias_sigma_px > 2.0) {
    throw std::invalid_argument("ImagePreprocessor: antialias_sigma_px outside [0, 2]");
  }
  setDotRemoval(params.dot_removal_px);

  // ---- working camera ----
  const int W = params.working_width_px;
  const double sx = static_cast<double>(W) / w;
  int H;
  double sy;
  if (params.working_height_px > 0) {
    H = params.working_height_px;
    sy = static_cast<double>(H) / h;
  } else {
    // ceil: the working image covers the whole raw field of view (752x480 @ 90 -> 58 rows, as the paper).
    H = static_cast<int>(std::ceil(W * static_cast<double>(h) / w - 1e-9));
    sy = sx;
  }
  H = std::max(H, 3);
  working_K_.width = W;
  working_K_.height = H;
  working_K_.fx = raw_K_.fx * sx;
  working_K_.fy = raw_K_.fy * sy;
  working_K_.cx = (raw_K_.cx + 0.5) * sx - 0.5;
  working_K_.cy = (raw_K_.cy + 0.5) * sy - 0.5;

  // ---- blur kernel (symmetric: stored as kern[0..r]) ----
  if (params.blur_sigma_px > 0.0) {
    const double s = params.blur_sigma_px;
    const int r = std::max(1, static_cast<int>(std::ceil(3.0 * s)));
    blur_kernel_.resize(r + 1);
    double sum = 0.0;
    for (int i = -r; i <= r; ++i) sum += std::exp(-0.5 * i * i / (s * s));
    for (int i = 0; i <= r; ++i) blur_kernel_[i] = static_cast<float>(std::exp(-0.5 * i * i / (s * s)) / sum);
    pad_ = r;
  }

  // ---- resampling table ----
  camera_ = camera;
  buildResampling();
}

void ImagePreprocessor::setFocalScale(double focal_scale) {
  if (!(std::abs(focal_scale) < 0.5)) {
    throw std::invalid_argument("ImagePreprocessor::setFocalScale: " + std::to_string(focal_scale) +
                                " outside (-0.5, 0.5)");
  }
  if (focal_scale == focal_scale_) return;
  focal_scale_ = focal_scale;
  buildResampling();
  ++resample_id_;
  if (!fill_mask_.empty()) updateFillCoverage();
}

// The resampling table for the camera whose focal lengths are (1 + focal_scale_) x the calibration's: working
// pixel (u, v) is the ray of the working pinhole camera scaledFocal(working_K_, focal_scale_), projected with that
// camera's raw focal lengths and the calibration's distortion and principal point.
void ImagePreprocessor::buildResampling() {
  columns_.clear();
  rows_.clear();
  fast_groups_.clear();
  tapsets_.clear();
  slow_pixels_.clear();
  const int w = raw_K_.width, h = raw_K_.height;
  const int W = working_K_.width, H = working_K_.height;
  const int padded_W = W + 2 * pad_;
  const CameraModel& camera = camera_;
  const PinholeK raw_K = scaledFocal(raw_K_, focal_scale_);
  const PinholeK Kw = scaledFocal(working_K_, focal_scale_);
  auto toRaw = [&](double u, double v) {
    const Vec2 xd = camera.distort(Vec2((u - Kw.cx) / Kw.fx, (v - Kw.cy) / Kw.fy));
    return Vec2(raw_K.fx * xd.x() + raw_K.cx, raw_K.fy * xd.y() + raw_K.cy);
  };
  const int raw_stride = w;  // process() hands a continuous CV_8UC1 image to the resampler

  // Footprint (docs/noise_model.md section 2): with antialias_sigma_px > 0 a Gaussian of that sigma in working px
  // (aa F raw px for a footprint F), its taps within +-2 sigma; else a box of the working pixel's width.
  const double aa = params_.antialias_sigma_px;
  // F quantised to 1/8 raw px: pixels share weight sets (F changes slowly across the image with the distortion).
  auto quantF = [](double F) { return static_cast<int>(std::lround(std::clamp(F, 0.0, 1e4) * 8.0)); };
  // 1-D taps: n taps `step` raw px apart around centre c in an axis of `size` px, weights of the footprint
  // (Gaussian of sigma_raw, or uniform for 0). Returns the first tap's coordinate and the quantised offset dq
  // (1/16 px) of c from the taps' middle, and fills the weights (sum 1, centroid first + span/2 + dq/16: a linear
  // tilt puts it there exactly).
  auto taps1d = [](double c, int n, int step, int size, double sigma_raw, double* wts, int* dq_out) {
    while ((n - 1) * step > size - 1 && step > 1) --step;
    while ((n - 1) * step > size - 1 && n > 2) --n;
    const int span = (n - 1) * step;
    int first = static_cast<int>(std::lround(c - 0.5 * span));
    first = std::clamp(first, 0, size - 1 - span);
    const double m = first + 0.5 * span;
    double sum_sq = 0.0;
    for (int i = 0; i < n; ++i) sum_sq += (i * step - 0.5 * span) * (i * step - 0.5 * span);
    int dq = 0;
    if (n > 1 && span > 0) {
      // Largest |d| keeping every box weight >= 0 (only reached for pixels mapping outside the raw image).
      const double d_max = sum_sq / (n * 0.5 * span);
      const int dq_max = static_cast<int>(std::floor(d_max * 16.0));
      dq = std::clamp(static_cast<int>(std::lround((c - m) * 16.0)), -dq_max, dq_max);
    }
    const double d = dq / 16.0;
    double centroid = 0.0;  // of the footprint's own weights, relative to m
    for (int i = 0; i < n; ++i) {
      const double xi = i * step - 0.5 * span;
      wts[i] = sigma_raw > 0.0 ? std::exp(-0.5 * (xi - d) * (xi - d) / (sigma_raw * sigma_raw)) : 1.0;
    }
    double sum = 0.0;
    for (int i = 0; i < n; ++i) sum += wts[i];
    for (int i = 0; i < n; ++i) {
      wts[i] /= sum;
      centroid += wts[i] * (i * step - 0.5 * span);
    }
    if (span > 0) {
      sum = 0.0;
      for (int i = 0; i < n; ++i) {
        wts[i] = std::max(0.0, wts[i] + (d - centroid) * (i * step - 0.5 * span) / sum_sq);
        sum += wts[i];
      }
      for (int i = 0; i < n; ++i) wts[i] /= sum;  // 1 but where a weight was clipped (outside the raw image)
    }
    *dq_out = dq;
    return std::make_tuple(first, n, step);
  };
  // Taps of a footprint F raw px wide: a box of round(F) taps or the Gaussian's 4 sigma, contiguous up to
  // `max_taps`; wider footprints spread that many taps evenly over the extent. Returns (n, step).
  auto tapsFor = [aa](double F, int max_taps) {
    const double extent = aa > 0.0 ? 4.0 * aa * F : F;
    const int wanted = std::max(2, static_cast<int>(aa > 0.0 ? std::ceil(extent - 1e-9) : std::lround(extent)));
    const int n = std::min(wanted, max_taps);
    const int step = wanted > max_taps ? std::max(1, static_cast<int>(std::lround(extent / n))) : 1;
    return std::make_pair(n, step);
  };
  auto sigmaFor = [&](double F) { return aa * quantF(F) / 8.0; };
  // Each set is keyed by its footprint too when that is a Gaussian (its width changes across the image).
  auto footprintKey = [&](double F) { return aa > 0.0 ? quantF(F) : 0; };

  // Noise propagation (docs/noise_model.md sections 2-3), from the tables themselves: along the middle row
  // (x) and column (y), the raw-space weights of the middle working pixel after the blur (K) and every raw
  // pixel's total weight over all working pixels (T). For white raw noise of variance s^2: a working pixel has
  // the variance s^2 sum K^2, and a sum over a large area of working pixels s^2 sum T^2 (the blur moves weight
  // between working pixels but keeps its total), i.e. as much as sum T^2 / (n sum K^2) independent pixels
  // each (the correlation area).
  const int u_mid = W / 2, v_mid = H / 2;
  const int blur_r = blur_kernel_.empty() ? 0 : static_cast<int>(blur_kernel_.size()) - 1;
  auto blurWeight = [&](int offset) {
    return blur_kernel_.empty() ? 1.0 : static_cast<double>(blur_kernel_[std::abs(offset)]);
  };
  std::vector<double> K_x(w, 0.0), T_x(w, 0.0), K_y(h, 0.0), T_y(h, 0.0);
  double c_lo_x = 0.0, c_hi_x = 0.0, c_lo_y = 0.0, c_hi_y = 0.0;  // raw centres of the span's ends
  // `pairs`: the taps are row pairs (tap t: raw rows 2t and 2t + 1, half its weight each).
  auto collect = [&](bool is_x, int index, int mid, double c, int first, int n, int step, const double* wts,
                     bool pairs = false) {
    std::vector<double>& K = is_x ? K_x : K_y;
    std::vector<double>& T = is_x ? T_x : T_y;
    const int size = is_x ? W : H;
    const double kb = std::abs(index - mid) <= blur_r ? blurWeight(index - mid) : 0.0;
    for (int i = 0; i < n; ++i) {
      const int t = first + i * step;
      for (int r = 0; r < (pairs ? 2 : 1); ++r) {
        const int at = pairs ? 2 * t + r : t;
        const double wt = pairs ? 0.5 * wts[i] : wts[i];
        T[at] += wt;
        K[at] += kb * wt;
      }
    }
    if (index == mid - std::max(2, size / 16)) (is_x ? c_lo_x : c_lo_y) = c;
    if (index == mid + std::max(2, size / 16)) (is_x ? c_hi_x : c_hi_y) = c;
  };

  std::map<std::tuple<int, int, int, int>, uint16_t> col_index, row_index, set_index;
  std::map<std::pair<int, int>, std::size_t> group_of;
  auto checkCount = [](std::size_t n) {
    if (n >= 65535) throw std::logic_error("ImagePreprocessor: too many resampling weight sets");
  };
  // Sparse tap set of the generic path (x: byte offsets i*step, y: j*step*raw_stride).
  // `index`: the working pixel's column (axis 0) or row; `record`: it lies on the middle row or column.
  auto sparseSet = [&](int axis, double c, double F, int size, int index, bool record) -> std::pair<int, uint16_t> {
    const auto [n0, step0] = tapsFor(F, kMaxTaps);
    double wts[kMaxTaps];
    int dq = 0;
    const auto [first, n, step] = taps1d(c, n0, step0, size, sigmaFor(F), wts, &dq);
    if (record) collect(axis == 0, index, axis == 0 ? u_mid : v_mid, c, first, n, step, wts);
    const auto key = std::make_tuple(axis + 2 * footprintKey(F), n, step, dq);
    auto it = set_index.find(key);
    if (it == set_index.end()) {
      checkCount(tapsets_.size());
      TapSet ts;
      ts.n = n;
      for (int i = 0; i < n; ++i) {
        ts.w[i] = static_cast<float>(wts[i]);
        ts.off[i] = axis == 0 ? i * step : i * step * raw_stride;
      }
      it = set_index.emplace(key, static_cast<uint16_t>(tapsets_.size())).first;
      tapsets_.push_back(ts);
    }
    return {first, it->second};
  };

  // The tap choices (roundings of centres and footprints) must not depend on the last bits of the mapping:
  // compilers contract a * b + c into one fused multiply-add on ARM (and on x86 with -march=native) but not on
  // portable x86-64, and exact downscale factors (376 or 94 px from 752) put centres exactly on rounding ties.
  // Snapping to 1/4096 raw px makes such ties exact on every platform (test LinearRampGradients).
  auto snap = [](double x) { return std::round(x * 4096.0) / 4096.0; };
  // Row pairs: where the Gaussian footprint is many raw rows tall (sigma >= kPairRowsMinSigmaRaw at the image's
  // middle: working widths up to about 146 px from 752 raw px), the fast path reads the raw rows summed in pairs
  // and puts the footprint's taps on the pairs: each pair summed once per image instead of once per footprint that
  // covers it, and twice the rows within the same taps (90 px: 16 contiguous raw rows instead of 8 rows 2 px
  // apart). A pair is a box of two rows (variance 1/4 raw px^2), so the taps' Gaussian is narrowed to
  // sigma' = sqrt(sigma^2 - 1/4): the footprint's variance, centroid and weights' sum stay the unpaired one's
  // (docs/noise_model.md section 2). Narrower footprints keep single rows: on pairs their shape would change with
  // their centre's phase against the pairs, a pattern fixed in the image (measured at 180 px: docs/results.md).
  {
    const Vec2 dv = toRaw(u_mid, v_mid + 0.5) - toRaw(u_mid, v_mid - 0.5);
    const double Fy = std::hypot(dv.x(), dv.y());
    pair_rows_ = aa > 0.0 && w >= kMaxWindow && h >= 8 && std::isfinite(Fy) && aa * Fy >= kPairRowsMinSigmaRaw;
  }
  const int n_pairs = h / 2;
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const Vec2 c = toRaw(u, v).unaryExpr(snap);
      const Vec2 du = toRaw(u + 0.5, v) - toRaw(u - 0.5, v);  // raw displacement per working px along x
      const Vec2 dv = toRaw(u, v + 0.5) - toRaw(u, v - 0.5);
      double Fx = snap(std::hypot(du.x(), dv.x()));
      double Fy = snap(std::hypot(du.y(), dv.y()));
      if (!std::isfinite(Fx)) Fx = 1.0;
      if (!std::isfinite(Fy)) Fy = 1.0;
      const double cxr = std::clamp(std::isfinite(c.x()) ? c.x() : 0.0, -1e6, 1e6);
      const double cyr = std::clamp(std::isfinite(c.y()) ? c.y() : 0.0, -1e6, 1e6);
      const int dst = v * padded_W + pad_ + u;
      const int out8 = v * W + u;

      if (w < kMaxWindow || Fx > kMaxWindow) {
        const auto tx = sparseSet(0, cxr, Fx, w, u, v == v_mid);
        const auto ty = sparseSet(1, cyr, Fy, h, v, u == u_mid);
        SlowPixel p;
        p.dst = dst;
        p.out8 = out8;
        p.base = ty.first * raw_stride + tx.first;
        p.tx = tx.second;
        p.ty = ty.second;
        slow_pixels_.push_back(p);
        continue;
      }

      // Columns: the footprint's contiguous taps inside an 8- or 16-byte window.
      double wx[kMaxWindow];
      int dqx = 0;
      const int nx_wanted = tapsFor(Fx, kMaxWindow).first;
      const auto [first_x, nx, step_x] = taps1d(cxr, nx_wanted, 1, w, sigmaFor(Fx), wx, &dqx);
      (void)step_x;
      if (v == v_mid) collect(true, u, u_mid, cxr, first_x, nx, 1, wx);
      const int window = nx <= 8 ? 8 : 16;
      const int win_start = std::min(first_x, w - window);
      const int lane = first_x - win_start;
      const auto ckey = std::make_tuple(window + 32 * footprintKey(Fx), nx, lane, dqx);
      auto cit = col_index.find(ckey);
      if (cit == col_index.end()) {
        checkCount(columns_.size());
        ColumnWeights cw;
        // (Row pairs are sums of two rows: half the weight.)
        for (int i = 0; i < nx; ++i) cw.w[lane + i] = static_cast<float>(wx[i] / (pair_rows_ ? 2 * kQ14 : kQ14));
        cit = col_index.emplace(ckey, static_cast<uint16_t>(columns_.size())).first;
        columns_.push_back(cw);
      }

      // Rows: the same footprint (contiguous up to kMaxRows, evenly spread beyond), even count, Q14 weights
      // summing exactly to 2^14.
      double wy[kMaxRows];
      int dqy = 0;
      int first_y = 0, ny = 0, step_y = 1;
      if (pair_rows_) {
        // In pair coordinates (pair k centred on raw row 2k + 1/2): centre (c - 1/2) / 2, sigma' / 2.
        const double s_raw = sigmaFor(Fy);
        const double s_pair = 0.5 * std::sqrt(std::max(s_raw * s_raw - 0.25, 0.25));
        const auto [n0, step0] = tapsFor(s_pair / aa, kMaxRows);  // the taps of a footprint of sigma s_pair
        std::tie(first_y, ny, step_y) = taps1d(0.5 * (cyr - 0.5), n0, step0, n_pairs, s_pair, wy, &dqy);
      } else {
        const auto [ny0, step_y0] = tapsFor(Fy, kMaxRows);
        std::tie(first_y, ny, step_y) = taps1d(cyr, ny0, step_y0, h, sigmaFor(Fy), wy, &dqy);
      }
      if (u == u_mid) collect(false, v, v_mid, cyr, first_y, ny, step_y, wy, pair_rows_);
      const int ny_even = (ny + 1) / 2 * 2;
      const auto rkey = std::make_tuple(ny, step_y, dqy, footprintKey(Fy));
      auto rit = row_index.find(rkey);
      if (rit == row_index.end()) {
        checkCount(rows_.size());
        RowTaps rt;
        rt.n = ny_even;
        int q[kMaxRows] = {};
        int q_sum = 0, largest = 0;
        for (int j = 0; j < ny; ++j) {
          q[j] = static_cast<int>(std::lround(wy[j] * kQ14));
          q_sum += q[j];
          if (q[j] > q[largest]) largest = j;
        }
        q[largest] += kQ14 - q_sum;
        for (int j = 0; j < ny_even; ++j) rt.off[j] = std::min(j, ny - 1) * step_y * raw_stride;
        for (int k = 0; k < ny_even / 2; ++k) {
          for (int l = 0; l < 4; ++l) {
            rt.wpair[k][2 * l] = static_cast<int16_t>(q[2 * k]);
            rt.wpair[k][2 * l + 1] = static_cast<int16_t>(q[2 * k + 1]);
          }
        }
        rit = row_index.emplace(rkey, static_cast<uint16_t>(rows_.size())).first;
        rows_.push_back(rt);
      }

      FastPixel p;
      p.dst = dst;
      p.out8 = out8;
      p.base = first_y * raw_stride + win_start;
      p.cols = cit->second;
      p.rows = rit->second;
      const std::pair<int, int> gkey(window, ny_even);
      auto git = group_of.find(gkey);
      if (git == group_of.end()) {
        git = group_of.emplace(gkey, fast_groups_.size()).first;
        fast_groups_.push_back(FastGroup{window, ny_even, {}});
      }
      fast_groups_[git->second].pixels.push_back(p);
    }
  }

  // Noise propagation, per axis (the footprint and the blur are separable): the middle pixel's sum K^2, and
  // the large-area sum's sum T^2 per working pixel over the raw span around it (+-W/16 working px: the
  // distortion changes the footprint across the image).
  auto axisFigures = [](const std::vector<double>& K, const std::vector<double>& T, double c_lo, double c_hi,
                        int n_work) {
    double k2 = 0.0, t2 = 0.0;
    for (double k : K) k2 += k * k;
    const int lo = static_cast<int>(std::ceil(std::min(c_lo, c_hi)));
    const int hi = static_cast<int>(std::floor(std::max(c_lo, c_hi)));
    for (int i = std::max(lo, 0); i <= std::min(hi, static_cast<int>(T.size()) - 1); ++i) t2 += T[i] * T[i];
    // Mean T^2 per raw pixel times the raw pixels per working pixel (the span between the centres is n_work
    // working pixels), over sum K^2.
    const double span = std::abs(c_hi - c_lo);
    const double area = k2 > 0.0 && hi > lo ? t2 / (hi - lo + 1.0) * (span / n_work) / k2 : 1.0;
    return std::make_pair(k2, area);
  };
  const auto [kx2, area_x] = axisFigures(K_x, T_x, c_lo_x, c_hi_x, 2 * std::max(2, W / 16));
  const auto [ky2, area_y] = axisFigures(K_y, T_y, c_lo_y, c_hi_y, 2 * std::max(2, H / 16));
  noise_variance_gain_ = kx2 * ky2;
  noise_correlation_area_px_ = std::max(1.0, area_x * area_y);
}

void ImagePreprocessor::resampleTable(const uint8_t* src, float* dst, uint8_t* g8) {
  const uint16_t* pairs = nullptr;
  if (pair_rows_ && !fast_groups_.empty()) {
    const int w = raw_K_.width, h = raw_K_.height;
    ensure(row_pairs_, h / 2, w, CV_16UC1);  // allocates once
    sumRowPairs(src, w, h, row_pairs_.ptr<uint16_t>());
    pairs = row_pairs_.ptr<uint16_t>();
  }
  for (const FastGroup& g : fast_groups_) {
    const FastPixel* pix = g.pixels.data();
    const std::size_t n = g.pixels.size();
    const ColumnWeights* cols = columns_.data();
    const RowTaps* rows = rows_.data();
    const auto run = [&](const auto* source) {
      return tryFastRows<8>(g.window, g.rows, pix, n, cols, rows, source, dst, g8) ||
             tryFastRows<16>(g.window, g.rows, pix, n, cols, rows, source, dst, g8);
    };
    const bool done = pairs != nullptr ? run(pairs) : run(src);
    if (!done) throw std::logic_error("ImagePreprocessor: resampling group outside the fast kernels");
  }
  for (const SlowPixel& p : slow_pixels_) {
    const TapSet& tx = tapsets_[p.tx];
    const TapSet& ty = tapsets_[p.ty];
    const uint8_t* b = src + p.base;
    float acc = 0.f;
    for (int j = 0; j < ty.n; ++j) {
      const uint8_t* row = b + ty.off[j];
      float s = 0.f;
      for (int i = 0; i < tx.n; ++i) s += tx.w[i] * static_cast<float>(row[tx.off[i]]);
      acc += ty.w[j] * s;
    }
    dst[p.dst] = acc;
    g8[p.out8] = toGray8(acc);
  }
}

void ImagePreprocessor::process(const cv::Mat& raw, double t_s, PreprocessedFrame* out, FixedPattern* pattern) {
  if (out == nullptr) throw std::invalid_argument("ImagePreprocessor::process: null output frame");
  resample(raw, &stage_);
  finish(&stage_, t_s, out, pattern);
}

bool ImagePreprocessor::validDotRemovalPx(int px) { return px >= 0 && px <= 31 && (px == 0 || px % 2 == 1); }

void ImagePreprocessor::setDotRemoval(int px) {
  if (!validDotRemovalPx(px)) {
    throw std::invalid_argument("ImagePreprocessor: dot_removal_px = " + std::to_string(px) +
                                " is not 0 or odd in [1, 31]");
  }
  dot_removal_px_ = px > 1 ? px : 0;  // (an opening over 1 px changes nothing)
}

void ImagePreprocessor::setDotGain(const cv::Mat& inv_gain_q12) {
  if (inv_gain_q12.empty()) {
    if (!dot_gain_.empty()) ++fill_id_;
    dot_gain_.release();
    dot_gain_share_ = 0.0;
    return;
  }
  if (inv_gain_q12.type() != CV_16UC1 || inv_gain_q12.cols != raw_K_.width || inv_gain_q12.rows != raw_K_.height) {
    throw std::invalid_argument("ImagePreprocessor::setDotGain: expected a CV_16UC1 " + std::to_string(raw_K_.width) +
                                "x" + std::to_string(raw_K_.height) + " table, got " + describe(inv_gain_q12));
  }
  dot_gain_ = inv_gain_q12.clone();  // (continuous)
  dot_gain_share_ = static_cast<double>(cv::countNonZero(dot_gain_ != 4096)) / static_cast<double>(dot_gain_.total());
  ++fill_id_;
}

void ImagePreprocessor::setDotFill(const cv::Mat& mask) {
  fill_.clear();
  dot_fill_share_ = 0.0;
  dot_fill_coverage_.release();
  fill_mask_.release();
  if (mask.empty()) return;
  const int w = raw_K_.width, h = raw_K_.height;
  if (mask.type() != CV_8UC1 || mask.cols != w || mask.rows != h) {
    throw std::invalid_argument("ImagePreprocessor::setDotFill: expected a CV_8UC1 " + std::to_string(w) + "x" +
                                std::to_string(h) + " mask, got " + describe(mask));
  }
  constexpr int kDx[4] = {1, -1, 0, 0}, kDy[4] = {0, 0, 1, -1};
  size_t lit = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (mask.at<uint8_t>(y, x) == 0) continue;
      ++lit;
      FillPixel f;
      f.at = y * w + x;
      double sum = 0.0;
      double wt[4] = {};
      for (int d = 0; d < 4; ++d) {
        f.tap[d] = f.at;
        for (int k = 1; k <= kMaxFillReachPx; ++k) {
          const int xx = x + k * kDx[d], yy = y + k * kDy[d];
          if (xx < 0 || yy < 0 || xx >= w || yy >= h) break;
          if (mask.at<uint8_t>(yy, xx) == 0) {
            f.tap[d] = yy * w + xx;
            wt[d] = 1.0 / k;
            sum += wt[d];
            break;
          }
        }
      }
      if (sum == 0.0) continue;  // nothing within reach: the pixel keeps its value
      int q_sum = 0, largest = 0;
      for (int d = 0; d < 4; ++d) {
        f.w[d] = static_cast<int32_t>(std::lround(wt[d] / sum * (1 << 15)));
        q_sum += f.w[d];
        if (f.w[d] > f.w[largest]) largest = d;
      }
      f.w[largest] += (1 << 15) - q_sum;
      fill_.push_back(f);
    }
  }
  dot_fill_share_ = static_cast<double>(lit) / (static_cast<double>(w) * h);
  ++fill_id_;
  fill_mask_ = (mask != 0) / 255;
  updateFillCoverage();
}

void ImagePreprocessor::updateFillCoverage() {
  // The footprints' share on the mask: the mask as 0 / 1 (contiguous) through the resampling table, whose weights
  // sum to 1.
  const cv::Mat& m8 = fill_mask_;
  const int W = working_K_.width, H = working_K_.height, PW = W + 2 * pad_;
  cv::Mat padded(H, PW, CV_32FC1, cv::Scalar(0.f)), g8(H, W, CV_8UC1);
  resampleTable(m8.ptr<uint8_t>(), padded.ptr<float>(), g8.ptr<uint8_t>());
  dot_fill_coverage_.create(H, W, CV_32FC1);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      dot_fill_coverage_.at<float>(y, x) = std::clamp(padded.at<float>(y, pad_ + x), 0.0f, 1.0f);
}

void ImagePreprocessor::resample(const cv::Mat& raw, ResampledImage* stage) {
  if (stage == nullptr) throw std::invalid_argument("ImagePreprocessor::resample: null stage");
  if (raw.type() != CV_8UC1 || raw.cols != raw_K_.width || raw.rows != raw_K_.height || raw.dims != 2) {
    throw std::invalid_argument("ImagePreprocessor::resample: expected CV_8UC1 " + std::to_string(raw_K_.width) +
                                "x" + std::to_string(raw_K_.height) + " (calibration resolution), got " +
                                describe(raw));
  }
  const uint8_t* src = raw.data;
  if (!raw.isContinuous()) {
    ensure(raw_copy_, raw.rows, raw.cols, CV_8UC1);
    raw.copyTo(raw_copy_);
    src = raw_copy_.data;
  }
  if (!fill_.empty() || !dot_gain_.empty()) {
    // The pixels an IR projector's dots light, divided by their learned gain (setDotGain) and filled from the
    // ground around them (setDotFill).
    ensure(dots_removed_, raw.rows, raw.cols, CV_8UC1);
    uint8_t* out = dots_removed_.data;
    const size_t n = static_cast<size_t>(raw.cols) * static_cast<size_t>(raw.rows);
    if (!dot_gain_.empty()) {
      internal::divideByGain(src, reinterpret_cast<const uint16_t*>(dot_gain_.data), n, out);
    } else {
      // Row by row: short copies move the bytes with vector instructions (one long copy becomes a string move,
      // which instruction counts weigh by the byte).
      const size_t row_bytes = static_cast<size_t>(raw.cols);
      for (int y = 0; y < raw.rows; ++y) std::memcpy(out + y * row_bytes, src + y * row_bytes, row_bytes);
    }
    for (const FillPixel& f : fill_) {
      // Q15 weights summing to 2^15: at most 255, rounded. (The taps lie outside the mask: never filled.)
      const int32_t v = f.w[0] * out[f.tap[0]] + f.w[1] * out[f.tap[1]] + f.w[2] * out[f.tap[2]] +
                        f.w[3] * out[f.tap[3]];
      out[f.at] = static_cast<uint8_t>((v + (1 << 14)) >> 15);
    }
    src = out;
  } else if (dot_removal_px_ > 1) {
    // Bright specks smaller than the element (an IR projector's dots) removed by a grey-scale opening: a
    // translation-equivariant filter, so the ground's image still moves as the warp says.
    ensure(dots_removed_, raw.rows, raw.cols, CV_8UC1);
    ensure(dots_scratch_, 2 * raw.rows, raw.cols, CV_8UC1);
    internal::openSquare(src, dots_removed_.data, dots_scratch_.data, dots_scratch_.ptr<uint8_t>(raw.rows), raw.cols, raw.rows,
               dot_removal_px_ / 2);
    src = dots_removed_.data;
  }
  const int W = working_K_.width, H = working_K_.height;
  const int PW = W + 2 * pad_;
  ensure(stage->padded, H, PW, CV_32FC1);
  ensure(stage->gray8, H, W, CV_8UC1);

  // 1. Anti-aliased resampling through the lookup table into the padded buffer; replicate the border columns.
  float* res = stage->padded.ptr<float>();
  resampleTable(src, res, stage->gray8.ptr<uint8_t>());
  if (pad_ > 0) {
    for (int y = 0; y < H; ++y) {
      float* r = res + y * PW;
      std::fill(r, r + pad_, r[pad_]);
      std::fill(r + pad_ + W, r + PW, r[pad_ + W - 1]);
    }
  }
  stage->dot_removal_px = dot_removal_px_;
  stage->dot_fill_id = dotFillId();
  stage->resample_id = resample_id_;
  stage->valid = true;
}

void ImagePreprocessor::finish(ResampledImage* stage, double t_s, PreprocessedFrame* out, FixedPattern* pattern) {
  if (out == nullptr || stage == nullptr) throw std::invalid_argument("ImagePreprocessor::finish: null argument");
  if (!stage->valid) throw std::invalid_argument("ImagePreprocessor::finish: no resampled image (resample() first)");
  const int W = working_K_.width, H = working_K_.height;
  const int PW = W + 2 * pad_;
  ensure(out->gray8, H, W, CV_8UC1);
  ensure(out->intensity, H, W, CV_32FC1);
  ensure(out->grad_x, H, W, CV_32FC1);
  ensure(out->grad_y, H, W, CV_32FC1);
  stage->gray8.copyTo(out->gray8);  // W x H bytes, into the frame's own buffer
  stage->valid = false;
  const float* res = stage->padded.ptr<float>();

  // 2. Separable Gaussian blur -> intensity (grey levels), with the moments for the normalisation.
  float* I = out->intensity.ptr<float>();
  // Moments of I - pivot, the pivot a value of the first row (limits cancellation in the float variance;
  // a uniform image gives exactly zero).
  float pivot = 0.f;
  double sum = 0.0, sum_sq = 0.0;
  if (blur_kernel_.empty()) {
    for (int y = 0; y < H; ++y) {
      std::copy(res + y * PW + pad_, res + y * PW + pad_ + W, I + y * W);
      if (y == 0) pivot = I[W / 2];
      if (pattern == nullptr) rowMoments(I + y * W, W, pivot, &sum, &sum_sq);
    }
  } else {
    ensure(blur_tmp_, H, W, CV_32FC1);
    const int r = pad_;
    const float* kern = blur_kernel_.data();
    float* tmp = blur_tmp_.ptr<float>();
    for (int y = 0; y < H; ++y) {
      const float* in = res + y * PW + r;
      float* o = tmp + y * W;
      switch (r) {
        case 1: blurRowH<1>(in, kern, W, o); break;
        case 2: blurRowH<2>(in, kern, W, o); break;
        case 3: blurRowH<3>(in, kern, W, o); break;
        case 4: blurRowH<4>(in, kern, W, o); break;
        default: blurRowHGeneric(in, kern, r, W, o); break;
      }
    }
    constexpr int kMaxRadius = 60;  // blur_sigma_px <= 20
    const float* rows[2 * kMaxRadius + 1];
    for (int y = 0; y < H; ++y) {
      for (int i = -r; i <= r; ++i) rows[i + r] = tmp + std::clamp(y + i, 0, H - 1) * W;
      float* o = I + y * W;
      switch (r) {
        case 1: blurRowV<1>(rows, kern, W, o); break;
        case 2: blurRowV<2>(rows, kern, W, o); break;
        case 3: blurRowV<3>(rows, kern, W, o); break;
        case 4: blurRowV<4>(rows, kern, W, o); break;
        default: blurRowVGeneric(rows, kern, r, W, o); break;
      }
      if (y == 0) pivot = o[W / 2];
      if (pattern == nullptr) rowMoments(o, W, pivot, &sum, &sum_sq);  // (else FixedPattern::apply takes them)
    }
  }

  // 2b. The camera-fixed pattern (docs/noise_model.md section 11), on the blurred image in grey levels; the
  //     moments are those of the corrected image.
  if (pattern != nullptr) {
    pivot = 0.f;
    pattern->apply(I, &sum, &sum_sq);
  }

  normalizeAndGradients(sum, sum_sq, pivot, out);
  out->t_s = t_s;
  out->dot_removal_px = stage->dot_removal_px;
  out->dot_fill_id = stage->dot_fill_id;
  out->resample_id = stage->resample_id;
  out->valid = true;
}

void ImagePreprocessor::normalizeAndGradients(double sum, double sum_sq, float pivot, PreprocessedFrame* out) const {
  // 3. Brightness normalisation, fused with 4. the central-difference gradients (0 on the 1-pixel border):
  //    row y+1 is normalised just before the gradients of row y read it.
  float scale = 1.f / 255.f, offset = 0.f;
  const int W = working_K_.width, H = working_K_.height;
  float* I = out->intensity.ptr<float>();
  if (params_.normalize_brightness) {
    const int N = W * H;
    const double mean_c = sum / N;  // mean of I - pivot
    const double var = std::max(0.0, sum_sq / N - mean_c * mean_c);
    const double mean = mean_c + pivot;
    // Below 1e-3 grey levels of standard deviation the image is uniform: output zeros (no division by ~0).
    const double sd = std::sqrt(var);
    scale = sd > 1e-3 ? static_cast<float>(1.0 / sd) : 0.f;
    offset = static_cast<float>(-mean) * scale;
    out->grey_per_unit = sd > 1e-3 ? sd : 0.0;
    out->level_offset = sd > 1e-3 ? mean / sd : 0.0;
  } else {
    out->grey_per_unit = 255.0;
    out->level_offset = 0.0;
  }
  auto normalizeRow = [&](int y) {
    float* r = I + y * W;
    for (int x = 0; x < W; ++x) r[x] = r[x] * scale + offset;
  };
  float* gx = out->grad_x.ptr<float>();
  float* gy = out->grad_y.ptr<float>();
  normalizeRow(0);
  normalizeRow(1);
  std::fill(gx, gx + W, 0.f);
  std::fill(gy, gy + W, 0.f);
  for (int y = 1; y < H - 1; ++y) {
    normalizeRow(y + 1);
    const float* r = I + y * W;
    const float* up = r - W;
    const float* dn = r + W;
    float* ox = gx + y * W;
    float* oy = gy + y * W;
    ox[0] = oy[0] = ox[W - 1] = oy[W - 1] = 0.f;
    for (int x = 1; x < W - 1; ++x) {
      ox[x] = 0.5f * (r[x + 1] - r[x - 1]);
      oy[x] = 0.5f * (dn[x] - up[x]);
    }
  }
  std::fill(gx + (H - 1) * W, gx + H * W, 0.f);
  std::fill(gy + (H - 1) * W, gy + H * W, 0.f);
}

void ImagePreprocessor::reapplyPattern(FixedPattern* pattern, PreprocessedFrame* frame) const {
  if (pattern == nullptr || frame == nullptr || !frame->valid) return;
  double sum = 0.0, sum_sq = 0.0;
  if (!pattern->reapply(frame->intensity.ptr<float>(), &sum, &sum_sq)) return;
  normalizeAndGradients(sum, sum_sq, 0.f, frame);
}

}  // namespace diekf
