// Metrics of docs/conventions.md section 5 on hand-made series.
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "diekf/eval/io.h"
#include "diekf/eval/metrics.h"

namespace diekf {
namespace eval {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Series {
  std::vector<EstimateRow> est;
  std::vector<std::optional<TruthSample>> truth;
};

/// 30 Hz frames from t0 for `duration_s`; the first frame has no update (iterations 0), the rest 2 passes.
/// Truth: d = 1 m, still; estimates exact unless modified by the caller.
Series makeSeries(double t0, double duration_s, double rate_hz = 30.0) {
  Series s;
  const int n = static_cast<int>(std::lround(duration_s * rate_hz)) + 1;
  for (int i = 0; i < n; ++i) {
    EstimateRow e;
    e.t_s = t0 + i / rate_hz;
    e.d_m = e.h_m = 1.0;
    e.iterations = i == 0 ? 0 : 2;
    e.update_ms = i == 0 ? 0.0 : 1.0 + (i % 3);  // 1, 2, 3 ms cycling
    e.status = i == 0 ? "initializing" : "tracking";
    TruthSample t;
    t.t_s = e.t_s;
    t.d_m = t.h_m = 1.0;
    s.est.push_back(e);
    s.truth.push_back(t);
  }
  return s;
}

TEST(Metrics, AngleBetween) {
  EXPECT_NEAR(angleBetweenDeg(Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 2, 0)), 90.0, 1e-12);
  EXPECT_NEAR(angleBetweenDeg(Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(-1, 0, 0)), 180.0, 1e-12);
  EXPECT_NEAR(angleBetweenDeg(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1e-9, 0, 1)), 1e-9 * 180.0 / kPi, 1e-18);
  EXPECT_TRUE(std::isnan(angleBetweenDeg(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 1))));
}

TEST(Metrics, Percentile) {
  EXPECT_DOUBLE_EQ(percentile({3.0, 1.0, 2.0}, 50.0), 2.0);
  EXPECT_DOUBLE_EQ(percentile({1.0, 2.0, 3.0, 4.0}, 50.0), 2.5);
  EXPECT_DOUBLE_EQ(percentile({0.0, 10.0}, 99.0), 9.9);
  EXPECT_TRUE(std::isnan(percentile({}, 50.0)));
}

TEST(Metrics, ExactEstimatesHaveZeroErrorAndTimingStats) {
  const Series s = makeSeries(10.0, 20.0);
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_FALSE(ev.diverged);
  EXPECT_EQ(ev.frames_total, static_cast<int>(s.est.size()));
  EXPECT_NEAR(ev.duration_s, 20.0, 1e-9);
  EXPECT_DOUBLE_EQ(ev.rmse_distance_m, 0.0);
  EXPECT_DOUBLE_EQ(ev.rmse_velocity_mps, 0.0);
  EXPECT_DOUBLE_EQ(ev.max_normal_deg, 0.0);
  // Timing over the 600 updated frames (1, 2, 3 ms equally often), the first frame excluded.
  EXPECT_NEAR(ev.update_ms_mean, 2.0, 1e-12);
  EXPECT_DOUBLE_EQ(ev.update_ms_median, 2.0);
  EXPECT_DOUBLE_EQ(ev.update_ms_p99, 3.0);
}

TEST(Metrics, EvaluationStartsThreeSecondsAfterTheFirstUpdate) {
  Series s = makeSeries(0.0, 10.0);  // frame 0 at 0 s (no update), first update at 1/30 s
  // A 1 m distance error on every frame before 3 s + 1/30 s, a 0.1 m error after.
  const double start = 1.0 / 30.0 + 3.0;
  int after = 0;
  for (auto& e : s.est) {
    if (e.t_s < start - 1e-9) {
      e.d_m = 2.0;
    } else {
      e.d_m = 1.1;
      ++after;
    }
  }
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_NEAR(ev.eval_start_s, start, 1e-12);
  EXPECT_EQ(ev.frames, after);
  EXPECT_NEAR(ev.rmse_distance_m, 0.1, 1e-12);
  EXPECT_NEAR(ev.rmse_height_m, 0.0, 1e-12);

  EvaluationOptions no_delay;
  no_delay.start_delay_s = 0.0;
  const Evaluation all = evaluate(s.est, s.truth, no_delay);
  EXPECT_GT(all.rmse_distance_m, 0.3);
  EXPECT_EQ(all.frames, static_cast<int>(s.est.size()) - 1);
}

