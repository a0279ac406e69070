#include "diekf/feature_update.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "gauss_newton.h"

namespace diekf {

namespace {
/// Fewest tracked corners for an update (2 rows each; the prior regularises the rest).
constexpr int kMinTracks = 4;
}  // namespace

FeatureUpdate::FeatureUpdate(const FeatureParams& feature, const PhotometricParams& iteration)
    : feature_(feature), iteration_(iteration) {}

UpdateStats FeatureUpdate::update(const PreprocessedFrame& ref, const PreprocessedFrame& cur, const PinholeK& K,
                                  const Vec3& gyro_mean_C, double dt_s, State* x, ErrorCov* P, double state_lag_s) {
  UpdateStats stats;
  if (x == nullptr || P == nullptr || ref.gray8.empty() || ref.gray8.type() != CV_8UC1 ||
      cur.gray8.size() != ref.gray8.size() || cur.gray8.type() != CV_8UC1 || !(dt_s > 0.0) ||
      !std::isfinite(dt_s) || !gyro_mean_C.allFinite() || !x->allFinite() || !P->allFinite() ||
      !(feature_.pixel_noise_sigma_px > 0.0) || feature_.max_corners < 1) {
    return stats;
  }

  // Corners in the reference image, tracked into the current one (pyramidal LK).
  cv::goodFeaturesToTrack(ref.gray8, ref_pts_, feature_.max_corners, feature_.quality_level,
                          feature_.min_distance_px);
  if (static_cast<int>(ref_pts_.size()) < kMinTracks) return stats;
  const int win = std::max(3, feature_.window_px | 1);
  int flags = 0;
  if (feature_.predict_flow) {
    // Start each track where the prior predicts it: invert the warp (current -> reference) by a fixed-point
    // iteration p_c <- p_c - (warp(p_c) - p_r); a track the warp cannot place starts at its reference position.
    cur_pts_.resize(ref_pts_.size());
    for (std::size_t i = 0; i < ref_pts_.size(); ++i) {
      const Vec2 p_r(ref_pts_[i].x, ref_pts_[i].y);
      Vec2 p_c = p_r;
      for (int it = 0; it < 4; ++it) {
        const Vec2 w = warpToReference(*x, K, gyro_mean_C, dt_s, p_c.x(), p_c.y(), nullptr, state_lag_s);
        if (!w.allFinite()) {
          p_c = p_r;
          break;
        }
        p_c -= w - p_r;
      }
      cur_pts_[i] = cv::Point2f(static_cast<float>(p_c.x()), static_cast<float>(p_c.y()));
    }
    flags = cv::OPTFLOW_USE_INITIAL_FLOW;
  }
  cv::calcOpticalFlowPyrLK(ref.gray8, cur.gray8, ref_pts_, cur_pts_, status_, err_, cv::Size(win, win),
                           std::max(0, feature_.pyramid_levels - 1),
                           cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 30, 0.01), flags);

  // Keep successfully tracked pairs that land inside the current image (compacted in place).
  const float max_x = static_cast<float>(cur.gray8.cols - 1);
  const float max_y = static_cast<float>(cur.gray8.rows - 1);
  const int detected = static_cast<int>(ref_pts_.size());
  int n = 0;
  for (int i = 0; i < detected; ++i) {
    const cv::Point2f& c = cur_pts_[i];
    if (!status_[i] || !(c.x >= 0.0f && c.x <= max_x && c.y >= 0.0f && c.y <= max_y)) continue;
    ref_pts_[n] = ref_pts_[i];
    cur_pts_[n] = c;
    ++n;
  }
  stats.valid_ratio = static_cast<double>(n) / detected;
  if (n < kMinTracks || stats.valid_ratio < iteration_.min_valid_ratio) return stats;

  // The filter's warp maps CURRENT pixels to REFERENCE positions, so the innovation of a track is
  // r = ref_pt - p_r(cur_pt; x) and dr/d delta = -J: S = J, the same sign convention as the photometric rows.
  const double inv_var = 1.0 / (feature_.pixel_noise_sigma_px * feature_.pixel_noise_sigma_px);
  const double huber_px = feature_.huber_threshold_px;
  auto linearize_at = [&](const State& x_j, internal::ObsMat* A, internal::ObsVec* b) {
    WarpJacobian J;
    for (int i = 0; i < n; ++i) {
      const Vec2 p_r = warpToReference(x_j, K, gyro_mean_C, dt_s, cur_pts_[i].x, cur_pts_[i].y, &J,
                                       state_lag_s);
      if (!p_r.allFinite()) continue;  // ray behind the reference camera: no measurement
      const Vec2 r(ref_pts_[i].x - p_r.x(), ref_pts_[i].y - p_r.y());
      const double norm = r.norm();
      const double w = (huber_px > 0.0 && norm > huber_px) ? inv_var * huber_px / norm : inv_var;
      A->noalias() += w * (J.transpose() * J);
      b->noalias() += w * (J.transpose() * r);
    }
    return true;
  };
  const internal::IterationResult it = internal::iterateInformationForm(
      iteration_.max_passes, iteration_.stop_threshold, linearize_at, x, P);
  stats.applied = it.ok;
  stats.passes = it.passes;
  stats.last_step_norm = it.last_step_norm;

  // RMS innovation (px) at the final estimate.
  double sum2 = 0.0;
  int finite = 0;
  for (int i = 0; i < n; ++i) {
    const Vec2 p_r = warpToReference(*x, K, gyro_mean_C, dt_s, cur_pts_[i].x, cur_pts_[i].y, nullptr,
                                     state_lag_s);
    if (!p_r.allFinite()) continue;
    sum2 += (Vec2(ref_pts_[i].x, ref_pts_[i].y) - p_r).squaredNorm();
    ++finite;
  }
  stats.rms_residual = finite > 0 ? std::sqrt(sum2 / finite) : 0.0;
  return stats;
}

}  // namespace diekf
