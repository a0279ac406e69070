#include "diekf/unit_vector.h"

#include <cmath>

namespace diekf {

Vec3 minimalRotation(const Vec3& b, const Vec3& a) {
  const Vec3 c = b.cross(a);
  const double s = c.norm();
  const double d = b.dot(a);
  if (s < 1e-12) {
    if (d > 0.0) return c;  // identical directions: angle ~ s, axis c/s
    // Antipodal: rotate by pi about any axis perpendicular to b.
    Vec3 axis = b.unitOrthogonal();
    return M_PI * axis;
  }
  return c * (std::atan2(s, d) / s);
}

UnitVector::UnitVector(const Vec3& n) {
  const double norm = n.norm();
  const Vec3 u = norm > 0.0 ? Vec3(n / norm) : Vec3::UnitZ();
  const Vec3 rot = minimalRotation(Vec3::UnitZ(), u);
  const double angle = rot.norm();
  q_ = angle > 0.0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, rot / angle))
                   : Eigen::Quaterniond::Identity();
}

UnitVector UnitVector::fromQuaternion(const Eigen::Quaterniond& q) {
  UnitVector u;
  u.q_ = q.normalized();
  return u;
}

Mat32 UnitVector::N() const {
  const Mat3 R = q_.toRotationMatrix();
  return R.leftCols<2>();
}

Mat32 UnitVector::M() const {
  const Mat3 R = q_.toRotationMatrix();
  Mat32 m;
  m.col(0) = -R.col(1);
  m.col(1) = R.col(0);
  return m;
}

UnitVector UnitVector::boxplus(const Vec2& delta) const {
  const Vec3 phi = N() * delta;
  const double angle = phi.norm();
  Eigen::Quaterniond dq = Eigen::Quaterniond::Identity();
  if (angle > 1e-15) {
    dq = Eigen::Quaterniond(Eigen::AngleAxisd(angle, phi / angle));
  }
  return fromQuaternion(dq * q_);
}

Vec2 UnitVector::boxminus(const UnitVector& b) const {
  return b.N().transpose() * minimalRotation(b.vector(), vector());
}

Mat2 UnitVector::boxminusJacobian(const UnitVector& b) const {
  // theta(a) = c * phi(s, d), c = b x a, s = |c|, d = b . a, phi = atan2(s, d) / s (|a| = |b| = 1).
  const Vec3 a = vector();
  const Vec3 bv = b.vector();
  const Vec3 c = bv.cross(a);
  const double s = c.norm();
  const double d = bv.dot(a);
  const Mat3 Bx = skew(bv);
  Mat3 dtheta_da;
  if (s < 1e-6 && d > 0.0) {
    // phi ~ 1 + s^2/6, (d - phi)/s^2 ~ -2/3.
    const double phi = 1.0 + s * s / 6.0;
    dtheta_da = phi * Bx + c * ((-2.0 / 3.0) * c.transpose() * Bx - bv.transpose());
  } else {
    const double phi = std::atan2(s, d) / s;
    const double dphi_ds = (d - phi) / s;  // uses s^2 + d^2 = 1
    dtheta_da = phi * Bx + c * ((dphi_ds / s) * c.transpose() * Bx - bv.transpose());
  }
  return b.N().transpose() * dtheta_da * M();
}

}  // namespace diekf