TEST(Metrics, VelocityErrorIsTheVectorNorm) {
  Series s = makeSeries(0.0, 5.0);
  for (auto& e : s.est) e.v_mps = Eigen::Vector3d(0.03, 0.04, 0.0);  // |error| = 5 cm/s on every frame
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_NEAR(ev.rmse_velocity_mps, 0.05, 1e-12);
}

TEST(Metrics, NormalAndGravityAnglesRmsAndMax) {
  Series s = makeSeries(0.0, 6.0);
  int k = 0;
  for (std::size_t i = 0; i < s.est.size(); ++i) {
    if (s.est[i].t_s < 3.0 + 1.0 / 30.0 - 1e-9) continue;
    const double deg = (k++ % 2 == 0) ? 3.0 : 4.0;  // alternating 3 and 4 degrees
    const double r = deg * kPi / 180.0;
    s.est[i].mu = Eigen::Vector3d(std::sin(r), 0.0, std::cos(r));
    s.est[i].g = Eigen::Vector3d(0.0, std::sin(r / 2), std::cos(r / 2)) * 3.0;  // not unit: normalised
  }
  const Evaluation ev = evaluate(s.est, s.truth);
  ASSERT_GT(k, 10);
  const double rms_expected = std::sqrt((k / 2 * 9.0 + (k - k / 2) * 16.0) / k);
  EXPECT_NEAR(ev.rms_normal_deg, rms_expected, 1e-9);
  EXPECT_NEAR(ev.max_normal_deg, 4.0, 1e-9);
  EXPECT_NEAR(ev.rms_gravity_deg, rms_expected / 2, 1e-9);
  EXPECT_NEAR(ev.max_gravity_deg, 2.0, 1e-9);
}

TEST(Metrics, FramesWithoutTruthAreSkipped) {
  Series s = makeSeries(0.0, 8.0);
  for (std::size_t i = 0; i < s.est.size(); i += 2) {
    s.truth[i].reset();
    s.est[i].d_m = 100.0;  // would dominate the RMSE if used
  }
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_DOUBLE_EQ(ev.rmse_distance_m, 0.0);
  EXPECT_GT(ev.frames, 0);
  EXPECT_THROW(evaluate(s.est, std::vector<std::optional<TruthSample>>(3)), std::invalid_argument);
}

TEST(Metrics, DivergedWhenMostOfTheLastTenSecondsAreFarOff) {
  Series s = makeSeries(0.0, 30.0);
  // Last 10 s: 60 % of the frames have a 60 % distance error.
  int window = 0, bad = 0;
  for (auto& e : s.est) {
    if (e.t_s >= 20.0 - 1e-9) {
      ++window;
      if (window % 5 < 3) {
        e.d_m = 1.6;
        ++bad;
      }
    }
  }
  ASSERT_GT(bad, window / 2);
  Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_TRUE(ev.diverged);
  EXPECT_FALSE(ev.divergence_reason.empty());

  // 40 % bad frames: not diverged.
  Series ok = makeSeries(0.0, 30.0);
  window = 0;
  for (auto& e : ok.est) {
    if (e.t_s >= 20.0 - 1e-9 && (window++ % 5) < 2) e.d_m = 1.6;
  }
  EXPECT_FALSE(evaluate(ok.est, ok.truth).diverged);

  // Errors just under 50 %: not bad frames.
  Series edge = makeSeries(0.0, 30.0);
  for (auto& e : edge.est) e.d_m = 1.49;
  EXPECT_FALSE(evaluate(edge.est, edge.truth).diverged);

  // Large errors only before the last 10 s: not diverged by the rule (only a large RMSE).
  Series early = makeSeries(0.0, 30.0);
  for (auto& e : early.est) {
    if (e.t_s > 5.0 && e.t_s < 19.0) e.d_m = 5.0;
  }
  const Evaluation ev_early = evaluate(early.est, early.truth);
  EXPECT_FALSE(ev_early.diverged);
  EXPECT_GT(ev_early.rmse_distance_m, 1.0);
}

