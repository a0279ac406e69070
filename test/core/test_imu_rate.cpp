// The IMU rate measured from stamps and the low-pass and decimation designed for it (diekf/imu_rate.h), at the
// MYNT EYE S's 100, 200 and 500 Hz: the design keeps the 100 Hz prediction and the cut-off, the filtered and
// decimated samples follow a flight's true specific force and rate, vibration is attenuated, and a cut-off that
// cannot work is an error naming the key. docs/ros.md, "IMU rate".
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "diekf/imu_filter.h"
#include "diekf/imu_rate.h"
#include "synthetic_flight.h"

namespace diekf {
namespace {

/// Stamps at `rate_hz` from t0 with uniform jitter of +-`jitter` periods, every 37th sample missing (a gap), one
/// duplicated stamp.
std::vector<double> stamps(double rate_hz, double seconds, double jitter, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter, jitter);
  std::vector<double> t;
  for (int k = 0; k < static_cast<int>(seconds * rate_hz); ++k) {
    if (k % 37 == 36) continue;
    t.push_back(1.6e9 + (k + u(rng)) / rate_hz);
    if (k == 10) t.push_back(t.back());
  }
  return t;
}

TEST(ImuRate, MedianIntervalGivesTheRateDespiteJitterGapsAndDuplicates) {
  for (const double rate : {100.0, 200.0, 250.0, 333.0, 500.0}) {
    RateMeter meter(1.0, 20);
    bool ready = false;
    double ready_after_s = 0.0;
    const std::vector<double> t = stamps(rate, 3.0, 0.1, 7);
    for (double s : t) {
      if (!ready && meter.add(s)) {
        ready = true;
        ready_after_s = s - t.front();
      }
    }
    ASSERT_TRUE(ready) << rate;
    EXPECT_NEAR(meter.rateHz(), rate, 0.02 * rate) << rate;
    EXPECT_GE(ready_after_s, 1.0) << rate;  // the window
    EXPECT_LT(ready_after_s, 1.1) << rate;
  }
  // Fewer intervals than asked for: not ready, however long the span.
  RateMeter sparse(0.5, 20);
  for (int k = 0; k < 10; ++k) EXPECT_FALSE(sparse.add(k * 1.0));
  EXPECT_EQ(sparse.rateHz(), 0.0);
}

TEST(ImuRate, DesignKeepsTheHundredHertzPredictionAndTheCutoff) {
  const ImuParams configured;  // 500 Hz, decimation 5, 20 Hz order 2
  struct Case {
    double rate_hz;
    int decimation;
  };
  for (const Case c : {Case{100.0, 1}, Case{200.0, 2}, Case{250.0, 3}, Case{333.0, 3}, Case{500.0, 5}}) {
    std::string summary;
    const ImuParams p = designImuPreprocessing(configured, c.rate_hz, &summary);
    EXPECT_EQ(p.input_rate_hz, c.rate_hz);
    EXPECT_EQ(p.decimation_factor, c.decimation) << c.rate_hz;
    EXPECT_EQ(p.lowpass_cutoff_hz, configured.lowpass_cutoff_hz);
    EXPECT_EQ(p.lowpass_order, configured.lowpass_order);
    EXPECT_NE(summary.find("decimation " + std::to_string(c.decimation)), std::string::npos) << summary;
    // Below twice the propellers' 200 Hz the summary names the steeper order and the notches it takes.
    const bool folds = c.rate_hz < 400.0;
    EXPECT_NE(summary.find(folds ? "vibration notches, order-4" : "Hz): order-2"), std::string::npos) << summary;
  }
}

void expectError(const ImuParams& configured, double rate_hz, const std::string& must_contain) {
  try {
    designImuPreprocessing(configured, rate_hz);
    ADD_FAILURE() << "no error at " << rate_hz << " Hz with cut-off " << configured.lowpass_cutoff_hz;
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("imu/lowpass_cutoff_hz"), std::string::npos) << what;
    EXPECT_NE(what.find(must_contain), std::string::npos) << what;
  }
}

TEST(ImuRate, ACutoffThatCannotWorkIsAnErrorNamingTheKey) {
  ImuParams c;
  c.lowpass_cutoff_hz = 60.0;  // above half of 100 Hz: not designable
  expectError(c, 100.0, "100 Hz");
  c.lowpass_cutoff_hz = 55.0;  // designable at 500 and 200 Hz, but aliases at the 100 Hz prediction
  expectError(c, 500.0, "alias");
  expectError(c, 200.0, "alias");
  c.lowpass_order = 0;  // no low-pass: no cut-off to check, but the summary warns about aliasing
  std::string summary;
  EXPECT_NO_THROW(designImuPreprocessing(c, 500.0, &summary));
  EXPECT_NE(summary.find("aliases"), std::string::npos) << summary;
  EXPECT_THROW(designImuPreprocessing(ImuParams(), 0.0), std::invalid_argument);
}

/// RMS error of the decimated, delay-compensated output against the flight's true specific force (m/s^2), with
/// vibration of 2-3 m/s^2 per axis added when asked: at 150 Hz when the raw rate can carry it (above 300 Hz),
/// else at 0.4 x the rate (just below the raw Nyquist frequency, the worst case for the decimation).
struct FlightErrors {
  double accel_rms_mps2 = 0.0;
  double output_rate_hz = 0.0;
};

