// Unit vector on the sphere S^2 stored as a rotation (as ROVIO's NormalVectorElement).
#pragma once

#include "diekf/types.h"

namespace diekf {

/// n = q * e_z. Tangent basis N(q) = [q e_x, q e_y]. Perturbation q [+] d = exp(N d) (x) q.
class UnitVector {
 public:
  UnitVector() : q_(Eigen::Quaterniond::Identity()) {}
  /// Builds the element with the minimal rotation taking e_z onto n/|n| (n must be non-zero).
  explicit UnitVector(const Vec3& n);
  static UnitVector fromQuaternion(const Eigen::Quaterniond& q);

  const Eigen::Quaterniond& quaternion() const { return q_; }
  /// The unit vector n = q e_z.
  Vec3 vector() const { return q_ * Vec3::UnitZ(); }
  /// Tangent basis N = [q e_x, q e_y] (3x2, orthonormal, perpendicular to n).
  Mat32 N() const;
  /// First-order perturbation map: (n [+] d) ~= n + M d, M = [-q e_y, q e_x] = -[n]x N.
  Mat32 M() const;

  /// exp(N d) (x) q.
  UnitVector boxplus(const Vec2& delta) const;
  /// this [-] b = N(b)^T theta(b -> this), theta the minimal rotation vector taking b onto this.
  Vec2 boxminus(const UnitVector& b) const;
  /// d((this [+] d) [-] b)/d d at d = 0 (2x2).
  Mat2 boxminusJacobian(const UnitVector& b) const;

 private:
  Eigen::Quaterniond q_;
};

/// Minimal rotation vector taking unit vector b onto unit vector a (angle via atan2; antipodal handled).
Vec3 minimalRotation(const Vec3& b, const Vec3& a);

}  // namespace diekf
