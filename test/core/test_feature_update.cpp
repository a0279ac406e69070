#include <cmath>

#include <Eigen/Cholesky>
#include <gtest/gtest.h>

#include "diekf/feature_update.h"
#include "two_view_scene.h"

namespace diekf {
namespace {

using test_util::TwoViewScene;

ErrorCov priorCov() {
  ErrorVec sd;
  sd << 0.5, 0.5, 0.5, 0.5, 0.1, 0.1, 0.05, 0.05, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01;
  return sd.array().square().matrix().asDiagonal();
}

class FeatureScene : public ::testing::Test {
 protected:
  // The baseline tracks at a higher working resolution than the photometric update.
  static void SetUpTestSuite() { scene_ = new TwoViewScene(test_util::makeTwoViewScene(376, 240, 2)); }
  static void TearDownTestSuite() {
    delete scene_;
    scene_ = nullptr;
  }
  static State startState() {
    State x;
    x.alpha = 1.0 / scene_->truth.d_m;
    x.vartheta.setZero();
    x.mu = UnitVector(scene_->truth.mu).boxplus(Vec2(0.04, -0.03));
    return x;
  }
  static TwoViewScene* scene_;
};
TwoViewScene* FeatureScene::scene_ = nullptr;

TEST_F(FeatureScene, TrackedCornersMoveVarthetaTowardTruth) {
  FeatureUpdate update(FeatureParams{}, PhotometricParams{});
  State x = startState();
  ErrorCov P = priorCov();
  const Vec3 truth = scene_->truth.vartheta_inv_s;
  const double err0 = (x.vartheta - truth).norm();
  const double mu_err0 = x.mu.boxminus(UnitVector(scene_->truth.mu)).norm();
  const UpdateStats st = update.update(scene_->ref, scene_->cur, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_GT(st.valid_ratio, 0.8);
  EXPECT_GE(st.passes, 1);
  const double err1 = (x.vartheta - truth).norm();
  EXPECT_LT(err1, 0.1 * err0) << err0 << " -> " << err1;  // measured ~0.02
  EXPECT_LE(x.mu.boxminus(UnitVector(scene_->truth.mu)).norm(), mu_err0 + 1e-3);
  EXPECT_LT(st.rms_residual, 0.5);  // px, at the final estimate
  const Eigen::LLT<ErrorCov> llt(P);
  EXPECT_EQ(llt.info(), Eigen::Success);
  EXPECT_LT(P(ErrIdx::kVartheta, ErrIdx::kVartheta), priorCov()(ErrIdx::kVartheta, ErrIdx::kVartheta));
}

TEST_F(FeatureScene, StaticSceneKeepsZeroVelocity) {
  FeatureUpdate update(FeatureParams{}, PhotometricParams{});
  State x;
  x.alpha = 1.0;
  x.mu = UnitVector(scene_->truth.mu);
  ErrorCov P = priorCov();
  const UpdateStats st = update.update(scene_->cur, scene_->cur, scene_->K, Vec3::Zero(), scene_->dt_s, &x, &P);
  ASSERT_TRUE(st.applied);
  EXPECT_LT(st.rms_residual, 0.05);
  EXPECT_LT(x.vartheta.norm(), 0.02);
}

TEST_F(FeatureScene, TexturelessImageSkipsUpdate) {
  FeatureUpdate update(FeatureParams{}, PhotometricParams{});
  PreprocessedFrame flat = scene_->cur;
  flat.gray8 = cv::Mat(scene_->cur.gray8.size(), CV_8UC1, cv::Scalar(128));
  State x = startState();
  const State x0 = x;
  const ErrorCov P0 = priorCov();
  ErrorCov P = P0;
  const UpdateStats st = update.update(flat, flat, scene_->K, scene_->w_C, scene_->dt_s, &x, &P);
  EXPECT_FALSE(st.applied);
  EXPECT_EQ(x.vartheta, x0.vartheta);
  EXPECT_EQ(P, P0);
}

}  // namespace
}  // namespace diekf
