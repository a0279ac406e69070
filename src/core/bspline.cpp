#include "bspline.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "lanes.h"

namespace diekf {
namespace internal {
namespace {

// The pole of the cubic B-spline's inverse filter 6 / (z + 4 + 1/z), and its gain (1 - z)(1 - 1/z) = 6.
constexpr double kPole = -0.2679491924311227;  // sqrt(3) - 2
constexpr float kGain = 6.0f;
// Terms of the causal recursion's initial value: |z|^12 < 1.5e-7, below float resolution of a unit signal.
constexpr int kInitTerms = 12;

/// The prefilter along n samples `step` floats apart, each sample `lanes` contiguous floats filtered independently
/// (kLanes > 0: that many, fixed at compile time; 0: `lanes`), in place, gain included:
///   c+(0) = 6 sum_k z^k f(k) (mirror boundary, truncated), c+(k) = 6 f(k) + z c+(k - 1);
///   then c(n - 1) = z / (z^2 - 1) (c+(n - 1) + z c+(n - 2)) and c(k) = z (c(k + 1) - c+(k)).
/// Along a row: one lane, the samples contiguous; down the columns: the rows are the samples and every column a
/// lane (contiguous inner loops, vectorised).
template <int kLanes>
void filterSamples(float* c, std::ptrdiff_t step, int n, int lanes) {
  const int L = kLanes > 0 ? kLanes : lanes;
  const float z = static_cast<float>(kPole);
  {
    float zk = z;
    for (int k = 1; k < std::min(n, kInitTerms); ++k) {
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

}  // namespace

void cubicBSplineCoefficients(const cv::Mat& image, cv::Mat* coeff, std::vector<float>* scratch) {
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
      filterSamples<4>(b, 4, W, 4);
      lanesToRows(b, W4, out);
      for (int x = W4; x < W; ++x)
        for (int l = 0; l < 4; ++l) out[l][x] = b[4 * x + l];
    }
    for (; y < H; ++y) {
      std::copy(image.ptr<float>(y), image.ptr<float>(y) + W, coeff->ptr<float>(y));
      filterSamples<1>(coeff->ptr<float>(y), 1, W, 1);
    }
  }
  if (H >= 2) filterSamples<0>(coeff->ptr<float>(0), static_cast<std::ptrdiff_t>(coeff->step1()), H, W);
}

}  // namespace internal
}  // namespace diekf
