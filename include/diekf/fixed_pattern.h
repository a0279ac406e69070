// Camera-fixed photometric structure (docs/noise_model.md section 11): vignetting, the drone's own shadow, lens
// dirt (a per-pixel gain g) and an IR projector's dots or glare (a per-pixel offset a), learned online from the
// working images and removed from them before the photometric update.
//
// Model, per working pixel p and image t, after dividing the image by its own mean (which removes exposure and
// gain changes): u_t(p) = g(p) R_t(p) + a(p), R_t the ground's radiance. While the camera moves over the ground,
// R_t(p) decorrelates over time and has (nearly) the same temporal mean c and spread S at every pixel; a
// pattern fixed in the image does not move. So from each pixel's exponentially forgotten mean m(p) and
// spread s(p):
//   g(p) = s(p) / median_p s,     c = median_p (m / g),     a(p) = m(p) - g(p) c
// each shrunk toward "no pattern" (g = 1, a = 0) unless it stands significance_sigma standard errors out of
// the statistics' own noise. The image is replaced by u' = (u - a) / g (times its mean, so that the
// preprocessing's own normalisation and the image checks are unchanged), and the pixels the model cannot
// restore (g below min_gain: saturated dots, opaque dirt) get the weight (g / min_gain)^2.
//
// By default (fixed_pattern/radial_vignetting) the smooth radial part of g is one field ln V(r) = a1 r^2 + a2 r^4
// about the principal point, learned from the ground's motion (VignettingLearner: the same ground point seen at two
// radii; the temporal mean holds the ground's large-scale structure too) and shrunk as a whole; the per-pixel
// model above works on m / V and s / V, and g then includes V.
//
// The statistics only learn from frames whose ground moved by a sizeable part of decorrelation_px since the
// last one (the filter's own velocity, distance and rotation rate say how far, imageMotionPx) and that the
// filter accepted, each pixel as far as its own ground moved (a change of scale or a turn moves the ground at the
// optical centre least: a climb over one spot is no pattern there). Before startup_samples independent samples
// nothing is corrected but the radial vignetting, applied alone once significant (its learner needs no start-up:
// the ground cancels in its pair ratios). A field that brightens the corner is never applied (a lens darkens its
// periphery). All buffers are allocated in the constructor: no allocation per frame.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/params.h"
#include "diekf/state.h"
#include "diekf/vignetting_learner.h"

namespace diekf {

/// Largest displacement (working px) of the ground through the image over dt_s, from the state's velocity over
/// distance (vartheta) and the rotation rate w (rad/s, bias removed), K the working camera: the flow at the
/// image centre f dt |(vartheta_x, vartheta_y)| + f dt |(w_x, w_y)| plus the scale and roll flow at the image's
/// half diagonal r dt (|vartheta_z| + |w_z|). An upper estimate (the terms are added, not vector-summed).
double imageMotionPx(const Vec3& vartheta_inv_s, const Vec3& rate_radps, const PinholeK& K, double dt_s);

/// The ground's shift through the working image over dt_s at the image centre (working px): the translation's
/// -f dt (vartheta_x, vartheta_y) plus the tilting's f dt (-w_y, w_x) (w: the rotation rate, rad/s, bias
/// removed); with groundTurnScale what FixedPattern accumulates to know how far the ground under its mean has
/// moved.
Vec2 groundShiftPx(const Vec3& vartheta_inv_s, const Vec3& rate_radps, const PinholeK& K, double dt_s);
/// The ground's turn (rad) and change of scale (log) in the working image over dt_s: -w_z dt about the optical axis,
/// vartheta_z dt toward the ground (the image grows); zero where unknown.
inline Vec2 groundTurnScale(const Vec3& vartheta_inv_s, const Vec3& rate_radps, double dt_s) {
  const Vec2 out(-dt_s * rate_radps.z(), dt_s * vartheta_inv_s.z());
  return dt_s > 0.0 && out.allFinite() ? out : Vec2::Zero();
}

/// A lower bound of vartheta for the two functions above while the filter has not converged: vartheta shrunk
/// toward zero by twice its 1-sigma, sqrt(trace cov) (cov: its 3 x 3 covariance), and zero where it is not
/// larger than that. The images measure vartheta (the flow over distance) long before the distance itself
/// converges, but not yet exactly: counting the ground's motion low makes the pattern's statistics count fewer
/// independent samples than they hold, never more (docs/noise_model.md section 11).
Vec3 lowerBoundVartheta(const Vec3& vartheta_inv_s, const Mat3& cov);

class FixedPattern {
 public:
  /// `width` x `height`: the working image. `flat_field` (optional, CV_32FC1 of the working size): an offline
  /// relative gain (vignetting calibration) divided out of every image before the online model.
  /// `optical_centre_px`: the principal point in the working image, the centre of the radial vignetting
  /// (negative: the image's centre).
  FixedPattern(const FixedPatternParams& params, int width, int height, const cv::Mat& flat_field = cv::Mat(),
               const Vec2& optical_centre_px = Vec2(-1.0, -1.0));

