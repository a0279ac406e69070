#include "bspline.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "lanes.h"

namespace diekf {
namespace internal {
namespace {

// The poles of the B-splines' inverse filters, inside the unit circle: the cubic's 6 / (z + 4 + 1/z) has
// sqrt(3) - 2, the quintic's 120 / (z^2 + 26 z + 66 + 26/z + 1/z^2) two. Each pole's pair of recursions carries
// its gain (1 - z)(1 - 1/z); the gains multiply to 6 and 120.
// `init_terms`: terms of the causal recursion's initial value, |z|^k below 1.5e-7 (float resolution of a unit
// signal).
struct Pole {
  double z;
  int init_terms;
  constexpr float gain() const { return static_cast<float>((1.0 - z) * (1.0 - 1.0 / z)); }
};
constexpr Pole kCubicPole{-0.2679491924311227, 12};
constexpr Pole kQuinticPoles[2] = {{-0.4305753470999738, 19}, {-0.04309628820326465, 5}};

/// One pole's prefilter along n samples `step` floats apart, each sample `lanes` contiguous floats filtered
/// independently (kLanes > 0: that many, fixed at compile time; 0: `lanes`), in place, gain g = (1 - z)(1 - 1/z):
///   c+(0) = g sum_k z^k f(k) (mirror boundary, truncated), c+(k) = g f(k) + z c+(k - 1);
///   then c(n - 1) = z / (z^2 - 1) (c+(n - 1) + z c+(n - 2)) and c(k) = z (c(k + 1) - c+(k)).
/// Along a row: one lane, the samples contiguous; down the columns: the rows are the samples and every column a
/// lane (contiguous inner loops, vectorised).
template <int kLanes>
void filterPole(float* c, std::ptrdiff_t step, int n, int lanes, const Pole& pole) {
  const int L = kLanes > 0 ? kLanes : lanes;
  const float z = static_cast<float>(pole.z);
  const float kGain = pole.gain();
  {
    float zk = z;
    for (int k = 1; k < std::min(n, pole.init_terms); ++k) {
      const float* ck = c + k * step;
      for (int l = 0; l < L; ++l) c[l] += zk * ck[l];
      zk *= z;
    }
    for (int l = 0; l < L; ++l) c[l] *= kGain;
  }
  for (int k = 1; k < n; ++k) {
    float* ck = c + k * step;
    const float* prev = ck - step;
    for (int l = 0; l < L; ++l) ck[l] = kGain * ck[l] + z * prev[l];
  }
  {
    float* last = c + (n - 1) * step;
    const float* before = last - step;
    const float a = z / (z * z - 1.0f);
    for (int l = 0; l < L; ++l) last[l] = a * (last[l] + z * before[l]);
  }
  for (int k = n - 2; k >= 0; --k) {
    float* ck = c + k * step;
    const float* next = ck + step;
    for (int l = 0; l < L; ++l) ck[l] = z * (next[l] - ck[l]);
  }
}

/// The prefilter of the spline of `degree` (3 or 5): its poles one after the other.
template <int kLanes>
void filterSamples(float* c, std::ptrdiff_t step, int n, int lanes, int degree) {
  if (degree == 5) {
    for (const Pole& z : kQuinticPoles) filterPole<kLanes>(c, step, n, lanes, z);
  } else {
    filterPole<kLanes>(c, step, n, lanes, kCubicPole);
  }
}

}  // namespace

void cubicBSplineCoefficients(const cv::Mat& image, cv::Mat* coeff, std::vector<float>* scratch) {
  bSplineCoefficients(image, 3, coeff, scratch);
}

void bSplineCoefficients(const cv::Mat& image, int degree, cv::Mat* coeff, std::vector<float>* scratch) {
  CV_Assert(degree == 3 || degree == 5);
  CV_Assert(image.type() == CV_32FC1 && coeff != nullptr && coeff->data != image.data);
  coeff->create(image.size(), CV_32FC1);
  const int W = image.cols, H = image.rows;
  if (W < 2) {
    image.copyTo(*coeff);
  } else {
    // Along the rows, four at a time: the block of four rows transposed into `block` (sample k of row l at
    // 4 k + l), filtered there with the rows as the lanes (the same operations per row, vectorised), and
    // transposed back into the coefficients. The rows left over are filtered one by one.
    std::vector<float> local;
    std::vector<float>& block = scratch != nullptr ? *scratch : local;
    block.resize(static_cast<std::size_t>(4) * W);
    const int W4 = W & ~3;
    int y = 0;
    for (; y + 4 <= H; y += 4) {
      const float* in[4] = {image.ptr<float>(y), image.ptr<float>(y + 1), image.ptr<float>(y + 2),
                            image.ptr<float>(y + 3)};
      float* out[4] = {coeff->ptr<float>(y), coeff->ptr<float>(y + 1), coeff->ptr<float>(y + 2),
                       coeff->ptr<float>(y + 3)};
      float* b = block.data();
      rowsToLanes(in, W4, b);
      for (int x = W4; x < W; ++x)
        for (int l = 0; l < 4; ++l) b[4 * x + l] = in[l][x];
      filterSamples<4>(b, 4, W, 4, degree);
      lanesToRows(b, W4, out);
      for (int x = W4; x < W; ++x)
        for (int l = 0; l < 4; ++l) out[l][x] = b[4 * x + l];
    }
    for (; y < H; ++y) {
      std::copy(image.ptr<float>(y), image.ptr<float>(y) + W, coeff->ptr<float>(y));
      filterSamples<1>(coeff->ptr<float>(y), 1, W, 1, degree);
    }
  }
  if (H >= 2) filterSamples<0>(coeff->ptr<float>(0), static_cast<std::ptrdiff_t>(coeff->step1()), H, W, degree);
}

}  // namespace internal
}  // namespace diekf