TEST(Metrics, NonFiniteOutputMeansDiverged) {
  Series s = makeSeries(0.0, 20.0);
  s.est[50].v_mps.y() = std::numeric_limits<double>::quiet_NaN();
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_TRUE(ev.diverged);
  EXPECT_NE(ev.divergence_reason.find("non-finite"), std::string::npos);

  Series inf = makeSeries(0.0, 20.0);
  inf.est[1].sigma_d_m = std::numeric_limits<double>::infinity();  // before the evaluation window: still counts
  EXPECT_TRUE(evaluate(inf.est, inf.truth).diverged);
}

TEST(Metrics, NoUpdateOrNoEstimatesIsDiverged) {
  Series s = makeSeries(0.0, 5.0);
  for (auto& e : s.est) e.iterations = 0;
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_TRUE(ev.diverged);
  EXPECT_TRUE(std::isnan(ev.rmse_distance_m));
  EXPECT_TRUE(evaluate({}, {}).diverged);
}

// --- Consistency of the reported sigma: 2-sigma coverage and NEES. ---

/// `seconds` of 30 Hz frames whose distance and velocity errors are drawn from N(0, sigma^2) with the true sigma
/// (varying over time and per axis); the estimates report sigma / `understatement`.
Series makeGaussianSeries(double seconds, double understatement, unsigned seed = 7) {
  Series s = makeSeries(0.0, seconds);
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (std::size_t i = 0; i < s.est.size(); ++i) {
    const double phase = 0.01 * static_cast<double>(i);
    const double sigma_d = 0.02 * (1.0 + 0.5 * std::sin(phase));
    const Eigen::Vector3d sigma_v(0.03 * (1.0 + 0.5 * std::cos(phase)), 0.05, 0.01 * (2.0 + std::sin(3.0 * phase)));
    s.truth[i]->v_C_mps = Eigen::Vector3d(0.3, -0.2, 0.1);
    s.est[i].d_m = s.truth[i]->d_m + sigma_d * normal(rng);
    for (int k = 0; k < 3; ++k) s.est[i].v_mps[k] = s.truth[i]->v_C_mps[k] + sigma_v[k] * normal(rng);
    s.est[i].sigma_d_m = sigma_d / understatement;
    s.est[i].sigma_v_mps = sigma_v / understatement;
  }
  return s;
}

TEST(MetricsConsistency, HonestSigmaGivesNinetyFivePercentAndNeesFour) {
  const Series s = makeGaussianSeries(600.0, 1.0);  // 18 000 frames
  const Evaluation ev = evaluate(s.est, s.truth);
  ASSERT_GT(ev.frames, 17000);
  EXPECT_EQ(ev.consistency_frames, ev.frames);
  EXPECT_EQ(ev.consistency_frames_excluded, 0);
  // Standard errors: coverage about 0.0016 (d) and 0.0009 (v); NEES mean sqrt(8 / n) = 0.02.
  EXPECT_NEAR(ev.coverage2_d, 0.9545, 0.01);
  EXPECT_NEAR(ev.coverage2_v, 0.9545, 0.01);
  EXPECT_NEAR(ev.nees_mean, 4.0, 0.12);
  EXPECT_NEAR(ev.nees_median, 3.357, 0.12);  // median of chi-square with 4 degrees of freedom
  EXPECT_NEAR(ev.coverage2_d_last_half, 0.9545, 0.015);
  EXPECT_NEAR(ev.coverage2_v_last_half, 0.9545, 0.01);
  EXPECT_NEAR(ev.nees_mean_last_half, 4.0, 0.17);
}

