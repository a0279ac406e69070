// Image preprocessing for the photometric update (see image_preprocessor.h for the working camera).
//
// Resampling (precomputed once): every working pixel p' maps to a raw pixel c = distortedPixel(K'^-1 p').
// Its footprint in the raw image is the image of a 1x1 working pixel under that map, with extents
// F_x = |d c / d p'_row 0| and F_y = |row 1| (raw px per working px, from central differences). The pixel's
// value is a separable box average over the footprint, sampled by a grid of integer raw taps:
//   n = clamp(ceil(F / 2.5), 2, 8) taps per axis, spaced step = max(1, round(F / n)) raw px
//   (752 -> 90 px: F ~ 8.4 at the centre, 4x4 taps 2 px apart),
//   weights w_i = 1/n + d (x_i - m) / sum_k (x_k - m)^2   (m = mean tap position, d = c - m),
// so the weights sum to one and the weighted tap centroid is exactly c (up to the 1/16 px quantisation of d
// that lets pixels share tap sets). With n = 2, step = 1 this is bilinear interpolation. Per frame the
// resampling is one pass over a table of (output index, base offset, x tap set, y tap set), 12 bytes per
// working pixel, grouped by tap counts so each group runs an unrolled kernel.
//
// Then, at working resolution: separable Gaussian blur (radius ceil(3 sigma), replicated border), brightness
// normalisation (zero mean, unit variance; a uniform image gives zeros), central-difference gradients.
#include "diekf/image_preprocessor.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>
#include <tuple>

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

// Resampling kernel with compile-time tap counts (unrolled, independent partial sums).
template <int NX, int NY, typename Pix, typename Set>
void resampleKernel(const Pix* pix, std::size_t count, const Set* sets, const uint8_t* src, float* dst,
                    uint8_t* g8) {
  for (std::size_t k = 0; k < count; ++k) {
    const Pix& p = pix[k];
    const Set& tx = sets[p.tx];
    const Set& ty = sets[p.ty];
    const uint8_t* b = src + p.base;
    float acc = 0.f;
    for (int j = 0; j < NY; ++j) {
      const uint8_t* row = b + ty.off[j];
      float s = 0.f;
      for (int i = 0; i < NX; ++i) s += tx.w[i] * static_cast<float>(row[tx.off[i]]);
      acc += ty.w[j] * s;
    }
    dst[p.out] = acc;
    const float r = acc + 0.5f;
    g8[p.out] = static_cast<uint8_t>(r <= 0.f ? 0 : (r >= 255.f ? 255 : static_cast<int>(r)));
  }
}

template <int NX, int NY, typename Pix, typename Set>
bool tryKernel(int nx, int ny, const Pix* pix, std::size_t count, const Set* sets, const uint8_t* src,
               float* dst, uint8_t* g8) {
  if (nx != NX || ny != NY) return false;
  resampleKernel<NX, NY>(pix, count, sets, src, dst, g8);
  return true;
}

template <int NY, typename Pix, typename Set>
bool dispatchX(int nx, int ny, const Pix* pix, std::size_t count, const Set* sets, const uint8_t* src,
               float* dst, uint8_t* g8) {
  return tryKernel<2, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<3, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<4, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<5, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<6, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<7, NY>(nx, ny, pix, count, sets, src, dst, g8) ||
         tryKernel<8, NY>(nx, ny, pix, count, sets, src, dst, g8);
}

}  // namespace