  /// In place on the blurred working image I (grey levels, row-major, width x height, contiguous): remembers
  /// the image (divided by its mean) for learn(), then, once the model is active, writes mean (u - a) / g.
  /// Returns the sum and the sum of squares of the written image (for the per-frame normalisation).
  void apply(float* I, double* sum, double* sum_sq);

  /// Learns from the image of the last apply(): `motion_px` is how far the ground moved in the working image since
  /// the previous image (imageMotionPx). Frames that moved less count as a fraction of a sample.
  /// `ground_shift_px` and `ground_turn_scale`: the ground's net shift, turn and change of scale in the image
  /// since the previous image (groundShiftPx, groundTurnScale), which tell how many different pieces of ground the
  /// mean holds and whether the mean now and an earlier snapshot of it are of different ground. The fields are
  /// computed only while the mean holds at least `min_ground_patches` different patches of ground
  /// (independentPatches: a camera hovering or holding its position sees one patch again and again, which the
  /// mean cannot tell from a fixed pattern): before, nothing is corrected but the radial vignetting once
  /// significant (radial_vignetting; every refresh_frames learning frames); after, the last fields stay.
  /// Returns true when the fields changed (the image just learned from should then be corrected again,
  /// ImagePreprocessor::reapplyPattern, so that it and the next image share one correction).
  bool learn(double motion_px, const Vec2& ground_shift_px, const Vec2& ground_turn_scale = Vec2::Zero());
  /// Waives (true) or restores the min_ground_patches condition of learn(): the estimator waives it while the
  /// images deny the motion the IMU measures (FixedPatternParams::scale_losses_waive_patches).
  void waivePatchCondition(bool waived) { patches_waived_ = waived; }
  /// How many different pieces of ground the mean holds: 1 / its variance per unit sample variance, counted over
  /// the cells of the ground's track (0 before the first sample).
  double independentGround() const { return var_factor_ > 0.0 ? 1.0 / var_factor_ : 0.0; }
  /// The same over cells of the local mean's window: how many different patches of ground (each a window of the
  /// coarser scale) the mean holds. Counted on two grids, the second shifted by half a cell along the track's four
  /// axes, and the lesser count kept: ground that jitters about a cell's edge of one grid (a camera holding its
  /// position, heading or height, which start on an edge of the first) lies inside a cell of the other.
  double independentPatches() const {
    const double v = std::max(coarse_var_factor_, coarse_shifted_var_factor_);
    return v > 0.0 ? 1.0 / v : 0.0;
  }
  /// Writes the image of the last apply() corrected with the current fields into I (grey levels), with its sum
  /// and sum of squares; false (I untouched) when there is none or the model is inactive.
  bool reapply(float* I, double* sum, double* sum_sq) const;

  /// Forgets everything learned (the next images are used as they come until the start-up is done again) but the
  /// vignetting learner's pairs: the lens is the same after the projector's dots are removed.
  void reset();

