// S^2 element, state manifold operations and SO(3) helpers against their definitions and finite differences.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "diekf/state.h"
#include "diekf/unit_vector.h"

namespace diekf {
namespace {

UnitVector randomUnit(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return UnitVector(Vec3(n(rng), n(rng), n(rng)));
}

/// Unit vector at angle `angle_rad` from `b`, in a random direction.
UnitVector unitNear(const UnitVector& b, double angle_rad, std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Vec2 d(n(rng), n(rng));
  d *= angle_rad / d.norm();
  return b.boxplus(d);
}

/// Central finite difference of delta -> (a [+] delta) [-] b.
Mat2 numericBoxminusJacobian(const UnitVector& a, const UnitVector& b, double h) {
  Mat2 J;
  for (int i = 0; i < 2; ++i) {
    Vec2 e = Vec2::Zero();
    e(i) = h;
    J.col(i) = (a.boxplus(e).boxminus(b) - a.boxplus(-e).boxminus(b)) / (2.0 * h);
  }
  return J;
}

TEST(UnitVector, ConstructionNormalisesAndPointsAlongInput) {
  const Vec3 n(0.2, -0.1, 0.97);
  const UnitVector u(n);
  EXPECT_NEAR(u.vector().norm(), 1.0, 1e-14);
  EXPECT_LT((u.vector() - n.normalized()).norm(), 1e-14);
  // Antipode of e_z is representable too.
  const UnitVector down(Vec3(0, 0, -1));
  EXPECT_LT((down.vector() - Vec3(0, 0, -1)).norm(), 1e-14);
}

TEST(UnitVector, BasisIsOrthonormalAndMIsMinusSkewN) {
  std::mt19937 rng(1);
  for (int trial = 0; trial < 20; ++trial) {
    const UnitVector u = randomUnit(rng);
    const Mat32 N = u.N();
    const Vec3 n = u.vector();
    EXPECT_LT((N.transpose() * N - Mat2::Identity()).norm(), 1e-14);
    EXPECT_LT((N.transpose() * n).norm(), 1e-14);
    EXPECT_LT((u.M() - (-skew(n) * N)).norm(), 1e-14);
  }
}

TEST(UnitVector, BoxplusBoxminusRoundTrip) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> angle(1e-9, 3.0);
  for (int trial = 0; trial < 50; ++trial) {
    const UnitVector x = randomUnit(rng);
    const UnitVector y = unitNear(x, angle(rng), rng);
    const Vec2 d = y.boxminus(x);
    EXPECT_LT((x.boxplus(d).vector() - y.vector()).norm(), 1e-12) << "trial " << trial;
    // And the other way round: (x [+] d) [-] x == d for |d| < pi.
    Vec2 d2(std::uniform_real_distribution<double>(-1.5, 1.5)(rng),
            std::uniform_real_distribution<double>(-1.5, 1.5)(rng));
    EXPECT_LT((x.boxplus(d2).boxminus(x) - d2).norm(), 1e-12);
  }
}

TEST(UnitVector, BoxminusIdenticalAndAntipodalAreFinite) {
  const UnitVector a(Vec3(0.3, 0.4, 0.5));
  const Vec2 zero = a.boxminus(a);
  EXPECT_TRUE(zero.allFinite());
  EXPECT_LT(zero.norm(), 1e-15);
  const UnitVector anti(-a.vector());
  const Vec2 pi_vec = anti.boxminus(a);
  EXPECT_TRUE(pi_vec.allFinite());
  EXPECT_NEAR(pi_vec.norm(), M_PI, 1e-12);
  // Moving a by the returned tangent lands on the antipode.
  EXPECT_LT((a.boxplus(pi_vec).vector() - anti.vector()).norm(), 1e-12);
  EXPECT_TRUE(a.boxminusJacobian(a).allFinite());
}

TEST(UnitVector, BoxminusJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(3);
  const double angles[] = {0.0, 1e-8, 1e-4, 0.3, 1.0, 2.0, 2.8};
  for (double ang : angles) {
    for (int trial = 0; trial < 10; ++trial) {
      const UnitVector b = randomUnit(rng);
      const UnitVector a = ang == 0.0 ? b : unitNear(b, ang, rng);
      const Mat2 J = a.boxminusJacobian(b);
      const Mat2 Jn = numericBoxminusJacobian(a, b, 1e-6);
      EXPECT_LT((J - Jn).norm(), 1e-6 * std::max(1.0, J.norm())) << "angle " << ang << "\nJ\n" << J << "\nJn\n"
                                                                  << Jn;
    }
  }
  // At a == b the Jacobian is the identity.
  const UnitVector c(Vec3(-0.4, 0.1, 0.9));
  EXPECT_LT((c.boxminusJacobian(c) - Mat2::Identity()).norm(), 1e-12);
}

State randomState(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  State x;
  x.alpha = 0.5 + std::abs(n(rng));
  x.vartheta = Vec3(n(rng), n(rng), n(rng));
  x.mu = UnitVector(Vec3(0.2 * n(rng), 0.2 * n(rng), 1.0));
  x.g = UnitVector(Vec3(0.2 * n(rng), 0.2 * n(rng), 1.0));
  x.b_a = 0.1 * Vec3(n(rng), n(rng), n(rng));
  x.b_w = 0.01 * Vec3(n(rng), n(rng), n(rng));
  return x;
}

TEST(State, BoxplusBoxminusRoundTrip) {
  std::mt19937 rng(4);
  std::normal_distribution<double> n(0.0, 0.3);
  for (int trial = 0; trial < 20; ++trial) {
    const State x = randomState(rng);
    ErrorVec d;
    for (int i = 0; i < kErrorDim; ++i) d(i) = n(rng);
    const State y = x.boxplus(d);
    EXPECT_LT((y.boxminus(x) - d).norm(), 1e-12);
    EXPECT_LT(x.boxplus(y.boxminus(x)).boxminus(y).norm(), 1e-12);
  }
}

TEST(State, BoxminusJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  const double scales[] = {0.0, 1e-7, 0.05, 0.5};  // distance between the two states
  for (double scale : scales) {
    for (int trial = 0; trial < 5; ++trial) {
      const State ref = randomState(rng);
      ErrorVec off;
      for (int i = 0; i < kErrorDim; ++i) off(i) = scale * n(rng);
      const State x = ref.boxplus(off);
      const ErrorCov L = x.boxminusJacobian(ref);
      ErrorCov Ln;
      const double h = 1e-6;
      for (int i = 0; i < kErrorDim; ++i) {
        ErrorVec e = ErrorVec::Zero();
        e(i) = h;
        Ln.col(i) = (x.boxplus(e).boxminus(ref) - x.boxplus(-e).boxminus(ref)) / (2.0 * h);
      }
      EXPECT_LT((L - Ln).norm(), 1e-6 * L.norm()) << "scale " << scale;
    }
  }
}

TEST(SO3, ExpIsARotationAndMatchesSmallAngle) {
  const Vec3 phi(0.3, -0.7, 1.1);
  const Mat3 R = expSO3(phi);
  EXPECT_LT((R.transpose() * R - Mat3::Identity()).norm(), 1e-14);
  EXPECT_NEAR(R.determinant(), 1.0, 1e-14);
  const Mat3 Ref = Eigen::AngleAxisd(phi.norm(), phi.normalized()).toRotationMatrix();
  EXPECT_LT((R - Ref).norm(), 1e-14);
  const Vec3 tiny(1e-9, -2e-9, 3e-9);
  EXPECT_LT((expSO3(tiny) - (Mat3::Identity() + skew(tiny))).norm(), 1e-16);
}

TEST(SO3, LeftJacobianMatchesFiniteDifferences) {
  // exp(phi + e) ~= exp([J e]x) exp(phi)  =>  J e ~= log(exp(phi + e) exp(phi)^T).
  const Vec3 phis[] = {Vec3(0.3, -0.7, 1.1), Vec3(1e-7, 2e-7, -1e-7), Vec3(0, 0, 0), Vec3(2.5, 0.1, -0.4)};
  for (const Vec3& phi : phis) {
    const Mat3 J = leftJacobianSO3(phi);
    Mat3 Jn;
    const double h = 1e-6;
    for (int i = 0; i < 3; ++i) {
      Vec3 e = Vec3::Zero();
      e(i) = h;
      const Eigen::AngleAxisd plus(expSO3(phi + e) * expSO3(phi).transpose());
      const Eigen::AngleAxisd minus(expSO3(phi - e) * expSO3(phi).transpose());
      Jn.col(i) = (plus.angle() * plus.axis() - minus.angle() * minus.axis()) / (2.0 * h);
    }
    EXPECT_LT((J - Jn).norm(), 1e-6) << "phi " << phi.transpose();
  }
}

}  // namespace
}  // namespace diekf