TEST(MetricsConsistency, SigmaThreeTimesTooSmallLowersCoverageAndGivesNeesThirtySix) {
  const Series s = makeGaussianSeries(600.0, 3.0);
  const Evaluation ev = evaluate(s.est, s.truth);
  // |z| <= 2 now means |error| <= 2/3 sigma: P = 0.495.
  EXPECT_NEAR(ev.coverage2_d, 0.495, 0.02);
  EXPECT_NEAR(ev.coverage2_v, 0.495, 0.015);
  EXPECT_LT(ev.coverage2_v, 0.6);
  EXPECT_NEAR(ev.nees_mean, 36.0, 1.0);  // 9 x 4; standard error 9 sqrt(8 / n) = 0.19
  EXPECT_NEAR(ev.nees_median, 9.0 * 3.357, 1.0);
  EXPECT_NEAR(ev.nees_mean_last_half, 36.0, 1.5);
}

TEST(MetricsConsistency, FramesWithoutAUsableSigmaAreLeftOut) {
  Series s = makeGaussianSeries(600.0, 1.0);
  const Evaluation honest = evaluate(s.est, s.truth);
  int spoiled = 0;
  for (std::size_t i = 0; i < s.est.size(); ++i) {
    if (s.est[i].t_s < 3.5 || i % 7 != 0) continue;  // inside the evaluation window
    s.est[i].d_m += 10.0;  // would be far outside any band if used
    s.est[i].v_mps.x() += 10.0;
    switch (spoiled++ % 4) {
      case 0: s.est[i].sigma_d_m = 0.0; break;
      case 1: s.est[i].sigma_v_mps.y() = 0.0; break;
      case 2: s.est[i].sigma_v_mps.z() = -0.1; break;
      default: s.est[i].sigma_d_m = std::numeric_limits<double>::quiet_NaN(); break;
    }
  }
  ASSERT_GT(spoiled, 2000);
  const Evaluation ev = evaluate(s.est, s.truth);
  EXPECT_EQ(ev.frames, honest.frames);
  EXPECT_EQ(ev.consistency_frames_excluded, spoiled);
  EXPECT_EQ(ev.consistency_frames, ev.frames - spoiled);
  EXPECT_NEAR(ev.coverage2_d, 0.9545, 0.012);
  EXPECT_NEAR(ev.coverage2_v, 0.9545, 0.01);
  EXPECT_NEAR(ev.nees_mean, 4.0, 0.15);
  EXPECT_TRUE(std::isfinite(ev.nees_mean_last_half));

  // Every sigma zero: nothing to evaluate, NaN (null in the JSON), the RMSE unaffected.
  Series zero = makeGaussianSeries(10.0, 1.0);
  for (auto& e : zero.est) e.sigma_d_m = 0.0;
  const Evaluation ev_zero = evaluate(zero.est, zero.truth);
  EXPECT_EQ(ev_zero.consistency_frames, 0);
  EXPECT_EQ(ev_zero.consistency_frames_excluded, ev_zero.frames);
  EXPECT_TRUE(std::isnan(ev_zero.coverage2_d));
  EXPECT_TRUE(std::isnan(ev_zero.coverage2_v));
  EXPECT_TRUE(std::isnan(ev_zero.nees_mean));
  EXPECT_TRUE(std::isnan(ev_zero.nees_median));
  EXPECT_TRUE(std::isnan(ev_zero.nees_mean_last_half));
  EXPECT_TRUE(std::isfinite(ev_zero.rmse_distance_m));
}

/// Four evaluated frames (start delay 0: frames 1..4 of 0, 1/30, ..., 4/30 s), sigma_d = 0.25 m and
/// sigma_v = (0.25, 0.5, 1) m/s, errors chosen so every z is exact in binary:
///   frame 1: z_d = 1,  z_v = (0, 0, 0)        NEES 1     d inside, 3 v inside
///   frame 2: z_d = 3,  z_v = (1, 0, 0)        NEES 10    d outside, 3 v inside
///   frame 3: z_d = -2, z_v = (2.5, -2.5, 3)   NEES 25.5  d inside (on the bound), 0 v inside
///   frame 4: z_d = 0,  z_v = (-2, 2, 2)       NEES 12    d inside, 3 v inside (on the bound)
Series handSeries() {
  Series s = makeSeries(0.0, 4.0 / 30.0);
  const double zd[] = {0.0, 1.0, 3.0, -2.0, 0.0};
  const Eigen::Vector3d zv[] = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), Eigen::Vector3d(1, 0, 0),
                                Eigen::Vector3d(2.5, -2.5, 3), Eigen::Vector3d(-2, 2, 2)};
  const Eigen::Vector3d sigma_v(0.25, 0.5, 1.0);
  for (std::size_t i = 0; i < s.est.size(); ++i) {
    s.truth[i]->v_C_mps = Eigen::Vector3d(0.5, 0.0, -0.25);
    s.est[i].sigma_d_m = 0.25;
    s.est[i].sigma_v_mps = sigma_v;
    s.est[i].d_m = s.truth[i]->d_m + 0.25 * zd[i];
    s.est[i].v_mps = s.truth[i]->v_C_mps + zv[i].cwiseProduct(sigma_v);
  }
  return s;
}