  /// True once the start-up is done and the model corrects the images.
  bool active() const { return active_; }
  /// True while the images are corrected: once active(), and before that with the radial vignetting alone once
  /// its learner's estimate is significant (radial_vignetting).
  bool corrects() const { return active_ || vignetting_only_; }
  /// Independent samples gathered (capped at memory_samples).
  double samples() const { return samples_; }
  /// Per-pixel confidence (CV_32FC1 in [0, 1]) to multiply the update's pixel weights with, or null when every
  /// pixel has full confidence (model inactive or no pixel below min_gain).
  const cv::Mat* confidence() const { return active_ && has_low_confidence_ ? &confidence_ : nullptr; }
  /// Share of the working image covered by a strong fixed pattern: |g - 1| > 0.3 or |a| > 0.5 S (0 when inactive).
  double strongFraction() const { return active_ ? strong_fraction_ : 0.0; }
  /// The learned pattern's share of the image's gradient energy (0..1; 0 when inactive): its vote in the update,
  /// which, uncorrected, is for "no motion". An IR projector's dense dots reach about half; a shadow a few %.
  double contrastShare() const { return active_ ? contrast_share_ : 0.0; }
  /// The fields in use (CV_32FC1, working size): gain g (1: none) and offset a (image-mean units; 0: none).
  /// The gain includes the radial vignetting.
  const cv::Mat& gain() const { return gain_; }
  /// The radial vignetting's part of the gain (CV_32FC1, 1 at the optical centre; all 1 when off or not
  /// significant) and its value at the image's farthest corner.
  const cv::Mat& vignetting() const { return vig_; }
  /// The learner of the radial vignetting from the ground's motion (radial_vignetting): the estimator gives it the
  /// pairs (VignettingLearner::observe, with lastImage() of both images), refresh() takes its estimate.
  VignettingLearner& vignettingLearner() { return vig_learner_; }
  /// The last applied image over its mean, before the correction (CV_32FC1), and whether it holds one (apply() ran
  /// with the model enabled on an image with a mean above 0, since the last reset()).
  const cv::Mat& lastImage() const { return last_u_; }
  bool lastImageKept() const { return last_kept_; }
  double vignettingAtCorner() const { return vig_corner_; }
  const cv::Mat& offset() const { return offset_; }

 private:
  void refresh();
  /// The radial vignetting learned from the motion (vig_learner_) into vig_ and inv_vig_, shrunk as a whole toward
  /// none unless its corner value stands significance_sigma standard errors out.
  void fitVignetting();
  /// No vignetting: V = 1 everywhere.
  void clearVignetting();
  /// Before the start-up is done: the fields are the radial vignetting alone (fitVignetting), or none while it is
  /// not significant. Returns true when the fields changed.
  bool applyVignettingOnly();
  /// Median of value(i) over every 2nd pixel in x and y (i: the pixel's index). No allocation.
  template <class Value>
  float sampleMedian(Value value);
  /// The detail ratio of the mean (mean over its local mean, minus 1) into dt, the local mean into sm (tmp:
  /// scratch, all W x H); `level`: the ground's level (<= 0: the median of the mean).
  void computeDetail(float* dt, float* sm, float* tmp, float level = 0.f);
  /// Keeps the detail in scratch_ as the newest snapshot (in the slot of the older one).
  void takeSnapshot();

  /// The detail's noise is measured against a snapshot once the two means share at most this correlation,
  /// counted over the pieces of ground they hold (ground_cells_): hovering, or flying a path again, the mean is
  /// of the same ground as the snapshot's, and their difference says nothing of the ground structure left in both
  /// (the last measured noise, or else the image's spread, is used then)...
  static constexpr double kMaxSnapshotCorrelation = 0.8;
  /// ...and a new snapshot is taken when the newest shares less than this correlation with the mean.
  static constexpr double kSnapshotRenewCorrelation = 0.5;
  /// The ground's track through the image in cells of kGroundCellSamples x decorrelation_px, kGroundSide per
  /// side, wrapped (cells kGroundSide apart share one: their ground counts as the same, which only lowers the
  /// measured correlation's chance of falling below kMaxSnapshotCorrelation). Two samples' spacing: ground 2 working
  /// px apart is still correlated 0.6-0.8 (measured, docs/results.md "Time offset and rolling shutter"), and
  /// cells of one spacing let a smooth ground's structure pass the time test as a pattern (a flight that repeats
  /// every second: 42 % of the contrast; 17 % with two, as before the cells).
  static constexpr int kGroundSide = 256;
  static constexpr double kGroundCellSamples = 2.0;

  /// Weights per ground cell: the stored value times `scale` (all cells decay at once through the scale).
  struct GroundWeights {
    std::vector<double> cell;
    double scale = 1.0;
    double at(int i) const { return cell[static_cast<size_t>(i)] * scale; }
  };
  /// The ground cell of the ground's position (working px), turn (rad) and log scale: the turn and the scale in
  /// steps that move the image's RMS radius by one cell, each step offsetting the cells (a hash: the cells only
  /// count the ground).
  /// `shift`: the grid's offset in cells along every axis (0 or 0.5).
  int groundCell(const Vec2& position_px, const Vec2& turn_scale, double cell_px, double shift = 0.0) const;
  /// Decays the weights g by kp, adds l to cell c and updates its variance factor (sum of the squared weights).
  static void addWeight(GroundWeights* g, double* var_factor, int c, double l, double kp);
  /// Half side (working px) of the local mean's window (computeDetail): 5 % of the width.
  int localMeanHalfPx() const { return std::max(1, static_cast<int>(std::lround(0.05 * width_))); }
  /// Side (working px) of the coarse cells: the local mean's window (the coarser of the two scales tested).
  double coarseCellPx() const { return 2.0 * localMeanHalfPx() + 1.0; }

