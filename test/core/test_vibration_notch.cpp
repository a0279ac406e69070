// VibrationNotch: folded propeller tones found in the IMU stream's spectrum and notched out, the motion kept.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <random>

#include "diekf/estimator.h"
#include "diekf/imu_filter.h"
#include "diekf/vibration_notch.h"
#include "synthetic_flight.h"

namespace diekf {
namespace {

using Vec6 = VibrationNotch::Vec6;

constexpr double kRateHz = 200.0;

VibrationNotch::Options options() {
  VibrationNotch::Options o;  // as ImuPreprocessor sets it up at 200 Hz
  o.min_hz = 20.0;
  o.window = 256;
  o.hop = 32;
  return o;
}

/// Amplitude of the output's component at f_hz over [t0, t1) (least squares of a sine and a cosine).
double amplitudeAt(const std::vector<double>& t, const std::vector<double>& y, double f_hz, double t0, double t1) {
  const double w = 2.0 * M_PI * f_hz;
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  Eigen::Vector3d Atb = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < t.size(); ++i) {
    if (t[i] < t0 || t[i] >= t1) continue;
    const Eigen::Vector3d row(std::sin(w * t[i]), std::cos(w * t[i]), 1.0);
    AtA += row * row.transpose();
    Atb += row * y[i];
  }
  const Eigen::Vector3d ab = AtA.ldlt().solve(Atb);
  return ab.head<2>().norm();
}

/// Runs `seconds` of x(t) through the notch; the outputs' first channel and times.
void run(VibrationNotch* n, double seconds, const std::function<Vec6(double)>& x, std::vector<double>* t,
         std::vector<double>* y) {
  for (int k = 0; k < static_cast<int>(seconds * kRateHz); ++k) {
    const double tk = k / kRateHz;
    t->push_back(tk);
    y->push_back(n->apply(x(tk))(0));
  }
}

// Two tones as a 200 Hz IMU sees a hovering quadrotor's 130 and 165 Hz (at 70 and 35 Hz), on slow motion and
// gravity: both found within a fraction of a bin, each taken down by more than 20 dB, the motion passed (its gain
// within 0.5 %) with the delay the notches report.
TEST(VibrationNotch, FindsAndRemovesFoldedTones) {
  VibrationNotch n(kRateHz, options());
  const auto x = [](double t) {
    Vec6 v = Vec6::Zero();
    v(0) = 0.5 * std::sin(2 * M_PI * 0.7 * t) + 1.5 * std::sin(2 * M_PI * 35.0 * t + 0.3) +
           1.0 * std::sin(2 * M_PI * 70.0 * t + 1.2);
    v(2) = -9.81 + 0.8 * std::sin(2 * M_PI * 35.0 * t + 2.0);
    v(3) = 0.03 * std::sin(2 * M_PI * 35.0 * t);
    return v;
  };
  std::vector<double> t, y;
  run(&n, 8.0, x, &t, &y);
  ASSERT_EQ(n.activeNotches(), 2);
  const double f0 = std::min(n.frequencyHz(0), n.frequencyHz(1)), f1 = std::max(n.frequencyHz(0), n.frequencyHz(1));
  EXPECT_NEAR(f0, 35.0, 0.3);
  EXPECT_NEAR(f1, 70.0, 0.3);
  const double a35 = amplitudeAt(t, y, 35.0, 3.0, 8.0), a70 = amplitudeAt(t, y, 70.0, 3.0, 8.0);
  std::printf("[VibrationNotch] tones at %.2f and %.2f Hz: 35 Hz 1.5 -> %.4f, 70 Hz 1.0 -> %.4f; delay %.3f samples\n",
              f0, f1, a35, a70, n.delaySamples());
  EXPECT_LT(a35, 0.15);
  EXPECT_LT(a70, 0.1);
  const double a_motion = amplitudeAt(t, y, 0.7, 3.0, 8.0);
  EXPECT_NEAR(a_motion, 0.5, 0.0025);
  // The delay at 0 Hz of a notch at f0 of quality q is sin(w0) / (2 q (1 - cos w0)) samples.
  double expected = 0.0;
  for (double f : {35.0, 70.0}) {
    const double w0 = 2 * M_PI * f / kRateHz;
    expected += std::sin(w0) / (2.0 * 3.0 * (1.0 - std::cos(w0)));
  }
  EXPECT_NEAR(n.delaySamples(), expected, 0.02);
}

// Noise and motion without a tone: no notch, the samples pass unchanged.
TEST(VibrationNotch, NoToneNoNotch) {
  VibrationNotch n(kRateHz, options());
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.05);
  for (int k = 0; k < 2000; ++k) {
    const double t = k / kRateHz;
    Vec6 v = Vec6::Zero();
    for (int i = 0; i < 6; ++i) v(i) = noise(rng);
    v(0) += 0.5 * std::sin(2 * M_PI * 0.7 * t);
    v(2) += -9.81;
    const Vec6 out = n.apply(v);
    ASSERT_EQ(n.activeNotches(), 0) << "t " << t;
    EXPECT_EQ(out, v);
  }
  EXPECT_EQ(n.delaySamples(), 0.0);
}