void ImagePreprocessor::resampleGroup(int nx, int ny, const PixelTaps* pix, std::size_t count,
                                      const TapSet* sets, const uint8_t* src, float* dst, uint8_t* g8) {
  const bool done = dispatchX<2>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<3>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<4>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<5>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<6>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<7>(nx, ny, pix, count, sets, src, dst, g8) ||
                    dispatchX<8>(nx, ny, pix, count, sets, src, dst, g8);
  if (!done) throw std::logic_error("ImagePreprocessor: tap count outside [2, 8]");
}

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

  // ---- resampling table ----
  const PinholeK& Kw = working_K_;
  auto toRaw = [&](double u, double v) {
    const Vec2 xd = camera.distort(Vec2((u - Kw.cx) / Kw.fx, (v - Kw.cy) / Kw.fy));
    return Vec2(raw_K_.fx * xd.x() + raw_K_.cx, raw_K_.fy * xd.y() + raw_K_.cy);
  };
  const int raw_stride = w;  // process() hands a continuous CV_8UC1 image to the resampler

  std::map<std::tuple<int, int, int, int>, uint16_t> index;  // (axis, n, step, d*16) -> tap set
  // Builds the 1-D taps for centre c (raw px), footprint F (raw px), image size `size`; returns the first
  // tap's coordinate and the tap set index.
  auto taps1d = [&](int axis, double c, double F, int size) -> std::pair<int, uint16_t> {
    int n = std::clamp(static_cast<int>(std::ceil(F / 2.5 - 1e-9)), 2, kMaxTaps);
    int step = std::max(1, static_cast<int>(std::lround(F / n)));
    while ((n - 1) * step > size - 1 && step > 1) --step;
    while ((n - 1) * step > size - 1 && n > 2) --n;
    const int span = (n - 1) * step;
    int first = static_cast<int>(std::lround(c - 0.5 * span));
    first = std::clamp(first, 0, size - 1 - span);
    const double m = first + 0.5 * span;
    double sum_sq = 0.0;
    for (int i = 0; i < n; ++i) sum_sq += (i * step - 0.5 * span) * (i * step - 0.5 * span);
    int dq = 0;
    if (n > 1) {
      // Largest |d| keeping every weight >= 0 (only reached for pixels mapping outside the raw image).
      const double d_max = sum_sq / (n * 0.5 * span);
      const int dq_max = static_cast<int>(std::floor(d_max * 16.0));
      dq = std::clamp(static_cast<int>(std::lround((c - m) * 16.0)), -dq_max, dq_max);
    }
    const auto key = std::make_tuple(axis, n, step, dq);
    auto it = index.find(key);
    if (it == index.end()) {
      if (tapsets_.size() >= 65535) throw std::logic_error("ImagePreprocessor: too many tap sets");
      TapSet ts;
      ts.n = n;
      const double d = dq / 16.0;
      for (int i = 0; i < n; ++i) {
        const double xi = i * step - 0.5 * span;
        ts.w[i] = static_cast<float>(1.0 / n + (n > 1 ? d * xi / sum_sq : 0.0));
        ts.off[i] = axis == 0 ? i * step : i * step * raw_stride;
      }
      it = index.emplace(key, static_cast<uint16_t>(tapsets_.size())).first;
      tapsets_.push_back(ts);
    }
    return {first, it->second};
  };

  std::map<std::pair<int, int>, std::size_t> group_of;
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const Vec2 c = toRaw(u, v);
      const Vec2 du = toRaw(u + 0.5, v) - toRaw(u - 0.5, v);  // raw displacement per working px along x
      const Vec2 dv = toRaw(u, v + 0.5) - toRaw(u, v - 0.5);
      const double Fx = std::hypot(du.x(), dv.x());
      const double Fy = std::hypot(du.y(), dv.y());
      const double cxr = std::isfinite(c.x()) ? c.x() : 0.0;
      const double cyr = std::isfinite(c.y()) ? c.y() : 0.0;
      const auto tx = taps1d(0, std::clamp(cxr, -1e6, 1e6), std::isfinite(Fx) ? Fx : 1.0, w);
      const auto ty = taps1d(1, std::clamp(cyr, -1e6, 1e6), std::isfinite(Fy) ? Fy : 1.0, h);
      PixelTaps p;
      p.out = v * W + u;
      p.base = ty.first * raw_stride + tx.first;
      p.tx = tx.second;
      p.ty = ty.second;
      const std::pair<int, int> key(tapsets_[p.tx].n, tapsets_[p.ty].n);
      auto it = group_of.find(key);
      if (it == group_of.end()) {
        it = group_of.emplace(key, groups_.size()).first;
        groups_.push_back(TapGroup{key.first, key.second, {}});
      }
      groups_[it->second].pixels.push_back(p);
    }
  }

  // ---- blur kernel ----
  if (params.blur_sigma_px > 0.0) {
    const double s = params.blur_sigma_px;
    const int r = std::max(1, static_cast<int>(std::ceil(3.0 * s)));
    blur_kernel_.resize(2 * r + 1);
    double sum = 0.0;
    for (int i = -r; i <= r; ++i) sum += std::exp(-0.5 * i * i / (s * s));
    for (int i = -r; i <= r; ++i) blur_kernel_[i + r] = static_cast<float>(std::exp(-0.5 * i * i / (s * s)) / sum);
  }
}

