#include "diekf/photometric_update.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>

#include <Eigen/Eigenvalues>
#include <opencv2/core/hal/intrin.hpp>

#include "bspline.h"
#include "gauss_newton.h"
#include "interval_warp.h"
#include "lanes.h"

// The sweep and the preprocessing are written with OpenCV's universal intrinsics. On 32-bit ARM, NEON is optional
// (ARMv7) and Debian's / Ubuntu's armhf compilers do not enable it by default: the intrinsics then silently fall back
// to plain C++ emulation, several times slower. CMake adds -mfpu=neon-vfpv4 there (cmake/arm_neon.cmake); a build
// for an ARM core without NEON has to say so (-DDIEKF_ARM_NEON=OFF defines DIEKF_ALLOW_SCALAR_SIMD).
#if (defined(__arm__) || defined(__aarch64__)) && (!CV_NEON || CV_SIMD128_CPP) && !defined(DIEKF_ALLOW_SCALAR_SIMD)
#error "ARM target without NEON: OpenCV's intrinsics would be scalar emulation. Compile with -mfpu=neon-vfpv4 (or neon), or configure with -DDIEKF_ARM_NEON=OFF to accept the scalar fallback."
#endif

namespace diekf {

const char* photometricSweepSimd() {
#if CV_SIMD128_CPP || !CV_SIMD128
  return "scalar C++ (no SIMD)";
#elif CV_NEON && defined(__aarch64__)
  return "NEON (AArch64, 128-bit, fused multiply-add)";
#elif CV_NEON
  return "NEON (ARMv7, 128-bit)";
#elif CV_SSE2 && defined(__AVX__)
  return "SSE2 (x86-64, 128-bit, VEX-encoded)";
#elif CV_SSE2
  return "SSE2 (x86-64, 128-bit)";
#else
  return "128-bit SIMD (not NEON or SSE2)";
#endif
}

using internal::IntervalWarp;
using internal::kMinDepthRatio;
using internal::loadPairs;

// The warp itself (IntervalWarp, warpToReference, the time states' and the focal length's maps): interval_warp.cpp;
// the outlier weights (updateWeightMap, reliefVariance): outlier_weights.cpp.

namespace {

/// The warp of one update in single precision, laid out for the pixel loop. The sweep stores rows S' with
/// S = (dt / 2) S' T (gradient sum instead of mean), T = blockdiag(N / kappa, I / kappa, J(dt w)); the b_w part
/// of S' is v = gD x E q + s_b C2^T gD + (gD . a) C3 q, with C2 = c (1 - f) [a]x J_b J^-1 and
/// C3 = c f (J_a J^-1)^T [mu]x E_a (gD = D_r^T g without the 1/Q_z, applied per pixel).
struct PixelWarp {
  float fx, fy, cx, cy, ifx, ify;
  float H[3][3];   // reference ray Q = H q, unitless
  float Hm[3][3] = {};  // rolling shutter: dH/dtau for a pair taken tau later (stateRateMap), 1/s; 0 otherwise
  float Hx[3][3] = {};  // rolling shutter: dH/dT for the interval T lengthened at the reference image's end, 1/s
  float E[3][3];   // rotation current -> reference
  float C2[3][3];  // b_w row: s_b C2^T gD
  float C3[3][3];  // b_w row: (gD . a) C3 q
  float b[3];      // s_b = b . q
  float a[3];      // E_b vartheta, 1/s
  float P[3][2];   // mu row: (gD . a) q^T P
  ObservedInfo T;  // S = (dt / 2) S' T (double, applied to the sums)
  bool ok = false;