  struct Snapshot {
    cv::Mat detail;             // the detail at the snapshot
    double var_factor = 0.0;    // the mean's variance then, per unit sample variance
    double cov_factor = 0.0;    // covariance of the mean now with the mean then, per unit sample variance
    GroundWeights ground;       // the mean's weights per ground cell then
    bool valid = false;
  };

  FixedPatternParams params_;
  int width_ = 0, height_ = 0;
  cv::Mat flat_inv_;    // 1 / offline flat field (empty: none)
  cv::Mat last_u_;      // last applied image over its mean (before the correction)
  cv::Mat m1_, m2_;     // exponentially weighted mean and variance of u
  cv::Mat gain_, inv_gain_, offset_, confidence_;
  cv::Mat vig_, inv_vig_;          // radial vignetting V and 1 / V
  cv::Mat radius_px_;              // distance to the optical centre, working px
  cv::Mat pixel_samples_;          // each pixel's independent samples (its ground's motion; learn())
  VignettingLearner vig_learner_;       // the radial vignetting from the ground's motion
  double vig_corner_ = 1.0;
  std::vector<float> median_buf_;
  cv::Mat smooth_, scratch_;     // local mean of the mean ratio, and its detail
  std::vector<double> colsum_;   // box filter column sums
  Snapshot snapshots_[2];        // two, so that one is old enough to compare with when the other was just taken
  int newest_ = 0;               // index of the newest snapshot
  double var_factor_ = 0.0;      // variance of the mean m1 per unit sample variance (sum over the ground cells of
                                 // their squared weights)
  GroundWeights ground_;         // the mean's weight of each ground cell
  GroundWeights coarse_;         // ... and of each coarse cell (coarseCellPx)
  double coarse_var_factor_ = 0.0;  // the mean's variance per unit sample variance counted over the coarse cells
  GroundWeights coarse_shifted_;  // ... over the coarse cells shifted by half a cell (independentPatches)
  double coarse_shifted_var_factor_ = 0.0;
  double detail_noise_per_sample_ = 0.0;  // the detail's noise per unit sample variance, last measured (0: never)
  Vec2 position_ = Vec2::Zero(); // the ground's accumulated shift through the image (working px)
  Vec2 turn_scale_ = Vec2::Zero(); // and its accumulated turn about the optical axis (rad) and log scale
  double samples_ = 0.0;
  int frames_since_refresh_ = 0;
  bool last_valid_ = false;   // last_u_ not learned from yet
  bool last_kept_ = false;    // last_u_ holds the last applied image
  double last_mean_ = 0.0;    // its mean (grey levels)
  bool active_ = false;
  bool vignetting_only_ = false;  // before active_: the fields are the radial vignetting alone
  bool patches_waived_ = false;     // learn() without the min_ground_patches condition (waivePatchCondition)
  bool has_low_confidence_ = false;
  double strong_fraction_ = 0.0;
  double contrast_share_ = 0.0;
};

/// Whether the status and diagnostics name the camera-fixed pattern: it covers at least `report_fraction` of the
/// image strongly, or holds at least `dominant_contrast_share` of its contrast (FixedPattern::strongFraction,
/// FixedPattern::contrastShare; a threshold of 0 turns its test off).
inline bool patternReported(const FixedPatternParams& p, double strong_fraction, double contrast_share) {
  return (p.report_fraction > 0.0 && strong_fraction >= p.report_fraction) ||
         (p.dominant_contrast_share > 0.0 && contrast_share >= p.dominant_contrast_share);
}

/// Loads an offline flat field (FixedPatternParams::vignetting_file): a cv::FileStorage matrix `gain` at the
/// raw resolution of `camera`, resampled to the working camera the same way the images are (through the
/// preprocessing) and normalised to a median of 1. Throws std::invalid_argument on a missing file or matrix or a
/// wrong size.
cv::Mat loadFlatField(const std::string& path, const CameraModel& camera, const PreprocessParams& preprocess);

}  // namespace diekf