/// The metrics of a hand series with the evaluation window starting at its first frame.
Evaluation evaluateFromStart(const Series& s) {
  EvaluationOptions opt;
  opt.start_delay_s = 0.0;
  return evaluate(s.est, s.truth, opt);
}

// The status's honesty counts every frame that says tracking, before the evaluation window too: a start that
// tracks 5 sigma off is counted although the window (from 3 s after the first update) never sees it.
TEST(MetricsConsistency, TrackingFramesBeyondThreeSigmaOverTheWholeRun) {
  Series s = handSeries();  // z_d = 0, 1, 3, -2, 0 at 0, 1/30, ..., 4/30 s, sigma_d 0.25 m
  for (EstimateRow& e : s.est) e.status = "tracking";
  s.est[0].d_m = s.truth[0]->d_m + 5.0 * 0.25;  // the first frame (before any window): 5 sigma
  s.est[1].status = "initializing";             // not counted
  s.est[2].d_m = s.truth[2]->d_m + 3.5 * 0.25;  // 3.5 sigma
  s.est[4].v_mps.y() = s.truth[4]->v_C_mps.y() - 4.0 * 0.5;  // velocity 4 sigma off on its y axis
  s.est[0].sigma_v_mps.z() = 0.0;                             // no velocity sigma: its d counts, its v not
  EvaluationOptions opt;
  opt.start_delay_s = 10.0;  // the window holds no frame
  const Evaluation ev = evaluate(s.est, s.truth, opt);
  EXPECT_EQ(ev.frames, 0);
  // None says tracking: nothing counted, no largest value.
  Series quiet = s;
  for (EstimateRow& e : quiet.est) e.status = "initializing";
  const Evaluation none = evaluate(quiet.est, quiet.truth, opt);
  EXPECT_EQ(none.tracking_frames, 0);
  EXPECT_TRUE(std::isnan(none.max_abs_z_d_tracking));
  EXPECT_EQ(none.tracking_beyond3_v, 0);
  EXPECT_TRUE(std::isnan(none.max_abs_z_v_tracking));
  EXPECT_EQ(ev.tracking_frames, 4);
  EXPECT_EQ(ev.tracking_beyond3_d, 2);
  EXPECT_DOUBLE_EQ(ev.max_abs_z_d_tracking, 5.0);
  // The velocity over frames 2, 3, 4 (frame 0 has no velocity sigma): largest |z_v,i| 1, 3 (not beyond), 4.
  EXPECT_EQ(ev.tracking_beyond3_v, 1);
  EXPECT_DOUBLE_EQ(ev.max_abs_z_v_tracking, 4.0);
  // Exactly 3 is not beyond.
  s.est[0].d_m = s.truth[0]->d_m + 3.0 * 0.25;
  EXPECT_EQ(evaluate(s.est, s.truth, opt).tracking_beyond3_d, 1);
  EXPECT_NE(evaluationSummary(ev).find("|z_d| above 3 on 2, largest 5.0; largest |z_v,i| above 3 on 1, largest 4.0"),
            std::string::npos)
      << evaluationSummary(ev);
}