  PixelWarp(const State& x, const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, double state_lag_s,
            const ObservedVec* m_rows = nullptr) {
    fx = static_cast<float>(K.fx);
    fy = static_cast<float>(K.fy);
    cx = static_cast<float>(K.cx);
    cy = static_cast<float>(K.cy);
    ifx = static_cast<float>(1.0 / K.fx);
    ify = static_cast<float>(1.0 / K.fy);
    const IntervalWarp iw(x, gyro_mean_C, dt_s, state_lag_s);
    ok = iw.ok;
    const double f = iw.dt > 0.0 ? iw.lag / iw.dt : 0.0;
    const Mat3 J_inv = iw.J.inverse();  // J(phi) is invertible for |phi| < 2 pi
    const Mat3 C2d = (iw.c * (1.0 - f)) * skew(iw.a) * iw.Jb * J_inv;
    const Mat3 C3d = (iw.c * f) * (iw.Ja * J_inv).transpose() * skew(iw.mu) * iw.Ea;
    for (int r = 0; r < 3; ++r) {
      for (int col = 0; col < 3; ++col) {
        H[r][col] = static_cast<float>(iw.H(r, col));
        E[r][col] = static_cast<float>(iw.E(r, col));
        C2[r][col] = static_cast<float>(C2d(r, col));
        C3[r][col] = static_cast<float>(C3d(r, col));
      }
      b[r] = static_cast<float>(iw.b(r));
      a[r] = static_cast<float>(iw.a(r));
      P[r][0] = static_cast<float>(iw.P(r, 0));
      P[r][1] = static_cast<float>(iw.P(r, 1));
    }
    if (m_rows != nullptr && ok) {
      const double h = 1e-4;  // s
      // dH = (H(+h) - H(-h)) / 2h into `out`, where both warps exist and the difference is finite.
      auto centralDifference = [h](const IntervalWarp& p, const IntervalWarp& m, float out[3][3]) {
        if (!p.ok || !m.ok) return;
        const Mat3 dH = (p.H - m.H) / (2.0 * h);
        if (!dH.allFinite()) return;
        for (int r = 0; r < 3; ++r)
          for (int col = 0; col < 3; ++col) out[r][col] = static_cast<float>(dH(r, col));
      };
      // Central difference in time along m: the warp of a row captured tau after the image's time is
      // H + tau Hm (first order in tau; the readout of a frame is a few ms).
      centralDifference(IntervalWarp(shiftedAlong(x, *m_rows, h), gyro_mean_C, dt_s, state_lag_s),
                        IntervalWarp(shiftedAlong(x, *m_rows, -h), gyro_mean_C, dt_s, state_lag_s), Hm);
      // The interval lengthened (shortened) by h at the reference image's end, the state and the current image
      // where they are: the window's mean rate takes in the rate at the reference image's time, the mean less
      // half the rate change between the images (m's b_w part is -rate_change / dt).
      const Vec3 gyro_ref_C = gyro_mean_C + (0.5 * dt_s) * m_rows->segment<3>(5);
      centralDifference(IntervalWarp(x, (dt_s * gyro_mean_C + h * gyro_ref_C) / (dt_s + h), dt_s + h, state_lag_s),
                        IntervalWarp(x, (dt_s * gyro_mean_C - h * gyro_ref_C) / (dt_s - h), dt_s - h, state_lag_s),
                        Hx);
    }
    T.setZero();
    const double inv_kappa = ok ? 1.0 / iw.kappa : 0.0;
    T.block<3, 3>(0, 0) = inv_kappa * iw.N;
    T.block<2, 2>(3, 3) = inv_kappa * Eigen::Matrix2d::Identity();
    T.block<3, 3>(5, 5) = iw.J;
  }
};

struct SweepConfig {
  int border = 1;             // px excluded at the current image's border (>= 1: gradients are 0 there)
  int stride = 1;             // use every stride-th pixel in x and y
  float huber_abs = 0.0f;     // Huber threshold on |r| in intensity units (0 = off)
  bool gradient_weighting = false;
  int tiles_x = 8, tiles_y = 6;  // tile grid of the score sums (noise model)
  // Per-pixel weights in [0, 1]: the confidence of the current image's pixels (CV_32FC1, image size; the
  // camera-fixed pattern's) and the outlier weights of the reference's (CV_32FC1, image size), sampled
  // bilinearly where the warp lands (section 10 of docs/noise_model.md).
  const cv::Mat* confidence_map = nullptr;
  const cv::Mat* reference_weights = nullptr;
  // Rolling shutter (docs/algorithm.md section 3.7): row y of the current image is captured readout_s
  // row_weight[y] after the image's time; null = global shutter.
  const float* row_weight = nullptr;
  // Per pixel (ImageTiming::pixel_weight, pixel_stride 1 only): the pixel's weight less its row's, the weight's
  // derivatives along x and y and its second derivatives xx, xy, yy; null: every pixel of a row at the row's time.
  const cv::Mat* pixel_weight = nullptr;
  float readout_s = 0.0f;
  bool row_moments = false;      // also accumulate SweepSums::G1, G2 (the readout's information)
  // (dt / 2) T_vartheta vartheta: with the sweep's rows S' (S = (dt / 2) S' T), S'_vartheta . depth_dir is the
  // residual's derivative over a relative change of the pixel's inverse depth (dr / d rho, section 10).
  float depth_dir[3] = {0.0f, 0.0f, 0.0f};
  // Brightness of the pair (docs/noise_model.md section 12): the model of the current image is gain I_r + offset;
  // the sweep also accumulates the model's columns I_r (T_9; brightness_columns >= 1) and 1 (T_10; = 2).
  int brightness_columns = 0;
  float gain = 1.0f;
  float offset = 0.0f;
  // Brightness kLevels: gain and offset applied as given (the levels' relation), no columns.
  bool fixed_brightness = false;
  // Row gains (brightness model kRows, brightness_columns 3; docs/noise_model.md section 12): the pair's gain is
  // a cubic B-spline over the capture time of the raw rows, g(s) = sum_k c_k beta(s - k), s the spline
  // coordinate. Row y sits at s_y; a pixel of it at s_y + delta, delta = row_gain_pixel (the pixel's capture
  // time less its row's, ImageTiming::pixel_weight) times row_gain_u_to_s, and its gain is taken to second order
  // in delta: g = G0 + delta (G1 + delta G2) with (G0, G1, G2) = row_gain[3 y ..]. The gain acts on the light,
  // i.e. on the images with their levels restored (intensity + level_offset, PreprocessedFrame::level_offset): the
  // model is g (I_r + ref_level) - cur_level, its columns N, delta N, delta^2 N with N = sqrt(w) (I_r + ref_level)
  // (T_9..T_11); per row they go to the row's four knots row_knot[y] + j with the coefficients
  // row_basis[12 y + 3 j ..] = (beta_j, beta_j', beta_j'' / 2) at s_y (SweepSums::GR, DR). Null: no row gains.
  const float* row_gain = nullptr;
  const int* row_knot = nullptr;
  const float* row_basis = nullptr;
  const cv::Mat* row_gain_pixel = nullptr;  // CV_32FC1, rows x cols (plane 0 of ImageTiming::pixel_weight); null: 0
  float row_gain_u_to_s = 0.0f;
  float ref_level = 0.0f;
  float cur_level = 0.0f;
};

/// Per-pixel outputs of a sweep (CV_32FC1, the current image's size; entries the sweep does not visit keep their
/// values): the residual r (0 where invalid), dr / d rho of a relative change of the pixel's inverse depth (0
/// where invalid) and the reference position (x, y) the warp lands on (-1 where invalid).
struct PixelOutputs {
  cv::Mat* residual;
  cv::Mat* depth_jac;
  cv::Mat* ref_x;
  cv::Mat* ref_y;
};

constexpr int kMaxTilesPerAxis = 16;
/// Columns of the sweep's Gram sums: the 8 observed columns S', the residual t (column 8) and the brightness
/// model's columns I_r (9) and 1 (10), or with row gains N, delta N, delta^2 N (9-11).
constexpr int kGramCols = 12;
constexpr int kMaxTiles = kMaxTilesPerAxis * kMaxTilesPerAxis;
constexpr int kMaxRowKnots = PhotometricParams::kMaxBrightnessRowKnots;

/// Sums of one sweep in double: G = [A | b] (A upper triangle, i <= j < 8; b in column 8; with the brightness
/// columns k = 9, 10 in use also G[i][k] (i < 8: their cross terms with S'), G[8][k] (their scores) and
/// G[k][l]), and per tile of the image the score sum_tile sqrt(w) S'^T t and the valid pixel count
/// (docs/noise_model.md).
struct SweepSums {
  int candidates = 0;
  int valid = 0;
  double sum_r2 = 0.0;
  double sum_abs_r = 0.0;  // sum of w_map |r| over valid pixels (w_map = 1 without a weight map)
  double sum_r = 0.0;      // sum of w_map r over valid pixels
  double sum_w = 0.0;      // sum of w_map over valid pixels
  double grad_sum = 0.0;  // sum of |grad I_c| over valid pixels (gradient weighting normalisation)
  double G[kGramCols][kGramCols] = {};
  // Row moments for the rolling-shutter readout (SweepConfig::row_moments): sum_y w_y G_y and sum_y w_y^2 G_y
  // over the rows' Gram sums G_y, w_y = readout_weight_per_row (y - zero_row).
  double G1[8][9] = {};
  double G2[8][9] = {};
  double tile_b[kMaxTiles][8];  // written for the tiles in use at the end of sweep()
  double tile_n[kMaxTiles];
  // Per-tile lane sums during the sweep (score of the 8 columns, valid count), reduced into tile_b / tile_n at
  // its end; only the tiles in use are zeroed (sweep()).
  alignas(16) float tile_acc[kMaxTiles][9][4];
  // Row gains (SweepConfig::row_gain): per knot k the sums of its column (the model's derivative by c_k) against
  // [T_0..T_7 | t] (GR[i][k], i <= 8) and against the other knots' (DR, upper triangle; banded: four knots per
  // row). Zeroed by the sweep when in use.
  double GR[9][kMaxRowKnots];
  double DR[kMaxRowKnots][kMaxRowKnots];
};

/// Row buffers of one sweep (structure of arrays, length padded to a multiple of 4):
/// T_k = sqrt(w) S_k (k = 0..7), t = T_8 = sqrt(w) r and (brightness model only) T_9 = sqrt(w) I_r,
/// T_10 = sqrt(w), zero for invalid pixels, the valid mask (1/0), and the current image's samples.
struct RowBuffers {
  float* T[kGramCols];
  float* valid;
  float* cur[3];  // I_c, dI_c/dx, dI_c/dy at the row's candidates (strided rows only)
  float* wmap;    // outlier weights at the row's candidates (strided rows only)
};

/// Gram sums of one block of pairs over a row: G[i][j] += sum_k T_i[k] T_j[k] for i in [I0, I0 + NI), j in
/// [J0, J0 + NJ) (j >= i when kUpper). Compile-time bounds: the accumulators stay in registers.
template <int I0, int NI, int J0, int NJ, bool kUpper>
void gramBlock(float* const* T, int n_pad, double (*G)[kGramCols]) {
  using namespace cv;
  v_float32x4 acc[NI][NJ];
  for (int i = 0; i < NI; ++i)
    for (int j = 0; j < NJ; ++j) acc[i][j] = v_setzero_f32();
  for (int k = 0; k < n_pad; k += 4) {
    v_float32x4 a[NI], b[NJ];
    for (int i = 0; i < NI; ++i) a[i] = v_load(T[I0 + i] + k);
    for (int j = 0; j < NJ; ++j) b[j] = v_load(T[J0 + j] + k);
    for (int i = 0; i < NI; ++i)
      for (int j = 0; j < NJ; ++j)
        if (!kUpper || J0 + j >= I0 + i) acc[i][j] = v_muladd(a[i], b[j], acc[i][j]);
  }
  for (int i = 0; i < NI; ++i)
    for (int j = 0; j < NJ; ++j)
      if (!kUpper || J0 + j >= I0 + i) G[I0 + i][J0 + j] += v_reduce_sum(acc[i][j]);
}

/// Score sums b_i += sum T_i t of one row (reduced to double per row, like the Gram sums), and per
/// tile-column segment [seg[c], seg[c+1]) (multiples of 4) the lane sums added to the tiles of row `tile_row`
/// with their valid counts (float lanes: a tile's sums only feed the noise statistics).
void scoreRow(float* const* T, const float* valid, const int* seg, int tiles_x, int tile_row, SweepSums* sums,
              double (*G)[kGramCols]) {
  using namespace cv;
  v_float32x4 row[8];
  for (int i = 0; i < 8; ++i) row[i] = v_setzero_f32();
  for (int c = 0; c < tiles_x; ++c) {
    if (seg[c] >= seg[c + 1]) continue;
    v_float32x4 acc[8];
    for (int i = 0; i < 8; ++i) acc[i] = v_setzero_f32();
    v_float32x4 cnt = v_setzero_f32();
    for (int k = seg[c]; k < seg[c + 1]; k += 4) {
      const v_float32x4 t = v_load(T[8] + k);
      for (int i = 0; i < 8; ++i) acc[i] = v_muladd(v_load(T[i] + k), t, acc[i]);
      cnt += v_load(valid + k);
    }
    float(*tile)[4] = sums->tile_acc[tile_row * tiles_x + c];
    for (int i = 0; i < 8; ++i) {
      row[i] += acc[i];
      v_store_aligned(tile[i], v_load_aligned(tile[i]) + acc[i]);
    }
    v_store_aligned(tile[8], v_load_aligned(tile[8]) + cnt);
  }
  for (int i = 0; i < 8; ++i) G[i][8] += v_reduce_sum(row[i]);
}

/// Gram sums of one row over [T_0..T_7 | t]: A_ij += sum T_i T_j (i <= j < 8) in blocks of at most 10
/// accumulators (4 lanes each) so that nothing spills, and the score sums per tile (scoreRow).
/// The row's Gram sums go to G (zeroed by the caller), its tile scores to sums. With `brightness_columns` (1 or 2)
/// also the sums of the brightness columns T_9 (and T_10) against [T_0..T_7 | t] and themselves.
void accumulateRow(float* const* T, const float* valid, int n_pad, const int* seg, int tiles_x, int tile_row,
                   int brightness_columns, SweepSums* sums, double (*G)[kGramCols]) {
  gramBlock<0, 4, 0, 4, true>(T, n_pad, G);
  gramBlock<4, 4, 4, 4, true>(T, n_pad, G);
  gramBlock<0, 4, 4, 2, false>(T, n_pad, G);
  gramBlock<0, 4, 6, 2, false>(T, n_pad, G);
  scoreRow(T, valid, seg, tiles_x, tile_row, sums, G);
  if (brightness_columns == 1) {
    gramBlock<0, 4, 9, 1, false>(T, n_pad, G);
    gramBlock<4, 4, 9, 1, false>(T, n_pad, G);
    gramBlock<8, 2, 8, 2, true>(T, n_pad, G);  // t t (unused), t T_9, T_9 T_9
  } else if (brightness_columns == 2) {
    gramBlock<0, 4, 9, 2, false>(T, n_pad, G);
    gramBlock<4, 4, 9, 2, false>(T, n_pad, G);
    gramBlock<8, 3, 8, 3, true>(T, n_pad, G);  // t t (unused), t T_9, t T_10, T_9 T_9, T_9 T_10, T_10 T_10
  } else if (brightness_columns == 3) {
    gramBlock<0, 4, 9, 2, false>(T, n_pad, G);
    gramBlock<0, 4, 11, 1, false>(T, n_pad, G);
    gramBlock<4, 4, 9, 2, false>(T, n_pad, G);
    gramBlock<4, 4, 11, 1, false>(T, n_pad, G);
    gramBlock<8, 4, 8, 4, true>(T, n_pad, G);  // t and T_9..T_11 against each other
  }
}

/// One linearisation sweep over the current image against the reference's cubic B-spline coefficients
/// (bspline.h). Per row: (1) 4 pixels at a time, warp, the reference's value and gradient from the 4x4 spline
/// taps (per tap row and lane group 4 loads, transposed unless the lanes' taps are consecutive columns),
/// residual, Jacobian row S (2/dt times the true row: gradient sum instead of mean, Jacobian without dt; the
/// caller rescales), weight; the results go to the row buffers; (2) the row's Gram sums.
/// The residual r, dr / d rho and the reference position per pixel go to `out` (PixelOutputs). The weighting
/// options are template parameters.
template <bool kHuber, bool kGradientWeighting, bool kWeightMap, int kTaps>
void sweep(const cv::Mat& ref_coeff, const PreprocessedFrame& cur, const PixelWarp& wp, const SweepConfig& cfg,
           RowBuffers buf, SweepSums* sums, const PixelOutputs& out) {
  using namespace cv;
  const int W = cur.intensity.cols;
  const int H = cur.intensity.rows;
  const float* C = ref_coeff.ptr<float>(0);
  const int sC = static_cast<int>(ref_coeff.step1());  // floats per coefficient row
  const float* RW = cfg.reference_weights != nullptr ? cfg.reference_weights->ptr<float>(0) : nullptr;
  const int sW = cfg.reference_weights != nullptr ? static_cast<int>(cfg.reference_weights->step1()) : 0;
  const bool same_stride = sW == sC;
  // The reference sample's spline taps x0 - lead ... x0 + lead + 1 stay inside the image: x0 = floor(rx) in
  // [lead, W - lead - 2]  <=>  rx in [lead, W - lead - 1). Cubic (4 taps): lead 1, as the 2x2 neighbourhood of
  // bilinear sampling inside the 1-px border; quintic (6 taps): lead 2.
  static_assert(kTaps == 4 || kTaps == 6, "cubic or quintic spline");
  constexpr int kLead = kTaps / 2 - 1;
  const v_float32x4 rx_lo = v_setall_f32(kLead), rx_hi = v_setall_f32(static_cast<float>(W - kLead - 1));
  const v_float32x4 ry_lo = v_setall_f32(kLead), ry_hi = v_setall_f32(static_cast<float>(H - kLead - 1));
  const v_float32x4 one = v_setall_f32(1.0f), zero = v_setzero_f32();
  const auto splat = [](float v) { return v_setall_f32(v); };  // constants of the spline weights
  const v_float32x4 fx = v_setall_f32(wp.fx), fy = v_setall_f32(wp.fy);
  const v_float32x4 cx = v_setall_f32(wp.cx), cy = v_setall_f32(wp.cy);
  const v_float32x4 ifx = v_setall_f32(wp.ifx);
  const v_float32x4 min_depth = v_setall_f32(static_cast<float>(kMinDepthRatio));
  const v_float32x4 huber = v_setall_f32(cfg.huber_abs);
  const bool brightness_cols = cfg.brightness_columns > 0;
  const bool brightness = brightness_cols || cfg.fixed_brightness;
  const v_float32x4 gain = v_setall_f32(cfg.gain), offset = v_setall_f32(cfg.offset);
  const bool row_gains = cfg.row_gain != nullptr;
  const v_float32x4 ref_level = v_setall_f32(cfg.ref_level), cur_level_neg = v_setall_f32(-cfg.cur_level);
  const v_float32x4 u_to_s = v_setall_f32(cfg.row_gain_u_to_s);
  if (row_gains) {
    for (int i = 0; i < 9; ++i) std::fill(sums->GR[i], sums->GR[i] + kMaxRowKnots, 0.0);
    for (int k = 0; k < kMaxRowKnots; ++k) std::fill(sums->DR[k], sums->DR[k] + kMaxRowKnots, 0.0);
  }
  // The warp's per-pixel coefficients as vectors, made once: the loop stores through float pointers (the row
  // buffers, the outputs), which the compiler must assume may alias wp's and cfg's floats, so read from there it
  // would load and broadcast every coefficient again for every 4 pixels.
  const v_float32x4 wp_b0 = v_setall_f32(wp.b[0]);
  const v_float32x4 wp_a[3] = {v_setall_f32(wp.a[0]), v_setall_f32(wp.a[1]), v_setall_f32(wp.a[2])};
  const v_float32x4 wp_E0[3] = {v_setall_f32(wp.E[0][0]), v_setall_f32(wp.E[1][0]), v_setall_f32(wp.E[2][0])};
  const v_float32x4 wp_C30[3] = {v_setall_f32(wp.C3[0][0]), v_setall_f32(wp.C3[1][0]), v_setall_f32(wp.C3[2][0])};
  v_float32x4 wp_C2[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) wp_C2[i][j] = v_setall_f32(wp.C2[i][j]);
  const v_float32x4 wp_P00 = v_setall_f32(wp.P[0][0]), wp_P01 = v_setall_f32(wp.P[0][1]);
  const v_float32x4 depth_dir[3] = {v_setall_f32(cfg.depth_dir[0]), v_setall_f32(cfg.depth_dir[1]),
                                    v_setall_f32(cfg.depth_dir[2])};
  const int n = (W - 2 * cfg.border + cfg.stride - 1) / cfg.stride;  // candidates per row
  if (n <= 0) return;
  const int n_pad = (n + 3) & ~3;
  // Tile-column segments of the candidates (multiples of 4 lanes) and the rows of the tile rows.
  const int tiles_x = std::clamp(cfg.tiles_x, 1, kMaxTilesPerAxis);
  const int tiles_y = std::clamp(cfg.tiles_y, 1, kMaxTilesPerAxis);
  int seg[kMaxTilesPerAxis + 1];
  for (int c = 0; c < tiles_x; ++c) seg[c] = ((c * n_pad) / tiles_x) & ~3;
  seg[tiles_x] = n_pad;
  const int rows_used = std::max(1, H - 2 * cfg.border);
  for (int t = 0; t < tiles_x * tiles_y; ++t)
    for (int i = 0; i < 9; ++i)
      for (int l = 0; l < 4; ++l) sums->tile_acc[t][i][l] = 0.0f;
  alignas(16) int32_t idx[4];
  alignas(16) int32_t widx[4];
  const v_int32x4 lane_ramp(0, 1, 2, 3);
  const v_int32x4 lead_i = v_setall_s32(kLead);
  alignas(16) float xs_init[4];
  for (int l = 0; l < 4; ++l) xs_init[l] = static_cast<float>(cfg.border + l * cfg.stride);
  const v_float32x4 x_step = v_setall_f32(static_cast<float>(4 * cfg.stride));

  for (int y = cfg.border; y < H - cfg.border; y += cfg.stride) {
    // Row gains (see SweepConfig): the row's gain, slope and half curvature over delta, and where delta comes from.
    const v_float32x4 rg0 = v_setall_f32(row_gains ? cfg.row_gain[3 * y] : 1.0f);
    const v_float32x4 rg1 = v_setall_f32(row_gains ? cfg.row_gain[3 * y + 1] : 0.0f);
    const v_float32x4 rg2 = v_setall_f32(row_gains ? cfg.row_gain[3 * y + 2] : 0.0f);
    const float* rg_pixel = row_gains && cfg.row_gain_pixel != nullptr && cfg.stride == 1
                                ? cfg.row_gain_pixel->ptr<float>(y) + cfg.border
                                : nullptr;
    const float* Ic;
    const float* Gxc;
    const float* Gyc;
    if (cfg.stride == 1) {
      // Reading up to 3 values past the last candidate stays inside the image (row y + 1 exists).
      Ic = cur.intensity.ptr<float>(y) + cfg.border;
      Gxc = cur.grad_x.ptr<float>(y) + cfg.border;
      Gyc = cur.grad_y.ptr<float>(y) + cfg.border;
    } else {
      const float* src[3] = {cur.intensity.ptr<float>(y), cur.grad_x.ptr<float>(y), cur.grad_y.ptr<float>(y)};
      for (int c = 0; c < 3; ++c) {
        for (int k = 0; k < n_pad; ++k) buf.cur[c][k] = src[c][cfg.border + std::min(k, n - 1) * cfg.stride];
      }
      Ic = buf.cur[0];
      Gxc = buf.cur[1];
      Gyc = buf.cur[2];
    }
    float* res_row = out.residual->ptr<float>(y);
    float* jac_row = out.depth_jac->ptr<float>(y);
    float* rx_row = out.ref_x->ptr<float>(y);
    float* ry_row = out.ref_y->ptr<float>(y);
    const float* Wm = nullptr;
    if constexpr (kWeightMap) {
      if (cfg.confidence_map == nullptr) {
        Wm = nullptr;
      } else if (cfg.stride == 1) {
        Wm = cfg.confidence_map->ptr<float>(y) + cfg.border;
      } else {
        const float* src = cfg.confidence_map->ptr<float>(y);
        for (int k = 0; k < n_pad; ++k) buf.wmap[k] = src[cfg.border + std::min(k, n - 1) * cfg.stride];
        Wm = buf.wmap;
      }
    }

    // Terms constant along the row: q = (qx, qy, 1), Q = H q = qx H_col0 + h_row, etc. With a rolling shutter
    // the row's warp is that of a pair taken tau = line_delay (y - zero_row) later: H + tau Hm (exactly H for
    // a global shutter, where tau = 0).
    const float yf = static_cast<float>(y);
    const float qy_s = (yf - wp.cy) * wp.ify;
    const float tau = cfg.row_weight != nullptr ? cfg.readout_s * cfg.row_weight[y] : 0.0f;  // s
    float Hr[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) Hr[i][j] = wp.H[i][j] + tau * wp.Hm[i][j];
    const v_float32x4 H00 = v_setall_f32(Hr[0][0]), H10 = v_setall_f32(Hr[1][0]), H20 = v_setall_f32(Hr[2][0]);
    const v_float32x4 h0 = v_setall_f32(Hr[0][1] * qy_s + Hr[0][2]);
    const v_float32x4 h1 = v_setall_f32(Hr[1][1] * qy_s + Hr[1][2]);
    const v_float32x4 h2 = v_setall_f32(Hr[2][1] * qy_s + Hr[2][2]);
    const bool rolling = cfg.row_weight != nullptr && cfg.readout_s != 0.0f;
    // Slope and curvature of the row weights (per working row), for the reference pixel's own row time.
    const int y_lo = std::max(y - 1, 0), y_hi = std::min(y + 1, H - 1), y_mid = std::clamp(y, 1, std::max(1, H - 2));
    const float slope = rolling && y_hi > y_lo ? (cfg.row_weight[y_hi] - cfg.row_weight[y_lo]) / (y_hi - y_lo) : 0.0f;
    const float curv = rolling && H >= 3 ? cfg.row_weight[y_mid + 1] - 2.0f * cfg.row_weight[y_mid] +
                                               cfg.row_weight[y_mid - 1]
                                         : 0.0f;
    const v_float32x4 yv = v_setall_f32(yf);
    // Per pixel (barrel distortion bends the raw rows): the pixel's time less its row's, tau_p - tau = readout dw,
    // moves its reference ray along Hm q; the reference pixel's own time from the weight's gradient and second
    // derivatives there.
    const bool per_pixel = rolling && cfg.pixel_weight != nullptr;
    const float* pw_d = per_pixel ? cfg.pixel_weight->ptr<float>(y) + cfg.border : nullptr;
    const float* pw_x = per_pixel ? cfg.pixel_weight->ptr<float>(H + y) + cfg.border : nullptr;
    const float* pw_y = per_pixel ? cfg.pixel_weight->ptr<float>(2 * H + y) + cfg.border : nullptr;
    const float* pw_xx = per_pixel ? cfg.pixel_weight->ptr<float>(3 * H + y) + cfg.border : nullptr;
    const float* pw_xy = per_pixel ? cfg.pixel_weight->ptr<float>(4 * H + y) + cfg.border : nullptr;
    const float* pw_yy = per_pixel ? cfg.pixel_weight->ptr<float>(5 * H + y) + cfg.border : nullptr;
    const v_float32x4 v_readout = v_setall_f32(cfg.readout_s), v_slope = v_setall_f32(slope),
                      v_curv = v_setall_f32(curv), half = v_setall_f32(0.5f), min_den = v_setall_f32(0.25f),
                      nan = v_setall_f32(std::numeric_limits<float>::quiet_NaN());
    // The flow's rate at the reference image's end, D_r Hx q (rolling shutter only).
    const v_float32x4 Hx00 = v_setall_f32(wp.Hx[0][0]), Hx10 = v_setall_f32(wp.Hx[1][0]),
                      Hx20 = v_setall_f32(wp.Hx[2][0]);
    const v_float32x4 hx0 = v_setall_f32(wp.Hx[0][1] * qy_s + wp.Hx[0][2]);
    const v_float32x4 hx1 = v_setall_f32(wp.Hx[1][1] * qy_s + wp.Hx[1][2]);
    const v_float32x4 hx2 = v_setall_f32(wp.Hx[2][1] * qy_s + wp.Hx[2][2]);
    const v_float32x4 Hm00 = v_setall_f32(wp.Hm[0][0]), Hm10 = v_setall_f32(wp.Hm[1][0]),
                      Hm20 = v_setall_f32(wp.Hm[2][0]);
    const v_float32x4 hm0 = v_setall_f32(wp.Hm[0][1] * qy_s + wp.Hm[0][2]);
    const v_float32x4 hm1 = v_setall_f32(wp.Hm[1][1] * qy_s + wp.Hm[1][2]);
    const v_float32x4 hm2 = v_setall_f32(wp.Hm[2][1] * qy_s + wp.Hm[2][2]);
    const v_float32x4 e0 = v_setall_f32(wp.E[0][1] * qy_s + wp.E[0][2]);
    const v_float32x4 e1 = v_setall_f32(wp.E[1][1] * qy_s + wp.E[1][2]);
    const v_float32x4 e2 = v_setall_f32(wp.E[2][1] * qy_s + wp.E[2][2]);
    const v_float32x4 k0 = v_setall_f32(wp.C3[0][1] * qy_s + wp.C3[0][2]);
    const v_float32x4 k1 = v_setall_f32(wp.C3[1][1] * qy_s + wp.C3[1][2]);
    const v_float32x4 k2 = v_setall_f32(wp.C3[2][1] * qy_s + wp.C3[2][2]);
    const v_float32x4 s_row = v_setall_f32(wp.b[1] * qy_s + wp.b[2]);
    const v_float32x4 qP0 = v_setall_f32(wp.P[1][0] * qy_s + wp.P[2][0]);
    const v_float32x4 qP1 = v_setall_f32(wp.P[1][1] * qy_s + wp.P[2][1]);

    v_float32x4 r2 = v_setzero_f32(), rabs = v_setzero_f32(), rsum = v_setzero_f32(), gsum = v_setzero_f32(),
                vcount = v_setzero_f32();
    v_float32x4 wsum = v_setzero_f32();
    v_float32x4 xv = v_load(xs_init);
    for (int k = 0; k < n_pad; k += 4, xv += x_step) {
      const v_float32x4 qx = (xv - cx) * ifx;
      v_float32x4 Qx = v_muladd(H00, qx, h0);
      v_float32x4 Qy = v_muladd(H10, qx, h1);
      v_float32x4 Qz = v_muladd(H20, qx, h2);
      if (per_pixel) {
        const v_float32x4 dtau = v_readout * v_load(pw_d + k);
        Qx = v_muladd(dtau, v_muladd(Hm00, qx, hm0), Qx);
        Qy = v_muladd(dtau, v_muladd(Hm10, qx, hm1), Qy);
        Qz = v_muladd(dtau, v_muladd(Hm20, qx, hm2), Qz);
      }
      const v_float32x4 in_front = Qz > min_depth;
      const v_float32x4 iz = one / v_select(in_front, Qz, one);
      v_float32x4 rx = v_muladd(fx, Qx * iz, cx);
      v_float32x4 ry = v_muladd(fy, Qy * iz, cy);
      if (rolling) {
        // The reference pixel was read out readout (w(p) - w(p_r)) earlier than p: the pair's interval is longer
        // by delta = -readout (w(p_r) - w(p)) at the reference image's end, and the reference pixel moves by delta
        // times the flow's rate there, u = D_r Hx q. With D = p_r - p, w(p_r) - w(p) = (grad w + Hess D / 2) . D
        // to second order, and delta itself moves p_r by delta u: delta = -readout dw / (1 + readout gradient . u).
        const v_float32x4 Dx = rx - xv, Dy = ry - yv;
        v_float32x4 gx0, gy0, gx1, gy1;  // the weight's gradient at the middle of D and at p_r
        if (per_pixel) {
          const v_float32x4 wxx = v_load(pw_xx + k), wxy = v_load(pw_xy + k), wyy = v_load(pw_yy + k);
          const v_float32x4 hess_x = v_muladd(wxx, Dx, wxy * Dy), hess_y = v_muladd(wxy, Dx, wyy * Dy);  // Hess D
          const v_float32x4 gxp = v_load(pw_x + k), gyp = v_load(pw_y + k);
          gx0 = v_muladd(half, hess_x, gxp);
          gy0 = v_muladd(half, hess_y, gyp);
          gx1 = gxp + hess_x;
          gy1 = gyp + hess_y;
        } else {
          gx0 = gx1 = zero;
          gy0 = v_muladd(half * v_curv, Dy, v_slope);
          gy1 = v_muladd(v_curv, Dy, v_slope);
        }
        const v_float32x4 dw = v_muladd(gx0, Dx, gy0 * Dy);
        const v_float32x4 Ux = v_muladd(Hx00, qx, hx0), Uy = v_muladd(Hx10, qx, hx1), Uz = v_muladd(Hx20, qx, hx2);
        const v_float32x4 ux = v_muladd(fx, Ux, (cx - rx) * Uz) * iz, uy = v_muladd(fy, Uy, (cy - ry) * Uz) * iz;
        // (A denominator near 0 is the ground moving as fast as the readout along the image: no time solves it,
        // and NaN makes the pixel invalid.)
        const v_float32x4 den = v_muladd(v_readout, v_muladd(gx1, ux, gy1 * uy), one);
        const v_float32x4 delta = v_select(den > min_den, (zero - v_readout * dw) / den, nan);
        rx = v_muladd(delta, ux, rx);
        ry = v_muladd(delta, uy, ry);
      }
      // Comparisons are false for NaN: such pixels are invalid.
      v_float32x4 valid = in_front & (rx >= rx_lo) & (rx < rx_hi) & (ry >= ry_lo) & (ry < ry_hi);
      if (k + 4 > n) {
        alignas(16) float lane_ok[4];
        for (int l = 0; l < 4; ++l) lane_ok[l] = k + l < n ? 1.0f : 0.0f;
        valid = valid & (v_load(lane_ok) == one);
      }
      // Invalid lanes sample the safe position (1, 1); their terms are zeroed below.
      const v_float32x4 rxs = v_select(valid, rx, rx_lo), rys = v_select(valid, ry, ry_lo);
      const v_int32x4 x0 = v_floor(rxs), y0 = v_floor(rys);
      const v_float32x4 ax = rxs - v_cvt_f32(x0), ay = rys - v_cvt_f32(y0);
      const v_int32x4 idx_v = (y0 - lead_i) * v_setall_s32(sC) + (x0 - lead_i);  // the lanes' top-left taps
      v_store_aligned(idx, idx_v);
      // Most groups sample 4 consecutive reference columns of one row (the warp is near a shift along the
      // row): lane l's taps start at idx[0] + l, so tap m of the 4 lanes is one load at idx[0] + m.
      const bool consecutive = v_check_all(idx_v == v_setall_s32(idx[0]) + lane_ramp);
      // The reference's value and gradient: per tap row, the 4 taps of the 4 lanes as tap planes, and
      // the row's value and x-derivative at ax (row_i, row_d); the rows are then combined with the vertical
      // weights (value, d/dx) and their derivatives (d/dy).
      v_float32x4 wx[kTaps], dwx[kTaps], wy[kTaps], dwy[kTaps];
      if constexpr (kTaps == 4) {
        internal::cubicBSplineWeights(ax, wx, dwx, splat);
        internal::cubicBSplineWeights(ay, wy, dwy, splat);
      } else {
        internal::quinticBSplineWeights(ax, wx, dwx, splat);
        internal::quinticBSplineWeights(ay, wy, dwy, splat);
      }
      v_float32x4 row_i[kTaps], row_d[kTaps];
      for (int j = 0; j < kTaps; ++j) {
        const int off = j * sC;
        v_float32x4 c[kTaps];
        if (consecutive) {
          const float* p = C + idx[0] + off;
          for (int m = 0; m < kTaps; ++m) c[m] = v_load(p + m);
        } else {
          // Taps 0-3, and for the quintic 2-5 (the last two kept): 4 floats from each lane's start.
          for (int g = 0; g < kTaps; g += 4) {
            const int at = g == 0 ? 0 : kTaps - 4;
            const v_float32x4 p0 = v_load(C + idx[0] + off + at), p1 = v_load(C + idx[1] + off + at);
            const v_float32x4 p2 = v_load(C + idx[2] + off + at), p3 = v_load(C + idx[3] + off + at);
            v_float32x4 t0, t1, t2, t3;
            v_transpose4x4(p0, p1, p2, p3, t0, t1, t2, t3);
            c[at] = t0;
            c[at + 1] = t1;
            c[at + 2] = t2;
            c[at + 3] = t3;
          }
        }
        v_float32x4 ri = wx[0] * c[0], rd = dwx[0] * c[0];
        for (int m = 1; m < kTaps; ++m) {
          ri = v_muladd(wx[m], c[m], ri);
          rd = v_muladd(dwx[m], c[m], rd);
        }
        row_i[j] = ri;
        row_d[j] = rd;
      }
      v_float32x4 ref_i = wy[0] * row_i[0], ref_gx = wy[0] * row_d[0], ref_gy = dwy[0] * row_i[0];
      for (int j = 1; j < kTaps; ++j) {
        ref_i = v_muladd(wy[j], row_i[j], ref_i);
        ref_gx = v_muladd(wy[j], row_d[j], ref_gx);
        ref_gy = v_muladd(dwy[j], row_i[j], ref_gy);
      }
      const v_float32x4 gxc = v_load(Gxc + k), gyc = v_load(Gyc + k);
      // The reference through the pair's brightness model, gain I_r + offset (section 12; off: I_r itself).
      v_float32x4 model = ref_i, model_gx = ref_gx, model_gy = ref_gy;
      v_float32x4 delta = zero;  // row gains: the pixel's spline coordinate less its row's
      if (row_gains) {
        if (rg_pixel != nullptr) delta = v_load(rg_pixel + k) * u_to_s;
        const v_float32x4 g = v_muladd(delta, v_muladd(delta, rg2, rg1), rg0);
        model = v_muladd(g, ref_i + ref_level, cur_level_neg);
        model_gx = g * ref_gx;
        model_gy = g * ref_gy;
      } else if (brightness) {
        model = v_muladd(gain, ref_i, offset);
        model_gx = gain * ref_gx;
        model_gy = gain * ref_gy;
      }
      const v_float32x4 r = v_select(valid, v_load(Ic + k) - model, zero);
      // Efficient second-order gradient: sum of current and warped reference gradients (1/2 applied later).
      const v_float32x4 gx = gxc + model_gx, gy = gyc + model_gy;
      const v_float32x4 ex = cx - rxs, ey = cy - rys;  // D_r(0, 2), D_r(1, 2)
      const v_float32x4 gD0 = gx * fx, gD1 = gy * fy, gD2 = v_muladd(gx, ex, gy * ey);
      const v_float32x4 s_b = v_muladd(wp_b0, qx, s_row);
      const v_float32x4 u = v_muladd(gD2, wp_a[2], v_muladd(gD1, wp_a[1], gD0 * wp_a[0]));
      // Weight (0 for invalid pixels); the rows are scaled by sqrt(w).
      v_float32x4 w = v_select(valid, one, zero);
      v_float32x4 wm = one;  // outlier weight of the pixel (1 without a map)
      if constexpr (kWeightMap) {
        // The reference pixel's outlier weight (1 without) times the current pixel's confidence.
        if (Wm != nullptr) wm = v_load(Wm + k);
        if (RW != nullptr) {
          // The reference's outlier weights, bilinear at the same position: per lane the pairs (x0, x0 + 1) of
          // rows y0 and y0 + 1.
          if (same_stride) {
            v_store_aligned(widx, v_load_aligned(idx) + v_setall_s32(sC + 1));  // y0 sC + x0
          } else {
            v_store_aligned(widx, y0 * v_setall_s32(sW) + x0);
          }
          v_float32x4 q00, q01, q10, q11;
          if (consecutive) {
            const float* p = RW + widx[0];
            q00 = v_load(p);
            q01 = v_load(p + 1);
            q10 = v_load(p + sW);
            q11 = v_load(p + sW + 1);
          } else {
            const float* p0 = RW + widx[0];
            const float* p1 = RW + widx[1];
            const float* p2 = RW + widx[2];
            const float* p3 = RW + widx[3];
            loadPairs(p0, p1, p2, p3, &q00, &q01);
            loadPairs(p0 + sW, p1 + sW, p2 + sW, p3 + sW, &q10, &q11);
          }
          const v_float32x4 bx = one - ax, by = one - ay;
          const v_float32x4 ref_w =
              v_muladd(ax * ay, q11, v_muladd(bx * ay, q10, v_muladd(ax * by, q01, (bx * by) * q00)));
          wm = wm * ref_w;
        }
        w = w * wm;
      }
      if constexpr (kGradientWeighting) {
        const v_float32x4 gmag = v_sqrt(v_muladd(gxc, gxc, gyc * gyc));
        gsum = v_muladd(w, gmag, gsum);
        w = w * gmag;
      }
      if constexpr (kHuber) {
        const v_float32x4 ar = v_abs(r);
        w = w * v_select(ar > huber, huber / v_select(ar > huber, ar, one), one);
      }
      const v_float32x4 sw = (kHuber || kGradientWeighting || kWeightMap) ? v_sqrt(w) : w;
      const v_float32x4 swj = sw * iz;  // the Jacobian rows carry dp_r/dQ = D_r / Q_z
      const v_float32x4 ssb = swj * s_b, su = swj * u;
      // S' = [vartheta (3), mu (2), b_w (3)] (see PixelWarp); b_w: gD x E q + s_b C2^T gD + u C3 q.
      const v_float32x4 Ex = v_muladd(wp_E0[0], qx, e0);
      const v_float32x4 Ey = v_muladd(wp_E0[1], qx, e1);
      const v_float32x4 Ez = v_muladd(wp_E0[2], qx, e2);
      v_float32x4 v_bw[3];
      v_bw[0] = gD1 * Ez - gD2 * Ey;
      v_bw[1] = gD2 * Ex - gD0 * Ez;
      v_bw[2] = gD0 * Ey - gD1 * Ex;
      const v_float32x4 Kq[3] = {v_muladd(wp_C30[0], qx, k0), v_muladd(wp_C30[1], qx, k1),
                                 v_muladd(wp_C30[2], qx, k2)};
      for (int j = 0; j < 3; ++j) {
        const v_float32x4 c2g = v_muladd(gD2, wp_C2[2][j], v_muladd(gD1, wp_C2[1][j], gD0 * wp_C2[0][j]));
        v_bw[j] = v_muladd(u, Kq[j], v_muladd(s_b, c2g, v_bw[j]));
      }
      v_store_aligned(buf.T[0] + k, ssb * gD0);
      v_store_aligned(buf.T[1] + k, ssb * gD1);
      v_store_aligned(buf.T[2] + k, ssb * gD2);
      v_store_aligned(buf.T[3] + k, su * v_muladd(wp_P00, qx, qP0));
      v_store_aligned(buf.T[4] + k, su * v_muladd(wp_P01, qx, qP1));
      v_store_aligned(buf.T[5] + k, swj * v_bw[0]);
      v_store_aligned(buf.T[6] + k, swj * v_bw[1]);
      v_store_aligned(buf.T[7] + k, swj * v_bw[2]);
      v_store_aligned(buf.T[8] + k, sw * r);
      if (brightness_cols) {
        if (row_gains) {
          const v_float32x4 nN = sw * (ref_i + ref_level), dN = delta * nN;
          v_store_aligned(buf.T[9] + k, nN);
          v_store_aligned(buf.T[10] + k, dN);
          v_store_aligned(buf.T[11] + k, delta * dN);
        } else {
          v_store_aligned(buf.T[9] + k, sw * ref_i);
          if (cfg.brightness_columns > 1) v_store_aligned(buf.T[10] + k, sw);
        }
      }
      r2 = v_muladd(r, r, r2);
      const v_float32x4 valid01 = v_select(valid, one, zero);
      if constexpr (kWeightMap) {
        rabs = v_muladd(v_abs(r), wm, rabs);
        rsum = v_muladd(r, wm, rsum);
        wsum = v_muladd(valid01, wm, wsum);
      } else {
        rabs += v_abs(r);
        rsum += r;
        wsum += valid01;
      }
      v_store_aligned(buf.valid + k, valid01);
      vcount += valid01;
      // dr / d rho (section 10), and where the warp lands.
      const v_float32x4 dj =
          v_select(valid, (s_b * iz) * v_muladd(gD2, depth_dir[2], v_muladd(gD1, depth_dir[1], gD0 * depth_dir[0])),
                   zero);
      const v_float32x4 minus_one = v_setall_f32(-1.0f);
      const v_float32x4 rxo = v_select(valid, rx, minus_one), ryo = v_select(valid, ry, minus_one);
      if (cfg.stride == 1) {
        // Up to 3 lanes past the last candidate land in the border (or the next row, written later): zeros.
        v_store(res_row + cfg.border + k, r);
        v_store(jac_row + cfg.border + k, dj);
        v_store(rx_row + cfg.border + k, rxo);
        v_store(ry_row + cfg.border + k, ryo);
      } else {
        alignas(16) float rr[4], jj[4], xx[4], yy[4];
        v_store_aligned(rr, r);
        v_store_aligned(jj, dj);
        v_store_aligned(xx, rxo);
        v_store_aligned(yy, ryo);
        for (int l = 0; l < 4 && k + l < n; ++l) {
          const int at = cfg.border + (k + l) * cfg.stride;
          res_row[at] = rr[l];
          jac_row[at] = jj[l];
          rx_row[at] = xx[l];
          ry_row[at] = yy[l];
        }
      }
    }
    const int tile_row = std::min(tiles_y - 1, ((y - cfg.border) * tiles_y) / rows_used);
    double Grow[kGramCols][kGramCols] = {};
    accumulateRow(buf.T, buf.valid, n_pad, seg, tiles_x, tile_row, cfg.brightness_columns, sums, Grow);
    for (int i = 0; i < 8; ++i)
      for (int j = i; j < 9; ++j) sums->G[i][j] += Grow[i][j];
    if (row_gains) {
      // The row's sums of its columns N, delta N, delta^2 N go to its four knots: knot k0 + j's column is
      // a_j . (N, delta N, delta^2 N) with a_j = row_basis[12 y + 3 j ..].
      const int k0 = cfg.row_knot[y];
      const float* a = cfg.row_basis + 12 * y;
      double Gb[3][3];
      for (int n = 0; n < 3; ++n)
        for (int q = 0; q < 3; ++q) Gb[n][q] = Grow[9 + std::min(n, q)][9 + std::max(n, q)];
      for (int j = 0; j < 4; ++j) {
        const double a0 = a[3 * j], a1 = a[3 * j + 1], a2 = a[3 * j + 2];
        for (int i = 0; i < 9; ++i) sums->GR[i][k0 + j] += a0 * Grow[i][9] + a1 * Grow[i][10] + a2 * Grow[i][11];
        double Ga[3];
        for (int q = 0; q < 3; ++q) Ga[q] = a0 * Gb[0][q] + a1 * Gb[1][q] + a2 * Gb[2][q];
        for (int l = j; l < 4; ++l)
          sums->DR[k0 + j][k0 + l] += Ga[0] * a[3 * l] + Ga[1] * a[3 * l + 1] + Ga[2] * a[3 * l + 2];
      }
    }
    const int j_end = 9 + cfg.brightness_columns;
    for (int i = 0; i < j_end; ++i)
      for (int j = std::max(i, 9); j < j_end; ++j) sums->G[i][j] += Grow[i][j];
    if (cfg.row_moments) {
      const double w = cfg.row_weight[y];
      for (int i = 0; i < 8; ++i)
        for (int j = i; j < 9; ++j) {
          sums->G1[i][j] += w * Grow[i][j];
          sums->G2[i][j] += w * w * Grow[i][j];
        }
    }
    sums->candidates += n;
    sums->valid += static_cast<int>(v_reduce_sum(vcount));
    sums->sum_r2 += v_reduce_sum(r2);
    sums->sum_abs_r += v_reduce_sum(rabs);
    sums->sum_r += v_reduce_sum(rsum);
    sums->sum_w += v_reduce_sum(wsum);
    sums->grad_sum += v_reduce_sum(gsum);
  }
  for (int t = 0; t < tiles_x * tiles_y; ++t) {
    const float(*tile)[4] = sums->tile_acc[t];
    for (int i = 0; i < 8; ++i) sums->tile_b[t][i] = double(tile[i][0]) + tile[i][1] + tile[i][2] + tile[i][3];
    sums->tile_n[t] = double(tile[8][0]) + tile[8][1] + tile[8][2] + tile[8][3];
  }
}

/// `huber_sigma`: the per-pixel noise 1-sigma the Huber threshold refers to (normalised units).
SweepConfig makeConfig(const PhotometricParams& params, const PreprocessParams& preprocess, double huber_sigma) {
  SweepConfig cfg;
  cfg.border = std::max(1, preprocess.border_px);
  cfg.stride = std::max(1, params.pixel_stride);
  cfg.huber_abs = params.huber_threshold > 0.0 ? static_cast<float>(params.huber_threshold * huber_sigma) : 0.0f;
  cfg.gradient_weighting = params.gradient_weighting;
  cfg.tiles_x = params.noise_tiles_x;
  cfg.tiles_y = params.noise_tiles_y;
  return cfg;
}

/// Row gains: the first pass is linearised again with the gains it fitted while their step is above this
/// (relative gain; the images' noise is a few % of their contrast).
constexpr double kRowGainRefitStep = 0.02;

/// The 95 % quantile of chi-square with 8 degrees of freedom (the NIS of the eight observed columns): a frame whose
/// NIS lies above it does not move the time states (update(); docs/algorithm.md section 3.6).
constexpr double kTimeStatesMaxNis = 15.507;

/// Bands of the rows (brightness model auto, rowBanding): found when the RMS over the rows of the pair's common
/// relative gain per row, smoothed over kBandsTimeConstantS, is above kBandsFoundGain, lost below kBandsLostGain.
/// On images whose level (mean over standard deviation) is 2-7, a 2 % gain leaves residuals of 0.04-0.14, several
/// times the pixels' noise (0.01-0.03); on steadily lit flights the RMS stays below 0.5 % (objects crossing the
/// view: up to 5 % for a second).
constexpr double kBandsFoundGain = 0.02, kBandsLostGain = 0.01, kBandsTimeConstantS = 3.0;

/// Knots of the row gains (brightness model kRows), within the supported range.
int rowKnotCount(const PhotometricParams& params) {
  return std::clamp(params.brightness_row_knots, 4, kMaxRowKnots);
}

/// Bounds of the pair's brightness gain and offset (normalised units: each image standardised
/// to zero mean and unit variance).
constexpr double kMinBrightnessGain = 0.25, kMaxBrightnessGain = 4.0, kMaxBrightnessOffset = 2.0;

/// Removes nuisance parameters from the state's information (the Schur complement, exact under a flat prior):
/// A - C D^-1 C^T, b - C D^-1 e, with C the parameters' cross terms with the observed columns (8 x n), D their
/// information (n x n) and e their score; `step` = D^-1 e, the parameters' step with the state held. A ridge of
/// 1e-9 tr D keeps D definite where a parameter has no column. Returns false (nothing changed) when D is not
/// positive definite or a result is not finite.
template <class CMat, class DMat, class EVec>
bool removeNuisance(const CMat& C, DMat D, const EVec& e, ObservedInfo* A, ObservedVec* b, EVec* step) {
  double trace = 0.0;
  for (int k = 0; k < D.rows(); ++k) trace += D(k, k);
  for (int k = 0; k < D.rows(); ++k) D(k, k) += 1e-9 * trace;
  const Eigen::LLT<DMat> llt(D);
  if (llt.info() != Eigen::Success) return false;
  using KMat = Eigen::Matrix<double, DMat::RowsAtCompileTime, 8, 0, DMat::MaxRowsAtCompileTime, 8>;
  const KMat K = llt.solve(C.transpose());  // D^-1 C^T
  const EVec s = llt.solve(e);
  if (!K.allFinite() || !s.allFinite()) return false;
  *A -= C * K;
  *A = (0.5 * (*A + A->transpose())).eval();
  *b -= K.transpose() * e;
  *step = s;
  return true;
}

/// Marginalises the pair's brightness (gain, and offset with `columns` = 2) from a sweep's information
/// (docs/noise_model.md section 12). With the brightness columns N = [I_r, 1] (the model's derivatives,
/// sqrt(w)-weighted in the sums), C = sum S^T N, D = sum N^T N and e = sum N^T r, the state's information is
/// A - C D^-1 C^T, b - C D^-1 e (A, b as accumulate() scales them: S = (dt / 2) S' T, times `scale`), and D^-1 e
/// is the brightness step with the state held. With the gain alone the offset's column is left out (its step 0).
/// Returns false (nothing changed) when D is singular.
bool marginalizeBrightness(const double (*G)[kGramCols], int columns, double scale, double half_dt,
                           const ObservedInfo& T, ObservedInfo* A, ObservedVec* b, Eigen::Vector2d* step) {
  Eigen::Matrix<double, 8, 2> C;
  for (int i = 0; i < 8; ++i) {
    C(i, 0) = G[i][9];
    C(i, 1) = columns > 1 ? G[i][10] : 0.0;
  }
  C = ((scale * half_dt) * (T.transpose() * C)).eval();
  Eigen::Matrix2d D;
  if (columns > 1) {
    D << G[9][9], G[9][10], G[9][10], G[10][10];
  } else {
    D << G[9][9], 0.0, 0.0, G[9][9];  // the offset's row uncoupled, its score 0: no step, no information
  }
  D *= scale;
  const Eigen::Vector2d e = scale * Eigen::Vector2d(G[8][9], columns > 1 ? G[8][10] : 0.0);
  if (!(D(0, 0) > 0.0) || !(D(1, 1) > 0.0) || !C.allFinite() || !D.allFinite() || !e.allFinite()) return false;
  return removeNuisance(C, D, e, A, b, step);
}

/// The same for the row gains (SweepConfig::row_gain; `knots` columns, the model's derivatives by the spline's
/// coefficients): C, D (banded) and e from the knots' sums GR, DR; `step` receives the coefficients' step with the
/// state held. Returns false (nothing changed) when D is not positive definite.
bool marginalizeRowGains(const SweepSums& sums, int knots, double scale, double half_dt, const ObservedInfo& T,
                         ObservedInfo* A, ObservedVec* b, BrightnessVec* step) {
  using KnotMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxRowKnots, kMaxRowKnots>;
  using CMat = Eigen::Matrix<double, 8, Eigen::Dynamic, 0, 8, kMaxRowKnots>;
  CMat C = CMat::Zero(8, knots);
  KnotMat D = KnotMat::Zero(knots, knots);
  BrightnessVec e = BrightnessVec::Zero(knots);
  for (int k = 0; k < knots; ++k) {
    for (int i = 0; i < 8; ++i) C(i, k) = sums.GR[i][k];
    e(k) = scale * sums.GR[8][k];
    for (int l = k; l < knots; ++l) D(k, l) = D(l, k) = scale * sums.DR[k][l];
  }
  C = ((scale * half_dt) * (T.transpose() * C)).eval();
  double trace = 0.0;
  for (int k = 0; k < knots; ++k) trace += D(k, k);
  if (!(trace > 0.0) || !C.allFinite() || !D.allFinite() || !e.allFinite()) return false;
  // A knot without pixels (all its rows invalid) has no column: the ridge keeps D definite, its step stays 0.
  return removeNuisance(C, D, e, A, b, step);
}

bool framesUsable(const PreprocessedFrame& ref, const PreprocessedFrame& cur, int border) {
  const cv::Mat* mats[6] = {&ref.intensity, &ref.grad_x, &ref.grad_y,
                            &cur.intensity, &cur.grad_x, &cur.grad_y};
  for (const cv::Mat* m : mats) {
    if (m->empty() || m->type() != CV_32FC1 || m->size() != cur.intensity.size()) return false;
  }
  return cur.intensity.cols > 2 * border + 3 && cur.intensity.rows > 2 * border + 3;
}

}  // namespace

PhotometricUpdate::PhotometricUpdate(const PhotometricParams& params, const PreprocessParams& preprocess)
    : params_(params), preprocess_(preprocess) {}

void PhotometricUpdate::setPreprocessNoise(double variance_gain, double correlation_area_px) {
  noise_variance_gain_ = std::isfinite(variance_gain) && variance_gain > 0.0 ? variance_gain : 1.0;
  noise_correlation_floor_ =
      std::isfinite(correlation_area_px) && correlation_area_px >= 1.0 ? correlation_area_px : 1.0;
}

int PhotometricUpdate::linearize(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                                 const Vec3& gyro_mean_C, double dt_s, const State& x, ObservedInfo* A,
                                 ObservedVec* b, int* candidates, double state_lag_s) {
  setReference(ref);
  effective_model_ = pairModel();
  prepareBuffers(cur.intensity.size());
  PassSums sums;
  const int valid = accumulate(cur, K, gyro_mean_C, dt_s, state_lag_s, x, params_.intensity_noise_sigma, &sums);
  const double inv_var = 1.0 / (params_.intensity_noise_sigma * params_.intensity_noise_sigma);
  *A = inv_var * sums.A;
  *b = inv_var * sums.b;
  if (candidates != nullptr) *candidates = sums.candidates;
  return valid;
}

BrightnessModel PhotometricUpdate::pairModel() const {
  // auto: the row gains while bands of the rows have been found (rowBanding), else the images at their grey
  // levels. Images that are not standardised (preprocess normalize_brightness false) are at their grey levels
  // already: kLevels is kNormalised for them.
  BrightnessModel model = params_.brightness_model != BrightnessModel::kAuto
                              ? params_.brightness_model
                              : (bands_found_ ? BrightnessModel::kRows : BrightnessModel::kLevels);
  if (model == BrightnessModel::kLevels && !preprocess_.normalize_brightness) model = BrightnessModel::kNormalised;
  return model;
}

void PhotometricUpdate::setReference(const PreprocessedFrame& ref) {
  internal::bSplineCoefficients(ref.intensity, splineDegree(), &ref_coeff_, &spline_scratch_);
  ref_level_offset_ = ref.level_offset;
  ref_grey_per_unit_ = ref.grey_per_unit;
}

void PhotometricUpdate::prepareBuffers(const cv::Size& size) {
  if (residual_.size() != size || residual_.type() != CV_32FC1) {
    residual_.create(size, CV_32FC1);
    residual_.setTo(0.0f);  // pixels the sweeps never visit (border, pixel_stride gaps) stay 0
    depth_jac_.create(size, CV_32FC1);
    depth_jac_.setTo(0.0f);
    ref_x_.create(size, CV_32FC1);
    ref_x_.setTo(-1.0f);
    ref_y_.create(size, CV_32FC1);
    ref_y_.setTo(-1.0f);
  }
  const int n_pad = (size.width + 3) & ~3;
  if (scratch_.rows != kGramCols + 5 || scratch_.cols < n_pad) scratch_.create(kGramCols + 5, n_pad, CV_32FC1);
}

void PhotometricUpdate::rowSpline(const BrightnessVec& c, int y, double g[3]) const {
  const int k0 = row_knot_[y];
  const float* a = &row_basis_[12 * y];
  g[0] = g[1] = g[2] = 0.0;
  for (int j = 0; j < 4; ++j)
    for (int n = 0; n < 3; ++n) g[n] += c(k0 + j) * a[3 * j + n];
}

void PhotometricUpdate::prepareRowKnots(int rows, const ImageTiming* timing) {
  const int knots = rowKnotCount(params_);
  const cv::Mat* pixel = timing != nullptr && timing->pixel_weight != nullptr &&
                                 timing->pixel_weight->type() == CV_32FC1 && timing->pixel_weight->rows >= rows &&
                                 !timing->pixel_weight->empty()
                             ? timing->pixel_weight
                             : nullptr;
  const float* row_weight = timing != nullptr && timing->row_weight != nullptr && timing->rows == rows
                                ? timing->row_weight
                                : nullptr;
  const size_t n = static_cast<size_t>(std::max(rows, 0));
  if (row_knot_.size() == n && row_knot_tables_knots_ == knots && row_knot_tables_pixel_ == pixel &&
      row_knot_tables_rows_ == row_weight)
    return;
  row_knot_tables_knots_ = knots;
  row_knot_tables_pixel_ = pixel;
  row_knot_tables_rows_ = row_weight;
  row_gain_.assign(3 * n, 0.0f);  // allocates only when the size, the knots or the timing change
  row_knot_.assign(n, 0);
  row_basis_.assign(12 * n, 0.0f);
  // Capture time per row (the raw rows' readout weight; without one, the working row as its proxy) and its
  // range over the image with the pixels' offsets: the spline's knots span it evenly.
  auto row_u = [&](int y) {
    return row_weight != nullptr ? static_cast<double>(row_weight[y])
                                 : (rows > 1 ? static_cast<double>(y) / (rows - 1) - 0.5 : 0.0);
  };
  double u_lo = 1e300, u_hi = -1e300;
  for (int y = 0; y < rows; ++y) {
    double lo = 0.0, hi = 0.0;
    if (pixel != nullptr) cv::minMaxLoc(pixel->row(y), &lo, &hi);
    u_lo = std::min(u_lo, row_u(y) + lo);
    u_hi = std::max(u_hi, row_u(y) + hi);
  }
  if (!(u_hi > u_lo)) u_hi = u_lo + 1.0;
  const double u_to_s = (knots - 3) / (u_hi - u_lo);
  row_gain_u_to_s_ = pixel != nullptr ? static_cast<float>(u_to_s) : 0.0f;
  for (int y = 0; y < rows; ++y) {
    const double s = std::clamp((row_u(y) - u_lo) * u_to_s, 0.0, static_cast<double>(knots - 3));
    const int k0 = std::min(knots - 4, static_cast<int>(std::floor(s)));
    const float t = static_cast<float>(s - k0);
    float w[4], dw[4];
    internal::cubicBSplineWeights(t, w, dw);
    const float half_d2w[4] = {0.5f * (1.0f - t), 1.5f * t - 1.0f, 0.5f * (1.0f - 3.0f * t), 0.5f * t};
    row_knot_[y] = k0;
    for (int j = 0; j < 4; ++j) {
      row_basis_[12 * y + 3 * j] = w[j];
      row_basis_[12 * y + 3 * j + 1] = dw[j];
      row_basis_[12 * y + 3 * j + 2] = half_d2w[j];
    }
  }
}

int PhotometricUpdate::accumulate(const PreprocessedFrame& cur, const PinholeK& K, const Vec3& gyro_mean_C,
                                  double dt_s, double state_lag_s, const State& x, double huber_sigma,
                                  PassSums* out, const ObservedVec* m_rows, const ImageTiming* timing,
                                  double readout_s, const BrightnessVec* brightness) {
  *out = PassSums();
  SweepConfig cfg = makeConfig(params_, preprocess_, huber_sigma);
  const int knots = rowKnotCount(params_);
  if (effective_model_ == BrightnessModel::kRows) {
    // Per row the spline's value, slope and half curvature from the knots' coefficients (gain 1 without them).
    prepareRowKnots(cur.intensity.rows, row_timing_);
    cfg.brightness_columns = 3;
    const bool given = brightness != nullptr && brightness->size() == knots;
    for (int y = 0; y < cur.intensity.rows; ++y) {
      double g[3] = {1.0, 0.0, 0.0};
      if (given) rowSpline(*brightness, y, g);
      for (int n = 0; n < 3; ++n) row_gain_[3 * y + n] = static_cast<float>(g[n]);
    }
    cfg.row_gain = row_gain_.data();
    cfg.row_knot = row_knot_.data();
    cfg.row_basis = row_basis_.data();
    cfg.row_gain_pixel = row_knot_tables_pixel_ != nullptr && row_knot_tables_pixel_->cols == cur.intensity.cols
                             ? row_knot_tables_pixel_
                             : nullptr;
    cfg.row_gain_u_to_s = row_gain_u_to_s_;
    cfg.ref_level = static_cast<float>(ref_level_offset_);
    cfg.cur_level = static_cast<float>(cur.level_offset);
  } else if (effective_model_ == BrightnessModel::kGain || effective_model_ == BrightnessModel::kAffine) {
    cfg.brightness_columns = effective_model_ == BrightnessModel::kAffine ? 2 : 1;
    const bool given = brightness != nullptr && brightness->size() == 2;
    cfg.gain = given ? static_cast<float>((*brightness)(0)) : 1.0f;
    cfg.offset = given && cfg.brightness_columns > 1 ? static_cast<float>((*brightness)(1)) : 0.0f;
  } else if (effective_model_ == BrightnessModel::kLevels && ref_grey_per_unit_ > 0.0 && cur.grey_per_unit > 0.0) {
    // The grey levels' relation I_c s_c + m_c = I_r s_r + m_r in the standardised units of the current image
    // (I = (grey - m) / s, level l = m / s): I_c = (s_r / s_c) (I_r + l_r) - l_c.
    const double gain = ref_grey_per_unit_ / cur.grey_per_unit;
    cfg.fixed_brightness = true;
    cfg.gain = static_cast<float>(gain);
    cfg.offset = static_cast<float>(gain * ref_level_offset_ - cur.level_offset);
  }
  cfg.confidence_map = active_map_;
  cfg.reference_weights = ref_map_;  // (update() points it only at maps of the current image's size)
  const bool rolling = m_rows != nullptr && timing != nullptr && timing->row_weight != nullptr &&
                       timing->rows == cur.intensity.rows && dt_s > 0.0 &&
                       (readout_s != 0.0 || timing->readoutColumn());
  if (rolling) {
    cfg.row_weight = timing->row_weight;
    const cv::Mat* pw = timing->pixel_weight;
    if (pw != nullptr && pw->type() == CV_32FC1 && pw->rows == kReadoutPixelPlanes * cur.intensity.rows &&
        pw->cols == cur.intensity.cols && cfg.stride == 1)
      cfg.pixel_weight = pw;
    cfg.readout_s = static_cast<float>(readout_s);
    // The row moments carry the readout's column and alpha's in the rows (section 3.7).
    cfg.row_moments = timing->readoutColumn() || readout_s != 0.0;
  }
  const PixelWarp wp(x, K, gyro_mean_C, dt_s, state_lag_s, rolling ? m_rows : nullptr);
  if (!wp.ok) return 0;  // the plane model breaks down within the interval: no measurement
  const Vec3 depth_dir = (0.5 * dt_s) * (wp.T.block<3, 3>(0, 0) * x.vartheta);
  for (int i = 0; i < 3; ++i) cfg.depth_dir[i] = static_cast<float>(depth_dir(i));
  const PixelOutputs outputs{&residual_, &depth_jac_, &ref_x_, &ref_y_};
  SweepSums sums;
  RowBuffers buf;
  for (int i = 0; i < kGramCols; ++i) buf.T[i] = scratch_.ptr<float>(i);
  buf.valid = scratch_.ptr<float>(kGramCols);
  for (int i = 0; i < 3; ++i) buf.cur[i] = scratch_.ptr<float>(kGramCols + 1 + i);
  buf.wmap = scratch_.ptr<float>(kGramCols + 4);
  const bool huber = cfg.huber_abs > 0.0f;
  auto run = [&](auto weight_map, auto taps) {
    constexpr bool kMap = decltype(weight_map)::value;
    constexpr int kTaps = decltype(taps)::value;
    if (huber && cfg.gradient_weighting) {
      sweep<true, true, kMap, kTaps>(ref_coeff_, cur, wp, cfg, buf, &sums, outputs);
    } else if (huber) {
      sweep<true, false, kMap, kTaps>(ref_coeff_, cur, wp, cfg, buf, &sums, outputs);
    } else if (cfg.gradient_weighting) {
      sweep<false, true, kMap, kTaps>(ref_coeff_, cur, wp, cfg, buf, &sums, outputs);
    } else {
      sweep<false, false, kMap, kTaps>(ref_coeff_, cur, wp, cfg, buf, &sums, outputs);
    }
  };
  auto run_taps = [&](auto weight_map) {
    if (splineDegree() == 5) {
      run(weight_map, std::integral_constant<int, 6>{});
    } else {
      run(weight_map, std::integral_constant<int, 4>{});
    }
  };
  if (cfg.confidence_map != nullptr || cfg.reference_weights != nullptr) {
    run_taps(std::true_type{});
  } else {
    run_taps(std::false_type{});
  }

  // Scale: the sweep's rows are 2/dt times the true S (gradient sum instead of mean, Jacobian without dt);
  // times the gradient normalisation (weights |grad I_c| / mean |grad I_c| over the valid pixels) when enabled.
  // No 1/sigma^2 here: the noise model applies it (update(), linearize()).
  double scale = 1.0;
  if (cfg.gradient_weighting) scale *= sums.grad_sum > 0.0 ? sums.valid / sums.grad_sum : 0.0;
  const double half_dt = 0.5 * dt_s;
  const double sA = scale * half_dt * half_dt;
  const double sb = scale * half_dt;
  ObservedInfo& A = out->A;
  ObservedVec& b = out->b;
  for (int i = 0; i < 8; ++i) {
    for (int j = i; j < 8; ++j) A(i, j) = A(j, i) = sA * sums.G[i][j];
    b(i) = sb * sums.G[i][8];
  }
  // The sweep's rows are S' with S = (dt / 2) S' T (the dt / 2 is in sA and sb above).
  A = (wp.T.transpose() * A * wp.T).eval();
  A = (0.5 * (A + A.transpose())).eval();
  b = (wp.T.transpose() * b).eval();
  if (cfg.row_gain != nullptr) {
    out->has_brightness = marginalizeRowGains(sums, knots, scale, half_dt, wp.T, &A, &b, &out->brightness_step);
  } else if (cfg.brightness_columns > 0) {
    Eigen::Vector2d step;
    out->has_brightness =
        marginalizeBrightness(sums.G, cfg.brightness_columns, scale, half_dt, wp.T, &A, &b, &step);
    out->brightness_step = step;
  }
  if (cfg.row_moments) {
    // The readout's information (docs/algorithm.md section 3.7): its column is w_y S m, so it needs the row
    // moments sum w S^T S, sum w^2 S^T S and sum w S^T r, scaled and turned like A and b.
    for (int i = 0; i < 8; ++i) {
      for (int j = i; j < 8; ++j) {
        out->A1(i, j) = out->A1(j, i) = sA * sums.G1[i][j];
        out->A2(i, j) = out->A2(j, i) = sA * sums.G2[i][j];
      }
      out->b1(i) = sb * sums.G1[i][8];
    }
    out->A1 = (wp.T.transpose() * out->A1 * wp.T).eval();
    out->A2 = (wp.T.transpose() * out->A2 * wp.T).eval();
    out->b1 = (wp.T.transpose() * out->b1).eval();
    out->has_moments = true;
  }
  out->valid = sums.valid;
  out->candidates = sums.candidates;
  out->sum_r2 = sums.sum_r2;
  out->weight_sum = sums.sum_w;
  out->mean_residual = sums.sum_w > 0.0 ? sums.sum_r / sums.sum_w : 0.0;
  out->robust_sigma = sums.sum_w > 0.0 ? std::sqrt(0.5 * 3.14159265358979323846) * sums.sum_abs_r / sums.sum_w : 0.0;

  // Score correlation (docs/noise_model.md): with independent pixels of variance s^2 the tile scores b_t are
  // independent with covariance s^2 A_t, so sum_t (b_t - f_t b)^T A^-1 (b_t - f_t b) has the expectation
  // s^2 tr(A^-1 A) (1 - sum_t f_t^2) (f_t: the tile's share of the valid pixels; subtracting f_t b removes
  // the part common to all tiles, e.g. the innovation of the prior). Its ratio to that expectation, with s the
  // robust residual scale, is the number of pixels that carry one pixel's worth of independent information.
  out->correlation = 1.0;
  const int tiles = std::clamp(cfg.tiles_x, 1, kMaxTilesPerAxis) * std::clamp(cfg.tiles_y, 1, kMaxTilesPerAxis);
  const double s2 = out->robust_sigma * out->robust_sigma;
  if (sums.valid > 0 && s2 > 0.0) {
    const double ridge = 1e-9 * std::max(1e-300, A.trace()) + 1e-300;
    const Eigen::LDLT<ObservedInfo> ldlt(A + ridge * ObservedInfo::Identity());
    if (ldlt.info() == Eigen::Success) {
      const ObservedInfo M = ldlt.solve(ObservedInfo::Identity());
      const double dof = (M * A).trace();
      double phi = 0.0, f2 = 0.0;
      for (int t = 0; t < tiles; ++t) {
        if (sums.tile_n[t] <= 0.0) continue;
        const double f = sums.tile_n[t] / sums.valid;
        ObservedVec bt;
        for (int i = 0; i < 8; ++i) bt(i) = sb * sums.tile_b[t][i];
        bt = (wp.T.transpose() * bt).eval() - f * b;
        phi += bt.dot(M * bt);
        f2 += f * f;
      }
      const double expected = s2 * dof * (1.0 - f2);
      if (expected > 0.0 && std::isfinite(phi)) out->correlation = phi / expected;
    }
  }
  return sums.valid;
}

namespace {

/// NIS of the innovation score b (information A) against the prior covariance P_o of the observed states, as a
/// function of a noise inflation gamma: NIS(gamma) = b^T (gamma A + A P_o A)^-1 b. With A = L L^T (Cholesky, a
/// tiny ridge for directions the image does not see) and L^T P_o L = U diag(m) U^T, gamma A + A P_o A =
/// L U (gamma I + diag(m)) U^T L^T, so NIS(gamma) = sum_i z_i^2 / (gamma + m_i) with z = U^T L^-1 b: one
/// factorisation, then every gamma costs 8 divisions.
struct InnovationSpectrum {
  ObservedVec z2 = ObservedVec::Zero();
  ObservedVec m = ObservedVec::Zero();
  bool ok = false;

