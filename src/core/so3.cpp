#include <cmath>

#include "diekf/types.h"

namespace diekf {

Mat3 expSO3(const Vec3& phi) {
  const double theta2 = phi.squaredNorm();
  const Mat3 K = skew(phi);
  double a, b;  // R = I + a K + b K^2
  if (theta2 < 1e-12) {
    a = 1.0 - theta2 / 6.0;
    b = 0.5 - theta2 / 24.0;
  } else {
    const double theta = std::sqrt(theta2);
    a = std::sin(theta) / theta;
    b = (1.0 - std::cos(theta)) / theta2;
  }
  return Mat3::Identity() + a * K + b * K * K;
}

Mat3 leftJacobianSO3(const Vec3& phi) {
  const double theta2 = phi.squaredNorm();
  const Mat3 K = skew(phi);
  double a, b;  // J = I + a K + b K^2
  if (theta2 < 1e-12) {
    a = 0.5 - theta2 / 24.0;
    b = 1.0 / 6.0 - theta2 / 120.0;
  } else {
    const double theta = std::sqrt(theta2);
    a = (1.0 - std::cos(theta)) / theta2;
    b = (theta - std::sin(theta)) / (theta2 * theta);
  }
  return Mat3::Identity() + a * K + b * K * K;
}

}  // namespace diekf