FlightErrors runFlight(double raw_rate_hz, const ImuParams& p, bool vibration) {
  test_util::SyntheticFlight flight;
  flight.rate = 3.0;  // up to ~0.4 Hz motion, accelerations ~3 m/s^2: the filter's delay matters
  ImuPreprocessor pre(Eigen::Isometry3d::Identity(), p);
  const double f_vib = raw_rate_hz > 300.0 ? 150.0 : 0.4 * raw_rate_hz;
  double sum2 = 0.0, first_out_s = 0.0, last_out_s = 0.0;
  int n = 0, outputs = 0;
  const double t0 = 1.0, seconds = 6.0;
  for (int k = 0; k <= static_cast<int>(seconds * raw_rate_hz); ++k) {
    const double t = t0 + k / raw_rate_hz;
    ImuSample s = flight.imuSample(t);
    if (vibration) s.accel_mps2 += Vec3(3.0, -2.0, 3.0) * std::sin(2.0 * M_PI * f_vib * t);
    ImuSample o;
    if (!pre.push(s, &o)) continue;
    if (outputs++ == 0) first_out_s = o.t_s;
    last_out_s = o.t_s;
    if (o.t_s < t0 + 1.0) continue;  // filter settling
    const Vec3 e = o.accel_mps2 - flight.imuSample(o.t_s).accel_mps2;
    sum2 += e.squaredNorm();
    ++n;
  }
  FlightErrors r;
  r.accel_rms_mps2 = std::sqrt(sum2 / std::max(1, n));
  r.output_rate_hz = outputs > 1 ? (outputs - 1) / (last_out_s - first_out_s) : 0.0;  // from the first output
  return r;
}

TEST(ImuRate, DesignedPreprocessingFollowsTheFlightAt100And200And500Hz) {
  const ImuParams configured;
  for (const double rate : {100.0, 200.0, 500.0}) {
    const ImuParams p = designImuPreprocessing(configured, rate);
    const FlightErrors clean = runFlight(rate, p, false);
    const FlightErrors shaky = runFlight(rate, p, true);
    std::printf("[ImuRate] %3.0f Hz: output %.1f Hz, accel error RMS %.2e m/s^2 clean, %.2e with vibration\n", rate,
                clean.output_rate_hz, clean.accel_rms_mps2, shaky.accel_rms_mps2);
    EXPECT_NEAR(clean.output_rate_hz, 100.0, 1.0) << rate;
    EXPECT_LT(clean.accel_rms_mps2, 1e-3) << rate;  // measured 1.3e-5 m/s^2 at each rate
    EXPECT_LT(shaky.accel_rms_mps2, 0.3) << rate;   // 3-4 m/s^2 of vibration going in; measured 0.18 at 100 Hz
    // The preprocessing designed for the 500 Hz of the configuration, fed the same stream, does not: at 100 and
    // 200 Hz it decimates to 20 and 40 Hz, and its delay compensation and cut-off are off by the rate ratio.
    if (rate < 500.0) {
      const FlightErrors assumed = runFlight(rate, configured, false);
      std::printf("[ImuRate] %3.0f Hz through the 500 Hz design: output %.1f Hz, accel error RMS %.2e m/s^2\n",
                  rate, assumed.output_rate_hz, assumed.accel_rms_mps2);
      EXPECT_LT(assumed.output_rate_hz, 50.0) << rate;
      EXPECT_GT(assumed.accel_rms_mps2, 100.0 * clean.accel_rms_mps2) << rate;  // measured 0.29 and 0.11 m/s^2
    }
  }
}

TEST(ImuRate, RecordingsAtTheConfiguredRateKeepTheConfigurationOthersGetTheirOwnDesign) {
  // diekf_bag_runner and diekf_replay measure a recording's rate first: within the tolerance the configuration is
  // used as it is (bit for bit the results of a run that trusts imu/input_rate_hz), a 100 or 200 Hz recording gets
  // the design for its rate, and too few samples to measure keep the configuration.
  const ImuParams configured;  // 500 Hz, decimation 5
  std::string summary;
  const ImuParams same = imuPreprocessingForRecording(configured, 499.99, 0.05, &summary);
  EXPECT_EQ(same.input_rate_hz, configured.input_rate_hz);
  EXPECT_EQ(same.decimation_factor, configured.decimation_factor);
  EXPECT_NE(summary.find("as configured"), std::string::npos) << summary;
  const ImuParams slow = imuPreprocessingForRecording(configured, 200.0, 0.05, &summary);
  EXPECT_EQ(slow.input_rate_hz, 200.0);
  EXPECT_EQ(slow.decimation_factor, 2);
  EXPECT_EQ(slow.lowpass_cutoff_hz, configured.lowpass_cutoff_hz);
  EXPECT_NE(summary.find("measured"), std::string::npos) << summary;
  const ImuParams hundred = imuPreprocessingForRecording(configured, 100.0, 0.05, &summary);
  EXPECT_EQ(hundred.decimation_factor, 1);
  const ImuParams unknown = imuPreprocessingForRecording(configured, 0.0, 0.05, &summary);
  EXPECT_EQ(unknown.input_rate_hz, configured.input_rate_hz);
  EXPECT_NE(summary.find("not measured"), std::string::npos) << summary;
  // A cut-off that cannot work at the measured rate is an error naming the key, as in the nodelet.
  ImuParams high_cut = configured;
  high_cut.lowpass_cutoff_hz = 60.0;
  try {
    imuPreprocessingForRecording(high_cut, 100.0, 0.05, &summary);
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("imu/lowpass_cutoff_hz"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace diekf
