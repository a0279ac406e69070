#include "bspline.h"

#include <algorithm>
#include <cmath>

namespace diekf {
namespace internal {
namespace {

// The pole of the cubic B-spline's inverse filter 6 / (z + 4 + 1/z), and its gain (1 - z)(1 - 1/z) = 6.
constexpr double kPole = -0.2679491924311227;  // sqrt(3) - 2
constexpr float kGain = 6.0f;
// Terms of the causal recursion's initial value: |z|^12 < 1.5e-7, below float resolution of a unit signal.
constexpr int kInitTerms = 12;

/// The prefilter along one row of n samples, in place, gain included: c+(0) = 6 sum_k z^k f(k) (mirror boundary,
/// truncated), c+(k) = 6 f(k) + z c+(k - 1); then c(n - 1) = z / (z^2 - 1) (c+(n - 1) + z c+(n - 2)) and
/// c(k) = z (c(k + 1) - c+(k)).
void filterRow(float* c, int n) {
  const float z = static_cast<float>(kPole);
  float zk = z, sum = c[0];
  for (int k = 1; k < std::min(n, kInitTerms); ++k) {
    sum += zk * c[k];
    zk *= z;
  }
  float prev = kGain * sum;
  c[0] = prev;
  for (int k = 1; k < n; ++k) {
    prev = kGain * c[k] + z * prev;
    c[k] = prev;
  }
  float next = (z / (z * z - 1.0f)) * (c[n - 1] + z * c[n - 2]);
  c[n - 1] = next;
  for (int k = n - 2; k >= 0; --k) {
    next = z * (next - c[k]);
    c[k] = next;
  }
}

}  // namespace

void cubicBSplineCoefficients(const cv::Mat& image, cv::Mat* coeff) {
  CV_Assert(image.type() == CV_32FC1 && coeff != nullptr);
  coeff->create(image.size(), CV_32FC1);
  image.copyTo(*coeff);
  const int W = coeff->cols, H = coeff->rows;
  if (W >= 2)
    for (int y = 0; y < H; ++y) filterRow(coeff->ptr<float>(y), W);
  if (H < 2) return;
  // Columns: the same recursions with whole rows as the samples (contiguous inner loops, vectorised).
  const float z = static_cast<float>(kPole);
  {
    float* r0 = coeff->ptr<float>(0);
    float zk = z;
    for (int k = 1; k < std::min(H, kInitTerms); ++k) {
      const float* rk = coeff->ptr<float>(k);
      for (int x = 0; x < W; ++x) r0[x] += zk * rk[x];
      zk *= z;
    }
    for (int x = 0; x < W; ++x) r0[x] *= kGain;
  }
  for (int y = 1; y < H; ++y) {
    float* r = coeff->ptr<float>(y);
    const float* up = coeff->ptr<float>(y - 1);
    for (int x = 0; x < W; ++x) r[x] = kGain * r[x] + z * up[x];
  }
  {
    float* rl = coeff->ptr<float>(H - 1);
    const float* rp = coeff->ptr<float>(H - 2);
    const float a = z / (z * z - 1.0f);
    for (int x = 0; x < W; ++x) rl[x] = a * (rl[x] + z * rp[x]);
  }
  for (int y = H - 2; y >= 0; --y) {
    float* r = coeff->ptr<float>(y);
    const float* dn = coeff->ptr<float>(y + 1);
    for (int x = 0; x < W; ++x) r[x] = z * (dn[x] - r[x]);
  }
}

}  // namespace internal
}  // namespace diekf