  InnovationSpectrum(const ObservedInfo& A, const ObservedInfo& P_o, const ObservedVec& b) {
    const ObservedInfo Ar = A + (1e-12 * std::max(1e-300, A.trace())) * ObservedInfo::Identity();
    const Eigen::LLT<ObservedInfo> llt(Ar);
    if (llt.info() != Eigen::Success) return;
    const ObservedInfo L = llt.matrixL();
    const ObservedInfo C = L.transpose() * P_o * L;
    const Eigen::SelfAdjointEigenSolver<ObservedInfo> eig(0.5 * (C + C.transpose()));
    if (eig.info() != Eigen::Success) return;
    const ObservedVec z = eig.eigenvectors().transpose() * llt.matrixL().solve(b);
    z2 = z.cwiseProduct(z);
    m = eig.eigenvalues().cwiseMax(0.0);
    ok = z2.allFinite() && m.allFinite();
  }
  double nis(double gamma) const {
    if (!ok) return std::numeric_limits<double>::quiet_NaN();
    return (z2.array() / (gamma + m.array())).sum();
  }
  /// The inflation at which NIS equals `target` (NIS falls monotonically with gamma); in [1e-6, 1e12].
  double inflationFor(double target) const {
    double lo = std::log(1e-6), hi = std::log(1e12);
    for (int it = 0; it < 48; ++it) {
      const double mid = 0.5 * (lo + hi);
      if (nis(std::exp(mid)) > target) lo = mid; else hi = mid;
    }
    return std::exp(0.5 * (lo + hi));
  }
};

/// Removes from the image's information (A, b) what it says about a per-frame error of the interval rotation
/// (docs/noise_model.md, section 6). The warp takes the rotation from the gyro; a rotation error theta of the
/// interval moves the pixels as the b_w columns do with delta b_w = -theta / dt (to first order), so an error
/// theta ~ N(0, var_theta I), independent per frame, is a nuisance parameter on those columns with the prior
/// variance var_bw = var_theta / dt^2. Marginalising it (Schur complement) leaves
///   A' = A - A_.w (A_ww + I / var_bw)^-1 A_w.,   b' = b - A_.w (A_ww + I / var_bw)^-1 b_w,
/// the information of the image about everything else, with the rotation-like part of the flow discounted.
/// The same for the system extended by the rolling shutter's columns (the readout's, alpha's; indices 8, 9): the
/// nuisance enters like b_w there too.
template <int N>
void marginalizeRotationError(double var_bw, Eigen::Matrix<double, N, N>* A, Eigen::Matrix<double, N, 1>* b) {
  if (!(var_bw > 0.0) || !std::isfinite(var_bw)) return;
  constexpr int w0 = 5;  // first b_w column of the observed block
  const Eigen::Matrix<double, N, 3> A_xw = A->template block<N, 3>(0, w0);
  const Mat3 S = A->template block<3, 3>(w0, w0) + (1.0 / var_bw) * Mat3::Identity();
  const Eigen::LLT<Mat3> llt(S);
  if (llt.info() != Eigen::Success) return;
  const Eigen::Matrix<double, 3, N> G = llt.solve(A_xw.transpose());  // S^-1 A_w.
  *A -= A_xw * G;
  *A = (0.5 * (*A + A->transpose())).eval();
  *b -= G.transpose() * b->template segment<3>(w0);
}

/// The rolling-shutter rows' dependence on alpha (docs/algorithm.md section 3.7) as a nuisance: column k of the
/// extended system (A, b) is w_y S m_a, m_a = T_ro (a + g0 g, 0, ..., 0), the derivative of the rows' shift by
/// alpha; with alpha's prior variance var_alpha it is marginalised like the rotation error (Schur complement),
///   A' = A - A_.k A_k. / (A_kk + 1 / var_alpha),   b' = b - A_.k b_k / (A_kk + 1 / var_alpha),
/// and its row and column cleared: the rows' prediction is widened by alpha's uncertainty, alpha is not moved by it.
template <int N>
void marginalizeRowsAlpha(int k, double var_alpha, Eigen::Matrix<double, N, N>* A, Eigen::Matrix<double, N, 1>* b) {
  if (!(var_alpha > 0.0) || !std::isfinite(var_alpha)) return;
  const double s = (*A)(k, k) + 1.0 / var_alpha;
  const Eigen::Matrix<double, N, 1> c = A->col(k);
  *A -= c * c.transpose() / s;
  *b -= c * ((*b)(k) / s);
  A->row(k).setZero();
  A->col(k).setZero();
  (*b)(k) = 0.0;
}

/// The image's own measurement of vartheta (UpdateStats::vartheta_image): from the last pass's information (A, b)
/// at x_j, with the prior of (mu, b_w) only (P_other; its right-hand side -P_other^-1 (x_j [-] x_prior)), the
/// Schur complement onto vartheta gives I z = r; the measurement is x_j.vartheta + z, its covariance I^-1.
void imageOnlyVartheta(const ObservedInfo& A, const ObservedVec& b, const State& x_j, const State& x_prior,
                       const Eigen::Matrix<double, 5, 5>& P_other, UpdateStats* stats) {
  const Eigen::LDLT<Eigen::Matrix<double, 5, 5>> prior(P_other);
  if (prior.info() != Eigen::Success || !prior.isPositive()) return;
  const ErrorVec e = x_j.boxminus(x_prior);
  Eigen::Matrix<double, 5, 1> e_o;
  for (int r = 0; r < 5; ++r) e_o(r) = e(internal::kObsToErr[3 + r]);
  const Eigen::Matrix<double, 5, 5> L_oo =
      A.bottomRightCorner<5, 5>() + prior.solve(Eigen::Matrix<double, 5, 5>::Identity());
  const Eigen::Matrix<double, 5, 1> r_o = b.tail<5>() - prior.solve(e_o);
  const Eigen::LLT<Eigen::Matrix<double, 5, 5>> llt_o(L_oo);
  if (llt_o.info() != Eigen::Success) return;
  const Eigen::Matrix<double, 5, 3> G = llt_o.solve(A.bottomLeftCorner<5, 3>());  // L_oo^-1 A_o.vartheta
  const Mat3 I = A.topLeftCorner<3, 3>() - A.topRightCorner<3, 5>() * G;
  const Vec3 r = b.head<3>() - G.transpose() * r_o;
  const Eigen::LLT<Mat3> llt(0.5 * (I + I.transpose()));
  if (llt.info() != Eigen::Success) return;
  const Mat3 cov = llt.solve(Mat3::Identity());
  const Vec3 z = x_j.vartheta + llt.solve(r);
  if (!cov.allFinite() || !z.allFinite()) return;
  stats->vartheta_image_valid = true;
  stats->vartheta_image = z;
  stats->vartheta_image_cov = cov;
}

}  // namespace

UpdateStats PhotometricUpdate::update(const PreprocessedFrame& ref, const PreprocessedFrame& cur,
                                      const PinholeK& K, const Vec3& gyro_mean_C, double dt_s, State* x,
                                      ErrorCov* P, double state_lag_s, const ImageTiming& timing) {
  UpdateStats stats;
  const SweepConfig cfg = makeConfig(params_, preprocess_, params_.intensity_noise_sigma);
  if (x == nullptr || P == nullptr || !framesUsable(ref, cur, cfg.border) || !(dt_s > 0.0) ||
      !std::isfinite(dt_s) || !gyro_mean_C.allFinite() || !x->allFinite() || !P->allFinite() ||
      !(params_.intensity_noise_sigma > 0.0)) {
    return stats;
  }
  prepareBuffers(cur.intensity.size());  // no-op after the first call at this size
  // The row gains' capture times (brightness model kRows) are this update's timing's, for its sweeps only.
  struct TimingScope {
    const ImageTiming** slot;
    ~TimingScope() { *slot = nullptr; }
  } timing_scope{&row_timing_};
  row_timing_ = &timing;
  effective_model_ = pairModel();
  stats.row_gains = effective_model_ == BrightnessModel::kRows;
  // Outlier weights from the previous update's residual (section 10), when that update's current image is this
  // one's reference: they belong to the reference's pixels and are sampled where the warp lands, so they move
  // with the objects. A map without any weight below 1 changes nothing: the plain sweep is used (bit for bit,
  // and cheaper).
  use_weight_map_ = params_.outlier_threshold_sigma > 0.0 && weight_map_has_outliers_ && weightsBelongTo(ref);
  setReference(ref);  // once per update, every pass
  // The camera-fixed pattern's confidence, per pixel of the current image (docs/noise_model.md section 11).
  active_map_ = confidence_ != nullptr && confidence_->type() == CV_32FC1 && confidence_->size() == cur.intensity.size()
                    ? confidence_ : nullptr;
  // The reference's weights, sampled where the warp lands: its outlier weights, times its confidence where given.
  ref_map_ = use_weight_map_ && weight_map_.type() == CV_32FC1 && weight_map_.size() == cur.intensity.size()
                 ? &weight_map_
                 : nullptr;
  if (ref_confidence_ != nullptr && ref_confidence_->type() == CV_32FC1 &&
      ref_confidence_->size() == cur.intensity.size()) {
    if (ref_map_ != nullptr) {
      cv::multiply(weight_map_, *ref_confidence_, ref_map_buf_);  // (allocates once: same size every time)
      ref_map_ = &ref_map_buf_;
    } else {
      ref_map_ = ref_confidence_;
    }
  }

  // Prior covariance of what the image observes, H P H^T with H = [observed columns | m] (the time offset
  // enters as the combination m of the observed columns; for the innovation test of the first pass).
  // The focal-length scale (section 3.8) enters the same way, as the combination m_f.
  const double t_d_prior_s = x->t_d_s;
  const ObservedVec m_prior = timeOffsetMap(*x, gyro_mean_C, timing, dt_s);
  const ObservedVec mf_prior = timing.estimate_focal_scale
                                   ? focalScaleMap(*x, scaledFocal(K, x->focal_scale), gyro_mean_C, dt_s, state_lag_s)
                                   : ObservedVec::Zero();
  Eigen::Matrix<double, internal::kObsDim, kErrorDim> H_obs = Eigen::Matrix<double, internal::kObsDim, kErrorDim>::Zero();
  for (int r = 0; r < internal::kObsDim; ++r) H_obs(r, internal::kObsToErr[r]) = 1.0;
  H_obs.col(ErrIdx::kTd) = m_prior;
  H_obs.col(ErrIdx::kFs) = mf_prior;
  const Eigen::Matrix<double, internal::kObsDim, kErrorDim> HP = H_obs * (*P);
  ObservedInfo P_obs = HP * H_obs.transpose();

  const bool adaptive = params_.adaptive_noise;
  // Per-pixel noise the Huber threshold refers to: the smoothed estimate once there is one.
  const double huber_sigma = adaptive && noise_.valid ? std::sqrt(noise_.variance) : params_.intensity_noise_sigma;
  // Floor of the per-pixel variance: sensor noise through resampling and blur, in both images of the pair.
  const double grey = cur.grey_per_unit > 0.0 ? cur.grey_per_unit : 255.0;
  const double floor_var =
      2.0 * params_.sensor_noise_grey * params_.sensor_noise_grey * noise_variance_gain_ / (grey * grey);
  pending_nis_scale_ = adaptive && noise_.valid ? noise_.nis_scale : 1.0;
  const double alpha_ema = params_.noise_time_constant_s > 0.0 ? 1.0 - std::exp(-dt_s / params_.noise_time_constant_s)
                                                               : 1.0;

  // Model error of the gyro's interval rotation (section 6): a relative scale error of its angle and a time
  // offset error times the change of the rate between consecutive intervals.
  const Vec3 rate_C = gyro_mean_C - x->b_w;  // rad/s
  const Vec3 rate_change = last_rate_valid_ ? Vec3(rate_C - last_rate_C_) : Vec3::Zero();
  const double var_theta =
      std::pow(params_.rotation_scale_sigma * dt_s, 2) * rate_C.squaredNorm() +
      std::pow(params_.time_offset_sigma_s, 2) * rate_change.squaredNorm() +
      timing.gyro_noise_density_sq * dt_s;  // rad^2
  const double var_bw_equiv = var_theta / (dt_s * dt_s);                        // (rad/s)^2
  last_rate_C_ = rate_C;
  last_rate_valid_ = true;

  double info_scale = 0.0;  // 1 / (sigma^2 c gamma): fixed at the first pass, used by every pass
  int pass = 0;
  // vartheta_image, only when asked for: the prior state and its (mu, b_w) block, and the last pass's information
  // over the observed columns with the point it was linearised at.
  const bool image_only = report_image_vartheta_;
  ObservedInfo A_last = ObservedInfo::Zero();
  ObservedVec b_last = ObservedVec::Zero();
  State x_last, x_prior;
  Eigen::Matrix<double, 5, 5> P_other = Eigen::Matrix<double, 5, 5>::Zero();
  if (image_only) {
    x_prior = *x;
    for (int r = 0; r < 5; ++r)
      for (int c = 0; c < 5; ++c) P_other(r, c) = (*P)(internal::kObsToErr[3 + r], internal::kObsToErr[3 + c]);
  }
  // The pair's brightness (gain, offset), section 12: from (1, 0), stepped after every linearisation to its best
  // value with the state held there (the state's steps see it marginalised).
  BrightnessVec brightness;
  if (effective_model_ == BrightnessModel::kRows) {
    brightness.setOnes(rowKnotCount(params_));
  } else {
    brightness.resize(2);
    brightness << 1.0, 0.0;
  }
  PassSums sums;
  // The time states before the update (offset, readout, focal scale), kept when the frame may not move them.
  const double readout_before_s = x->readout_s, focal_scale_before = x->focal_scale;  // (the offset: t_d_prior_s)
  const Eigen::Matrix<double, ErrIdx::kTimeStates, ErrIdx::kTimeStates> P_time_before =
      P->block<ErrIdx::kTimeStates, ErrIdx::kTimeStates>(ErrIdx::kTd, ErrIdx::kTd);
  bool time_states_frozen = false;
  const double var_alpha_prior = (*P)(ErrIdx::kAlpha, ErrIdx::kAlpha);  // (1/m)^2
  const double var_readout_prior = std::max(0.0, (*P)(ErrIdx::kRo, ErrIdx::kRo));  // s^2
  // Every pass writes the residual image; the RMS and the valid ratio are those of the last linearisation.
  auto linearize_at = [&](const State& x_j, internal::ObsMat* A, internal::ObsVec* b, internal::ObsVec* m,
                          internal::ExtraColumn* readout, internal::CalibrationColumns* calib) {
    // The time states of the iterate; once the frame holds them (from its first pass, below), the prior's: its later
    // passes see them where the update leaves them.
    const double t_d_j = time_states_frozen ? t_d_prior_s : x_j.t_d_s;
    const double readout_j = time_states_frozen || timing.consider_readout ? readout_before_s : x_j.readout_s;
    const double focal_scale_j = time_states_frozen ? focal_scale_before : x_j.focal_scale;
    // A time offset changed by e within the update: the image sees the state and the gyro window of e later.
    *m = timeOffsetMap(x_j, gyro_mean_C, timing, dt_s);
    const State x_seen = shiftedAlong(x_j, *m, t_d_j - t_d_prior_s);
    // The iterate's focal lengths (section 3.8).
    const PinholeK K_j = scaledFocal(K, focal_scale_j);
    calib->m[0] = timing.estimate_focal_scale ? focalScaleMap(x_seen, K_j, gyro_mean_C, dt_s, state_lag_s)
                                              : ObservedVec::Zero();
    // Rolling shutter: every row with the motion at its own time (the readout of the iterate); while the readout is
    // estimated, from the expected rates given their readings (docs/algorithm.md section 3.7).
    const bool rolling = timing.rates_valid && timing.row_weight != nullptr &&
                         (readout_j != 0.0 || timing.readoutColumn());
    const ObservedVec m_rows =
        rolling ? stateRateMap(x_seen, gyro_mean_C, timing, dt_s, timing.estimate_readout) : ObservedVec::Zero();
    // The rows' shift depends on alpha through m_rows's alpha (a + g0 g): its column w_y S m_alpha, marginalised
    // below with alpha's prior variance (marginalizeRowsAlpha). Before convergence alpha is barely known and the rows
    // predicted from it were taken as exact: a flight at 0.84 m started at 0.33 m predicted 2.5 times the rows'
    // shift in its first climb, the update's NIS reached 273 and the distance was 15-20 cm off for 10 s.
    // With the readout's column in the update (estimated or considered) the readout is uncertain too, and the rows'
    // dependence on alpha is that of a product of two uncertain states: its spread is that of alpha times the
    // readout's root mean square sqrt(readout^2 + var_readout), not its mean. A readout estimated from the first
    // image (section 3.7) starts at 0 +- 10 ms with alpha unknown, and with its mean alone the rows' alpha was not
    // widened at all (fast flights of 5 s, 16 ms readout: 1.72 / 1.11 times the global-shutter errors; 1.53 / 1.05).
    const double readout_rms_s =
        timing.readoutColumn() ? std::sqrt(readout_j * readout_j + var_readout_prior) : readout_j;
    ObservedVec m_alpha = ObservedVec::Zero();
    if (rolling && readout_rms_s != 0.0)
      m_alpha.head<3>() = readout_rms_s * stateRateAcceleration(x_seen, timing, timing.estimate_readout);
    // The image's information over the observed columns (A_out, b_out) with the rotation error marginalised. With
    // the rows' moments the system is extended by the readout's column w_y S m_rows (`with_readout`; its terms go to
    // `ro`) and by alpha's in the rows w_y S m_alpha (indices 8, 9), alpha's marginalised with its prior variance.
    auto information = [&](bool with_readout, ObservedInfo* A_out, ObservedVec* b_out, internal::ExtraColumn* ro) {
      const ObservedVec* columns[2] = {with_readout && sums.has_moments ? &m_rows : nullptr,
                                       sums.has_moments && !m_alpha.isZero(0.0) ? &m_alpha : nullptr};
      if (columns[0] == nullptr && columns[1] == nullptr) {
        *A_out = info_scale * sums.A;
        *b_out = info_scale * sums.b;
        marginalizeRotationError(var_bw_equiv, A_out, b_out);
        return;
      }
      Eigen::Matrix<double, 10, 10> Ae = Eigen::Matrix<double, 10, 10>::Zero();
      Eigen::Matrix<double, 10, 1> be = Eigen::Matrix<double, 10, 1>::Zero();
      Ae.topLeftCorner<8, 8>() = info_scale * sums.A;
      be.head<8>() = info_scale * sums.b;
      for (int k = 0; k < 2; ++k) {
        if (columns[k] == nullptr) continue;
        const ObservedVec& mk = *columns[k];
        const ObservedVec cross = info_scale * (sums.A1 * mk);
        Ae.block<8, 1>(0, 8 + k) = cross;
        Ae.block<1, 8>(8 + k, 0) = cross.transpose();
        for (int l = 0; l < 2; ++l)
          if (columns[l] != nullptr) Ae(8 + k, 8 + l) = info_scale * mk.dot(sums.A2 * *columns[l]);
        be(8 + k) = info_scale * mk.dot(sums.b1);
      }
      marginalizeRotationError(var_bw_equiv, &Ae, &be);
      if (columns[1] != nullptr) marginalizeRowsAlpha(9, var_alpha_prior, &Ae, &be);
      *A_out = Ae.topLeftCorner<8, 8>();
      *b_out = be.head<8>();
      if (columns[0] != nullptr && ro != nullptr) {
        ro->active = true;
        ro->cross = Ae.block<8, 1>(0, 8);
        ro->diag = Ae(8, 8);
        ro->rhs = be(8);
      }
    };
    // One sweep at this iterate with the current brightness, then the brightness's step (state held).
    auto sweep_here = [&]() {
      const int n_valid = accumulate(cur, K_j, gyro_mean_C, dt_s, state_lag_s, x_seen, huber_sigma, &sums,
                                     rolling ? &m_rows : nullptr, rolling ? &timing : nullptr, readout_j,
                                     &brightness);
      if (sums.has_brightness && sums.brightness_step.size() == brightness.size()) {
        brightness += sums.brightness_step;
        if (effective_model_ == BrightnessModel::kRows) {
          brightness = brightness.cwiseMax(kMinBrightnessGain).cwiseMin(kMaxBrightnessGain);
          stats.brightness_gain = brightness.mean();
          stats.brightness_row_spread = brightness.maxCoeff() - brightness.minCoeff();
        } else {
          brightness(0) = std::clamp(brightness(0), kMinBrightnessGain, kMaxBrightnessGain);
          brightness(1) = std::clamp(brightness(1), -kMaxBrightnessOffset, kMaxBrightnessOffset);
          stats.brightness_gain = brightness(0);
          stats.brightness_offset = brightness(1);
        }
      }
      return n_valid;
    };
    int valid = sweep_here();
    // Levels (section 12): a mean residual of the first linearisation above light_change_threshold of the current
    // image's level is a change of the light or the exposure, not motion: this pair is compared as standardised.
    if (pass == 0 && effective_model_ == BrightnessModel::kLevels &&
        std::abs(sums.mean_residual) > params_.light_change_threshold * std::abs(cur.level_offset)) {
      effective_model_ = BrightnessModel::kNormalised;
      stats.light_change = true;
      valid = sweep_here();
    }
    // Row gains (section 12): a pair under flickering light starts far from its gains (the bands of the two
    // images are unrelated), and this pass's residual, noise and outlier statistics would be those of the bands.
    // The first pass is therefore linearised again, at the same state, with the gains just fitted while they
    // still move (at most twice more; on a steadily lit pair their first step is small: one sweep as before).
    if (pass == 0 && effective_model_ == BrightnessModel::kRows) {
      for (int refit = 0; refit < 2 && sums.has_brightness &&
                          sums.brightness_step.cwiseAbs().maxCoeff() > kRowGainRefitStep;
           ++refit)
        valid = sweep_here();
    }
    stats.valid_ratio = sums.candidates > 0 ? static_cast<double>(valid) / sums.candidates : 0.0;
    stats.rms_residual = valid > 0 ? std::sqrt(sums.sum_r2 / valid) : 0.0;
    stats.residual_sigma = sums.robust_sigma;
    stats.correlation = sums.correlation;
    stats.noise_floor_sigma = std::sqrt(floor_var);
    if (!(valid > 0 && stats.valid_ratio >= params_.min_valid_ratio)) return false;
    if (pass == 0) {
      double var, corr;
      if (!adaptive) {
        var = params_.intensity_noise_sigma * params_.intensity_noise_sigma;
        corr = 1.0;
      } else {
        // This frame's estimates, blended into the smoothed ones (alone on the first frame).
        const double var_frame = sums.robust_sigma * sums.robust_sigma;
        const double corr_frame = std::isfinite(sums.correlation) ? sums.correlation : 1.0;
        var = noise_.valid ? (1.0 - alpha_ema) * noise_.variance + alpha_ema * var_frame : var_frame;
        corr = noise_.valid ? (1.0 - alpha_ema) * noise_.correlation + alpha_ema * corr_frame : corr_frame;
        var = std::max(var, floor_var);
        corr = std::max(corr, noise_correlation_floor_);
      }
      if (!(var > 0.0) || !std::isfinite(var) || !std::isfinite(corr)) return false;
      const double lambda = adaptive && noise_.valid ? noise_.nis_scale : 1.0;
      stats.noise_sigma = std::sqrt(var);
      stats.noise_correlation = corr;
      stats.nis_scale = lambda;
      info_scale = 1.0 / (var * corr * lambda);
      // Innovation gate: NIS = b^T (A + A P A)^-1 b ~ chi-square(8) for a consistent filter.
      ObservedInfo A0;
      ObservedVec b0;
      information(false, &A0, &b0, nullptr);  // (the rows' alpha as in the update: its uncertainty is the prior's)
      const InnovationSpectrum spectrum(A0, P_obs, b0);
      stats.nis = spectrum.nis(1.0);
      if (adaptive && params_.nis_time_constant_s > 0.0 && std::isfinite(stats.nis) && stats.nis > 0.0) {
        // Innovation-based adaptation: the noise scale at which this frame's NIS would be its mean (8), smoothed
        // in log over nis_time_constant_s and never below 1 (the model of sections 2-3 is the floor). Frames
        // at the gate count at the gate's level only, so that one bad frame cannot inflate the noise for long.
        const double cap = params_.gate_nis > 0.0 ? std::max(params_.gate_nis, 8.0) : HUGE_VAL;
        const double frame_inflation = spectrum.inflationFor(8.0 * std::max(1.0, stats.nis / cap));
        const double a = 1.0 - std::exp(-dt_s / params_.nis_time_constant_s);
        const double log_next = std::log(lambda) + a * std::log(std::max(1e-6, frame_inflation));
        pending_nis_scale_ = std::min(1e6, std::max(1.0, std::exp(log_next)));
      }
      if (params_.gate_nis > 0.0 && stats.nis > params_.gate_nis) {
        // Down-weight until the NIS equals the target.
        stats.gate_inflation = spectrum.inflationFor(params_.gate_target_nis);
        stats.gated = true;
        info_scale /= stats.gate_inflation;
      }
    }
    // A frame the innovation test flags does not move the time states (offset, readout, focal scale): they are slow
    // properties of the sensors, and a wrong frame's innovation projected on their columns would be taken for them.
    // Nor does a frame whose NIS lies above its 95 % quantile (kTimeStatesMaxNis): a model error building up (a
    // fast dash below the gate) dragged the offset by 9 ms and the readout by 7 ms (docs/algorithm.md section 3.6).
    const bool freeze = stats.gated || stats.nis > kTimeStatesMaxNis;
    if (freeze) {
      m->setZero();
      calib->setZero();
      time_states_frozen = true;
    }
    information(rolling && !freeze && timing.readoutColumn(), A, b, readout);
    if (image_only) {
      A_last = *A;
      b_last = *b;
      x_last = x_j;
    }
    ++pass;
    return true;
  };
  const internal::IterationResult it = internal::iterateInformationForm(
      params_.max_passes, params_.stop_threshold, linearize_at, x, P);
  // Time states held as consider states (Schmidt): their means and their own block of the covariance put back to
  // the prior's; the other states' update and every cross-covariance stay the Kalman update's (their gains do not
  // involve the held states' rows).
  auto hold = [&](std::initializer_list<int> held) {
    for (int i : held) {
      if (i == ErrIdx::kTd) x->t_d_s = t_d_prior_s;
      if (i == ErrIdx::kRo) x->readout_s = readout_before_s;
      if (i == ErrIdx::kFs) x->focal_scale = focal_scale_before;
      for (int j : held) (*P)(i, j) = P_time_before(i - ErrIdx::kTd, j - ErrIdx::kTd);
    }
  };
  if (it.ok && !time_states_frozen && timing.readout_with_considered_offset) {
    // The offset (considered) and the focal scale held, the readout estimated.
    hold({ErrIdx::kTd, ErrIdx::kFs});
    stats.offset_held = true;
  } else if (it.ok && (time_states_frozen || timing.consider_offset)) {
    // Without their columns the frame still moved the time states through their correlations with the observed
    // ones: all three held. An offset not yet estimated (consider_offset) is held the same way, with its column in
    // the update (the readout and the focal scale are not estimated then either, but for the readout above).
    hold({ErrIdx::kTd, ErrIdx::kRo, ErrIdx::kFs});
    stats.time_states_held = true;
  } else if (it.ok && timing.consider_readout) {
    // The readout alone held.
    hold({ErrIdx::kRo});
    stats.readout_held = true;
  }
  // The focal scale as a consider parameter (Schmidt-Kalman): the other states' rows of the full update are the
  // optimal gain with it considered; its own mean and variance put back, on their own (its cross-covariance with a
  // time state held above stays that hold's).
  if (it.ok && timing.consider_focal_scale) hold({ErrIdx::kFs});
  use_weight_map_ = false;
  active_map_ = nullptr;
  ref_map_ = nullptr;
  stats.applied = it.ok;
  if (image_only && it.ok && !stats.gated) imageOnlyVartheta(A_last, b_last, x_last, x_prior, P_other, &stats);
  stats.outlier_fraction = sums.valid > 0 ? std::clamp(1.0 - sums.weight_sum / sums.valid, 0.0, 1.0) : 0.0;
  stats.passes = it.passes;
  stats.last_step_norm = it.last_step_norm;
  // Smoothed noise estimates from the last linearisation (the closest to the converged residual).
  if (adaptive && pass > 0 && sums.valid > 0 && sums.robust_sigma > 0.0 && std::isfinite(sums.correlation)) {
    const double var_frame = sums.robust_sigma * sums.robust_sigma;
    noise_.nis_scale = pending_nis_scale_;
    if (!noise_.valid) {
      noise_.variance = var_frame;
      noise_.correlation = sums.correlation;
      noise_.valid = true;
    } else {
      noise_.variance += alpha_ema * (var_frame - noise_.variance);
      noise_.correlation += alpha_ema * (sums.correlation - noise_.correlation);
    }
  }
  if (pass > 0 && sums.valid > 0) {
    const double var = adaptive && noise_.valid ? noise_.variance
                                                : params_.intensity_noise_sigma * params_.intensity_noise_sigma;
    const double var_mu = 0.5 * (P->block<2, 2>(ErrIdx::kMu, ErrIdx::kMu).trace());
    updateWeightMap(ref, cur, K, *x, var_mu, dt_s, std::max(var, floor_var));
    noise_.relief_var = noise_.relief_valid ? noise_.relief_var + alpha_ema * (relief_var_ - noise_.relief_var)
                                            : relief_var_;
    noise_.relief_valid = true;
    stats.relief_var = noise_.relief_var;
    rowBanding(cur, brightness, dt_s, &stats);
  }
  return stats;
}

void PhotometricUpdate::rowBanding(const PreprocessedFrame& cur, const BrightnessVec& brightness, double dt_s,
                                   UpdateStats* stats) {
  const int W = residual_.cols, H = residual_.rows;
  const int border = std::max(1, preprocess_.border_px);
  // The model with its level restored: the reference's level added (under kLevels the model already holds the
  // levels' relation less the current image's level).
  const float c_r =
      static_cast<float>(effective_model_ == BrightnessModel::kLevels ? cur.level_offset : ref_level_offset_);
  // Per row and half of the row: the current image's relative gain against the model, g = sum r N / sum N^2,
  // N = I_c - r + the reference's level (the model with its level restored): what a gain of that row would still
  // fit. Bands of the rows change both halves alike; an object in the view changes one. So the bands' variance is
  // the covariance over the rows of the two halves' gains (noise and objects: zero in expectation).
  const int half = W / 2;
  double sw = 0.0, sl = 0.0, sr = 0.0, slr = 0.0;
  int rows = 0;
  for (int y = border; y < H - border; ++y) {
    const float* r = residual_.ptr<float>(y);
    const float* I = cur.intensity.ptr<float>(y);
    double rN[2] = {0.0, 0.0}, NN[2] = {0.0, 0.0};
    const int ends[3] = {border, half, W - border};
    for (int h = 0; h < 2; ++h) {
      // Four lanes at a time; a pixel without a residual (not valid in the last linearisation) adds nothing.
      using namespace cv;
      const v_float32x4 zero = v_setzero_f32(), level = v_setall_f32(c_r);
      v_float32x4 acc_rN = zero, acc_NN = zero;
      int x = ends[h];
      for (; x + 4 <= ends[h + 1]; x += 4) {
        const v_float32x4 rv = v_load(r + x), N = v_load(I + x) - rv + level;
        acc_rN = v_muladd(rv, N, acc_rN);
        acc_NN = v_muladd(v_select(rv != zero, N, zero), N, acc_NN);
      }
      rN[h] = v_reduce_sum(acc_rN);
      NN[h] = v_reduce_sum(acc_NN);
      for (; x < ends[h + 1]; ++x) {
        if (r[x] == 0.0f) continue;
        const double N = I[x] - r[x] + c_r;
        rN[h] += r[x] * N;
        NN[h] += N * N;
      }
    }
    if (!(NN[0] > 0.0) || !(NN[1] > 0.0)) continue;
    const double gl = rN[0] / NN[0], gr = rN[1] / NN[1];
    const double w = NN[0] * NN[1] / (NN[0] + NN[1]);
    sw += w;
    sl += w * gl;
    sr += w * gr;
    slr += w * gl * gr;
    ++rows;
  }
  if (!(sw > 0.0) || rows < 2) return;
  const double ml = sl / sw, mr = sr / sw;
  double rms2 = std::max(0.0, slr / sw - ml * mr);
  // With the row gains estimated the bands are in the model, not the residual: add the fitted gains' spread over
  // the rows (their value at each row, about the mean).
  if (effective_model_ == BrightnessModel::kRows && brightness.size() == rowKnotCount(params_) &&
      row_knot_.size() == static_cast<size_t>(H)) {
    double m = 0.0, m2 = 0.0;
    int n = 0;
    for (int y = border; y < H - border; ++y) {
      double g[3];
      rowSpline(brightness, y, g);
      m += g[0];
      m2 += g[0] * g[0];
      ++n;
    }
    if (n > 0 && m > 0.0) {
      m /= n;
      rms2 += std::max(0.0, m2 / n - m * m) / (m * m);
    }
  }
  stats->row_gain_rms = std::sqrt(rms2);
  // Smoothed over kBandsTimeConstantS: flicker bands are there in every pair (their pattern changes from pair to
  // pair, their size does not); an object crossing the view shows in a few seconds at most. Found above
  // kBandsFoundGain, lost below kBandsLostGain (hysteresis).
  const double a = 1.0 - std::exp(-dt_s / kBandsTimeConstantS);
  bands_rms_ = bands_valid_ ? bands_rms_ + a * (stats->row_gain_rms - bands_rms_) : stats->row_gain_rms;
  bands_valid_ = true;
  if (!bands_found_ && bands_rms_ > kBandsFoundGain) bands_found_ = true;
  if (bands_found_ && bands_rms_ < kBandsLostGain) bands_found_ = false;
  stats->row_banding = bands_rms_;
  stats->row_bands_found = bands_found_;
}

}  // namespace diekf
