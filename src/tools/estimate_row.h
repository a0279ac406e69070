// Internal to the tools (not installed): one estimator result as a row of estimates.csv (docs/conventions.md
// section 4), the one conversion of diekf_bag_runner and diekf_replay, so that the two write the same file.
#pragma once

#include <algorithm>

#include "diekf/estimator.h"
#include "diekf/eval/metrics.h"

namespace diekf {
namespace tools {

inline eval::EstimateRow toEstimateRow(const FrameResult& r) {
  eval::EstimateRow row;
  row.t_s = r.t_s;
  row.d_m = r.distance_m();
  row.h_m = r.height_m();
  row.v_mps = r.velocity_mps();
  row.mu = r.state.mu.vector();
  row.g = r.state.g.vector();
  row.sigma_d_m = r.sigma_distance_m();
  row.sigma_v_mps = r.sigma_velocity_mps();
  row.iterations = r.update_applied ? std::max(1, r.passes) : 0;
  row.update_ms = r.update_ms;
  row.status = toString(r.status);
  return row;
}

}  // namespace tools
}  // namespace diekf
