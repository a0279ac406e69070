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
  sd << 0.5, 0.5, 0.5, 0.5, 0.1, 0.1, 0.05, 0.05, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01, 0.005, 0.005, 0.01;
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

// A fast pass (2.5 m/s at 1 m, ~12 px per frame at 376 px) tracked without a pyramid: started at the corners, LK
// cannot reach the matches; started where the prior (here the true state) predicts them, it does.
TEST(FeatureUpdateFlow, PredictedFlowTracksLargeDisplacements) {
  const PinholeK K = test_util::makeK(376, 240);
  const double dt = 1.0 / 30.0;
  const Vec3 v_W(2.0, -1.5, 0.0), w_C(0.3, -0.2, 0.1);
  const test_util::PlaneTexture texture(5);
  const test_util::Plane ground;
  const test_util::CameraPose cur = test_util::lookDownPose(Vec3(0.0, 0.0, 1.0), 0.2, 0.1);
  const test_util::CameraPose ref = test_util::propagate(cur, v_W, w_C, -dt);
  const test_util::PlaneTruth truth = test_util::planeTruth(ground, cur, v_W);
  const PreprocessedFrame f_ref =
      test_util::makeFrame(test_util::toGray8(test_util::renderPlane(texture, ground, K, ref, 2)), 0.0);
  const PreprocessedFrame f_cur =
      test_util::makeFrame(test_util::toGray8(test_util::renderPlane(texture, ground, K, cur, 2)), dt);
  State x0;
  x0.alpha = 1.0 / truth.d_m;
  x0.vartheta = truth.vartheta_inv_s;
  x0.mu = UnitVector(truth.mu);
  double rms[2] = {0.0, 0.0};
  for (const bool predict : {false, true}) {
    FeatureParams fp;
    fp.pyramid_levels = 1;
    fp.predict_flow = predict;
    FeatureUpdate update(fp, PhotometricParams{});
    State x = x0;
    ErrorCov P = priorCov();
    const UpdateStats st = update.update(f_ref, f_cur, K, w_C, dt, &x, &P);
    rms[predict ? 1 : 0] = st.applied ? st.rms_residual : 1e9;
    if (predict) {
      ASSERT_TRUE(st.applied);
      EXPECT_GT(st.valid_ratio, 0.8);
      EXPECT_LT((x.vartheta - truth.vartheta_inv_s).norm(), 0.05 * truth.vartheta_inv_s.norm());
    }
  }
  EXPECT_LT(rms[1], 0.5) << "px, predicted start";
  EXPECT_GT(rms[0], 2.0) << "px, start at the corners";
}

}  // namespace
}  // namespace diekf