TEST(MetricsConsistency, HandComputedCase) {
  const Series s = handSeries();
  ASSERT_EQ(s.est.size(), 5u);
  const Evaluation ev = evaluateFromStart(s);
  ASSERT_EQ(ev.frames, 4);
  EXPECT_EQ(ev.consistency_frames, 4);
  EXPECT_EQ(ev.consistency_frames_excluded, 0);
  EXPECT_DOUBLE_EQ(ev.coverage2_d, 0.75);
  EXPECT_DOUBLE_EQ(ev.coverage2_v, 9.0 / 12.0);
  EXPECT_DOUBLE_EQ(ev.nees_mean, (1.0 + 10.0 + 25.5 + 12.0) / 4.0);
  EXPECT_DOUBLE_EQ(ev.nees_median, 11.0);
  // The four frames after the first say tracking: |z_d| at most 3, none beyond it.
  EXPECT_EQ(ev.tracking_frames, 4);
  EXPECT_EQ(ev.tracking_beyond3_d, 0);
  EXPECT_DOUBLE_EQ(ev.max_abs_z_d_tracking, 3.0);
  EXPECT_EQ(ev.tracking_beyond3_v, 0);  // the largest |z_v,i| of the four: 0, 1, 3, 2
  EXPECT_DOUBLE_EQ(ev.max_abs_z_v_tracking, 3.0);
  // Second half of the window [1/30, 4/30] s: frames 3 and 4.
  EXPECT_DOUBLE_EQ(ev.coverage2_d_last_half, 1.0);
  EXPECT_DOUBLE_EQ(ev.coverage2_v_last_half, 0.5);
  EXPECT_DOUBLE_EQ(ev.nees_mean_last_half, 18.75);

  // The same through consistency() on chosen frames; frames without truth are skipped, not counted as excluded.
  Consistency c = consistency(s.est, s.truth, {2, 3});
  EXPECT_EQ(c.frames, 2);
  EXPECT_DOUBLE_EQ(c.coverage2_d, 0.5);
  EXPECT_DOUBLE_EQ(c.coverage2_v, 0.5);
  EXPECT_DOUBLE_EQ(c.nees_mean, 17.75);
  EXPECT_DOUBLE_EQ(c.nees_median, 17.75);
  Series no_truth = s;
  no_truth.truth[2].reset();
  c = consistency(no_truth.est, no_truth.truth, {1, 2, 3});
  EXPECT_EQ(c.frames, 2);
  EXPECT_EQ(c.excluded, 0);
  EXPECT_DOUBLE_EQ(c.nees_mean, (1.0 + 25.5) / 2.0);
  c = consistency(s.est, s.truth, {});
  EXPECT_EQ(c.frames, 0);
  EXPECT_TRUE(std::isnan(c.coverage2_d) && std::isnan(c.nees_mean));
}

TEST(MetricsConsistency, ZeroSigmaFrameIsExcludedExactly) {
  Series s = handSeries();
  s.est[2].sigma_v_mps.y() = 0.0;  // frame 2 (NEES 10, d outside) leaves the figures
  const Evaluation ev = evaluateFromStart(s);
  EXPECT_EQ(ev.frames, 4);
  EXPECT_EQ(ev.consistency_frames, 3);
  EXPECT_EQ(ev.consistency_frames_excluded, 1);
  EXPECT_DOUBLE_EQ(ev.coverage2_d, 1.0);
  EXPECT_DOUBLE_EQ(ev.coverage2_v, 6.0 / 9.0);
  EXPECT_DOUBLE_EQ(ev.nees_mean, (1.0 + 25.5 + 12.0) / 3.0);
  EXPECT_DOUBLE_EQ(ev.nees_median, 12.0);
}

TEST(MetricsConsistency, NonFiniteEstimateIsOutsideTheBandAndMakesTheNeesNaN) {
  Series s = handSeries();
  s.est[4].d_m = std::numeric_limits<double>::quiet_NaN();
  const Evaluation ev = evaluateFromStart(s);
  EXPECT_TRUE(ev.diverged);
  EXPECT_EQ(ev.consistency_frames, 4);
  EXPECT_DOUBLE_EQ(ev.coverage2_d, 0.5);
  EXPECT_TRUE(std::isnan(ev.nees_mean));
  EXPECT_TRUE(std::isnan(ev.nees_median));
}

}  // namespace
}  // namespace eval
}  // namespace diekf
