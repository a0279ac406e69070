// The filter's state between images (diekf/state_predictor.h): the last posterior propagated with the filter's
// prediction and the estimator's filtered IMU, on the synthetic flight. At the posterior's time it is the
// posterior; between images its distance and velocity follow the truth about as well as the posteriors do; and it
// refuses times before the posterior or too far beyond the IMU.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/estimator.h"
#include "diekf/state_predictor.h"
#include "synthetic_flight.h"

namespace diekf {
namespace {

using test_util::flightTruth;
using test_util::renderFlightImage;
using test_util::syntheticCamera;
using test_util::SyntheticFlight;

TEST(StatePredictor, FollowsTheFlightBetweenImagesFromEachPosterior) {
  const SyntheticFlight flight;
  const CameraModel cam = syntheticCamera();
  EstimatorParams params;
  params.preprocess.working_width_px = 90;
  params.init.alpha0_inv_m = 1.0 / 0.9;  // start near the truth: this test is about the time between images
  Estimator estimator(cam, params);
  StatePredictor predictor(cam, params);

  const double imu_rate_hz = 500.0, cam_rate_hz = 30.0, duration_s = 8.0;
  cv::Mat image;
  int j = 0;
  double sq_d_post = 0.0, sq_v_post = 0.0, sq_d_pred = 0.0, sq_v_pred = 0.0;
  int n_post = 0, n_pred = 0, checked_equal = 0;
  double last_post_t = -1.0, last_post_d = 0.0;
  bool last_post_tracking = false;
  double sq_incr_err = 0.0, sq_incr = 0.0;  // distance change since the posterior: predicted - true, and true
  for (int k = 0; k <= static_cast<int>(duration_s * imu_rate_hz); ++k) {
    const double t = k / imu_rate_hz;
    const ImuSample raw{t, flight.accel_I(t), flight.gyro_I(t)};
    estimator.addImu(raw);
    const bool filtered = predictor.addImu(raw);
    if (j / cam_rate_hz <= t) {
      renderFlightImage(flight, cam, j / cam_rate_hz, &image);
      estimator.addImage(j / cam_rate_hz, image);
      ++j;
    }
    FrameResult r;
    while (estimator.popResult(&r)) {
      predictor.setPosterior(r.t_s, r.state, r.covariance);
      State x;
      ErrorCov P;
      ASSERT_TRUE(predictor.predict(r.t_s, &x, &P));  // at the posterior's time: the posterior
      EXPECT_EQ((P - r.covariance).cwiseAbs().maxCoeff(), 0.0);
      EXPECT_EQ(x.alpha, r.state.alpha);
      ++checked_equal;
      if (r.t_s > 3.0 && r.status == FilterStatus::kTracking) {
        const auto truth = flightTruth(flight, cam, r.t_s);
        sq_d_post += std::pow(r.distance_m() - truth.d_m, 2);
        sq_v_post += (r.velocity_mps() - truth.v_C).squaredNorm();
        ++n_post;
      }
      last_post_t = r.t_s;
      last_post_d = r.distance_m();
      last_post_tracking = r.status == FilterStatus::kTracking;
      // Before the posterior: refused.
      EXPECT_FALSE(predictor.predict(r.t_s - 0.01, &x, &P));
    }
    // Between images, at each filtered sample: the prediction to the newest raw stamp (the filtered samples lag
    // it by the low-pass delay; the newest one is held over the rest).
    if (filtered && last_post_t > 3.0 && last_post_tracking && t > last_post_t) {
      State x;
      ErrorCov P;
      ASSERT_TRUE(predictor.predict(t, &x, &P)) << t;
      ASSERT_TRUE(x.allFinite() && P.allFinite());
      const auto truth = flightTruth(flight, cam, t);
      sq_d_pred += std::pow(x.distance_m() - truth.d_m, 2);
      sq_v_pred += (x.velocity_mps() - truth.v_C).squaredNorm();
      const double true_change = truth.d_m - flightTruth(flight, cam, last_post_t).d_m;
      sq_incr_err += std::pow((x.distance_m() - last_post_d) - true_change, 2);
      sq_incr += true_change * true_change;
      ++n_pred;
      // Far beyond the IMU data: refused.
      EXPECT_FALSE(predictor.predict(t + 0.5, &x, &P));
    }
  }
  ASSERT_GT(n_post, 60);
  ASSERT_GT(n_pred, 2 * n_post);
  const double d_post = std::sqrt(sq_d_post / n_post), v_post = std::sqrt(sq_v_post / n_post);
  const double d_pred = std::sqrt(sq_d_pred / n_pred), v_pred = std::sqrt(sq_v_pred / n_pred);
  const double incr = std::sqrt(sq_incr / n_pred), incr_err = std::sqrt(sq_incr_err / n_pred);
  std::printf("[StatePredictor] posteriors (%d): d %.4f m, v %.4f m/s RMS; predictions at 100 Hz (%d): d %.4f m, "
              "v %.4f m/s RMS; distance change since the posterior %.2e m RMS, its error %.2e m RMS\n", n_post,
              d_post, v_post, n_pred, d_pred, v_pred, incr, incr_err);
  EXPECT_LT(d_pred, 1.2 * d_post + 0.002);
  EXPECT_LT(v_pred, 1.2 * v_post + 0.003);
  // The motion since the posterior is predicted (holding the posterior would make this error equal the change).
  EXPECT_LT(incr_err, 0.3 * incr);
  EXPECT_GT(checked_equal, 200);
}

}  // namespace
}  // namespace diekf