// A tone moving with the rotors' speed (30 -> 40 Hz over 6 s, 1.7 Hz/s) keeps a notch throughout (its peak
// smeared over the window may take a second one for a while) and stays down by more than 10 dB: the notch follows
// about 0.8 s behind (half the one-second window and a hop), 1.3 Hz here, inside its 5.8 Hz half width. Gone, its
// notches go.
TEST(VibrationNotch, FollowsAMovingToneAndDropsAGoneOne) {
  VibrationNotch n(kRateHz, options());
  double phase = 0.0;
  std::vector<double> t, y;
  int lost = 0;
  for (int k = 0; k < static_cast<int>(8.0 * kRateHz); ++k) {
    const double tk = k / kRateHz;
    const double f = tk < 2.0 ? 30.0 : std::min(40.0, 30.0 + 10.0 * (tk - 2.0) / 6.0);
    phase += 2 * M_PI * f / kRateHz;
    Vec6 v = Vec6::Zero();
    v(0) = 1.5 * std::sin(phase);
    t.push_back(tk);
    y.push_back(n.apply(v)(0));
    if (tk > 2.0 && n.activeNotches() < 1) ++lost;
  }
  EXPECT_EQ(lost, 0);
  double sum2 = 0.0;
  int count = 0;
  for (size_t i = 0; i < t.size(); ++i) {
    if (t[i] <= 3.0) continue;
    sum2 += y[i] * y[i];
    ++count;
  }
  const double rms = std::sqrt(sum2 / count);
  std::printf("[VibrationNotch] 1.5 m/s^2 tone sweeping 30 -> 40 Hz: output %.3f RMS (input 1.06)\n", rms);
  EXPECT_LT(rms, 0.3);
  for (int k = 0; k < static_cast<int>(2.0 * kRateHz); ++k) n.apply(Vec6::Zero());
  EXPECT_EQ(n.activeNotches(), 0);
}

TEST(VibrationNotch, BadOptionsThrow) {
  VibrationNotch::Options o = options();
  EXPECT_THROW(VibrationNotch(0.0, o), std::invalid_argument);
  o.min_hz = 150.0;
  EXPECT_THROW(VibrationNotch(kRateHz, o), std::invalid_argument);
  o = options();
  o.window = 100;
  EXPECT_THROW(VibrationNotch(kRateHz, o), std::invalid_argument);
  o = options();
  o.max_notches = 5;
  EXPECT_THROW(VibrationNotch(kRateHz, o), std::invalid_argument);
}

// In the preprocessing: only at rates that fold the vibration (and with imu/aliased_notch).
TEST(VibrationNotch, OnlyWhereTheRateFoldsTheVibration) {
  ImuParams p;
  EXPECT_EQ(ImuPreprocessor(Eigen::Isometry3d::Identity(), p).notch(), nullptr);  // 500 Hz
  p.input_rate_hz = 200.0;
  p.decimation_factor = 2;
  EXPECT_NE(ImuPreprocessor(Eigen::Isometry3d::Identity(), p).notch(), nullptr);
  p.aliased_notch = false;
  EXPECT_EQ(ImuPreprocessor(Eigen::Isometry3d::Identity(), p).notch(), nullptr);
  p.aliased_notch = true;
  p.lowpass_order = 0;
  EXPECT_EQ(ImuPreprocessor(Eigen::Isometry3d::Identity(), p).notch(), nullptr);
  // A 45 Hz IMU leaves too narrow a band above the 20 Hz cutoff to search (two bins): no notch, and no error.
  p.lowpass_order = 2;
  p.input_rate_hz = 45.0;
  p.decimation_factor = 1;
  EXPECT_FALSE(vibrationNotchesOn(p));
  EXPECT_EQ(ImuPreprocessor(Eigen::Isometry3d::Identity(), p).notch(), nullptr);
  p.input_rate_hz = 100.0;
  EXPECT_TRUE(vibrationNotchesOn(p));
}

// Through the estimator: a 200 Hz IMU on a vibrating airframe (130 and 165 Hz, folded to 70 and 35 Hz) names its
// notches in every result once found; a 500 Hz IMU (or the notches off) names none.
TEST(VibrationNotch, TheEstimatorReportsItsNotches) {
  const test_util::SyntheticFlight flight;
  const CameraModel cam = test_util::syntheticCamera(0.5);
  const auto lastNotches = [&](double imu_rate_hz, bool notches_on) {
    EstimatorParams p;
    p.preprocess.working_width_px = 64;
    p.imu.input_rate_hz = imu_rate_hz;
    p.imu.decimation_factor = static_cast<int>(imu_rate_hz / 100.0);
    p.imu.aliased_notch = notches_on;
    Estimator est(cam, p);
    FrameResult last;
    int j = 0, k = 0;
    while (j < 60) {  // 2 s of images at 30 Hz
      const double t_imu = k / imu_rate_hz, t_img = j / 30.0;
      if (t_imu <= t_img) {
        ImuSample s = flight.imuSample(t_imu);
        s.accel_mps2 += Vec3(1.0, 0.5, 1.5) * (std::sin(2 * M_PI * 130.0 * t_imu) + std::sin(2 * M_PI * 165.0 * t_imu));
        est.addImu(s);
        ++k;
      } else {
        cv::Mat image;
        test_util::renderFlightImage(flight, cam, t_img, &image);
        est.addImage(t_img, image);
        ++j;
      }
      FrameResult r;
      while (est.popResult(&r)) last = r;
    }
    return last.imu_notch_hz;
  };
  std::array<double, 2> f = lastNotches(200.0, true);
  std::sort(f.begin(), f.end());
  EXPECT_NEAR(f[0], 35.0, 0.5);
  EXPECT_NEAR(f[1], 70.0, 0.5);
  EXPECT_EQ(lastNotches(200.0, false), (std::array<double, 2>{}));
  EXPECT_EQ(lastNotches(500.0, true), (std::array<double, 2>{}));
}

}  // namespace
}  // namespace diekf