void ImagePreprocessor::process(const cv::Mat& raw, double t_s, PreprocessedFrame* out) {
  if (out == nullptr) throw std::invalid_argument("ImagePreprocessor::process: null output frame");
  if (raw.type() != CV_8UC1 || raw.cols != raw_K_.width || raw.rows != raw_K_.height || raw.dims != 2) {
    throw std::invalid_argument("ImagePreprocessor::process: expected CV_8UC1 " + std::to_string(raw_K_.width) +
                                "x" + std::to_string(raw_K_.height) + " (calibration resolution), got " +
                                describe(raw));
  }
  const uint8_t* src = raw.data;
  if (!raw.isContinuous()) {
    ensure(raw_copy_, raw.rows, raw.cols, CV_8UC1);
    raw.copyTo(raw_copy_);
    src = raw_copy_.data;
  }
  const int W = working_K_.width, H = working_K_.height;
  ensure(resampled_, H, W, CV_32FC1);
  ensure(out->gray8, H, W, CV_8UC1);
  ensure(out->intensity, H, W, CV_32FC1);
  ensure(out->grad_x, H, W, CV_32FC1);
  ensure(out->grad_y, H, W, CV_32FC1);

  // 1. Anti-aliased resampling through the lookup table, one kernel per (nx, ny) group.
  {
    float* dst = resampled_.ptr<float>();
    uint8_t* g8 = out->gray8.ptr<uint8_t>();
    for (const TapGroup& g : groups_) {
      resampleGroup(g.nx, g.ny, g.pixels.data(), g.pixels.size(), tapsets_.data(), src, dst, g8);
    }
  }

  // 2. Separable Gaussian blur with a replicated border: resampled_ -> intensity.
  float* I = out->intensity.ptr<float>();
  if (blur_kernel_.empty()) {
    std::copy(resampled_.ptr<float>(), resampled_.ptr<float>() + W * H, I);
  } else {
    ensure(blur_tmp_, H, W, CV_32FC1);
    const int r = static_cast<int>(blur_kernel_.size() / 2);
    const float* kern = blur_kernel_.data() + r;  // kern[-r..r]
    const float* in = resampled_.ptr<float>();
    float* tmp = blur_tmp_.ptr<float>();
    // Horizontal pass: interior vectorised along x, the r border columns with clamped indices.
    const int x_lo = std::min(r, W), x_hi = std::max(x_lo, W - r);
    for (int y = 0; y < H; ++y) {
      const float* rin = in + y * W;
      float* rout = tmp + y * W;
      for (int x = x_lo; x < x_hi; ++x) rout[x] = kern[-r] * rin[x - r];
      for (int i = -r + 1; i <= r; ++i) {
        const float ki = kern[i];
        const float* src_i = rin + i;
        for (int x = x_lo; x < x_hi; ++x) rout[x] += ki * src_i[x];
      }
      for (int x = 0; x < W; ++x) {
        if (x == x_lo) x = x_hi;
        if (x >= W) break;
        float s = 0.f;
        for (int i = -r; i <= r; ++i) s += kern[i] * rin[std::clamp(x + i, 0, W - 1)];
        rout[x] = s;
      }
    }
    // Vertical pass, row by row (vectorisable along x).
    for (int y = 0; y < H; ++y) {
      float* rout = I + y * W;
      const float k0 = kern[-r];
      const float* r0 = tmp + std::clamp(y - r, 0, H - 1) * W;
      for (int x = 0; x < W; ++x) rout[x] = k0 * r0[x];
      for (int i = -r + 1; i <= r; ++i) {
        const float ki = kern[i];
        const float* ri = tmp + std::clamp(y + i, 0, H - 1) * W;
        for (int x = 0; x < W; ++x) rout[x] += ki * ri[x];
      }
    }
  }

  // 3. Brightness normalisation.
  const int N = W * H;
  if (params_.normalize_brightness) {
    // Sums of (I - 128) in 8 float lanes per row (vectorisable; the pivot limits cancellation in the
    // variance), accumulated in double across rows.
    constexpr float kPivot = 128.f;
    double sum = 0.0, sum_sq = 0.0;
    for (int y = 0; y < H; ++y) {
      const float* r = I + y * W;
      float a1[8] = {}, a2[8] = {};
      int x = 0;
      for (; x + 8 <= W; x += 8) {
        for (int l = 0; l < 8; ++l) {
          const float v = r[x + l] - kPivot;
          a1[l] += v;
          a2[l] += v * v;
        }
      }
      for (; x < W; ++x) {
        const float v = r[x] - kPivot;
        a1[0] += v;
        a2[0] += v * v;
      }
      double s1 = 0.0, s2 = 0.0;
      for (int l = 0; l < 8; ++l) {
        s1 += a1[l];
        s2 += a2[l];
      }
      sum += s1;
      sum_sq += s2;
    }
    const double mean_c = sum / N;  // mean of I - kPivot
    const double var = std::max(0.0, sum_sq / N - mean_c * mean_c);
    const double mean = mean_c + kPivot;
    // Below 1e-3 grey levels of standard deviation the image is uniform: output zeros (no division by ~0).
    const double sd = std::sqrt(var);
    const float scale = sd > 1e-3 ? static_cast<float>(1.0 / sd) : 0.f;
    const float offset = static_cast<float>(-mean) * scale;
    for (int k = 0; k < N; ++k) I[k] = I[k] * scale + offset;
  } else {
    constexpr float kInv255 = 1.f / 255.f;
    for (int k = 0; k < N; ++k) I[k] *= kInv255;
  }

  // 4. Central-difference gradients, 0 on the 1-pixel border.
  float* gx = out->grad_x.ptr<float>();
  float* gy = out->grad_y.ptr<float>();
  std::fill(gx, gx + W, 0.f);
  std::fill(gy, gy + W, 0.f);
  std::fill(gx + (H - 1) * W, gx + N, 0.f);
  std::fill(gy + (H - 1) * W, gy + N, 0.f);
  for (int y = 1; y < H - 1; ++y) {
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
  out->t_s = t_s;
  out->valid = true;
}

}  // namespace diekf
