// Detection of an IR projector's dots in the raw images within the first seconds of motion (docs/noise_model.md
// section 11): the dots are bright specks fixed in the image, the ground's specks move with the ground.
//
// Per sampled raw image I: the white top-hat T = I - open(I) (square of side `element_px`, the opening that
// would take the dots out); a speck where T > contrast open(I) + kNoiseFloorGrey (it adds at least `contrast`
// of the brightness around it), or where I is saturated and T > kNoiseFloorGrey (a dot clipped); the speck mask dilated by one pixel (a dot whose image drifts by a pixel, as a
// real projector's does with the distance, stays in it); the masks of all sampled images intersected (M).
//
// A ground speck is no larger than the element (larger bright structure passes the opening). The image is cut
// into kBlocksX x kBlocksY blocks, and the ground's position at each block's centre is followed (addMotion: the
// filter's estimate of its shift per image pair, with the 1-sigma). A sample is independent in a block when the
// ground there stands at least element + 2 px (a dilated speck) away from where it stood in every earlier
// independent sample of that block: a ground speck is then on a pixel only by chance, so with q_k the share of
// sample k covered by specks in a tile of kTilePx x kTilePx px, what is left of the ground in M is about the
// product of the q_k of the tile's independent samples (tiles, not the whole image: near the working Nyquist a
// ground's aliasing covers whole regions with specks), while each dot stays. A block is resolved when its
// independent positions span kMotionElements elements along both image axes (or kStraightFactor times that along
// one: a thin bright line lying along a straight motion stays on its pixels), beyond twice their 1-sigma.
//
// Contrast levels: the test runs at `levels` contrasts at once, each half the one before (one opening and one mask
// per sample, the number of levels each pixel passes; per pixel its three lowest over the samples, so that M of a
// level, and the pixels that missed one or two samples, are those whose lowest passes reach it; chance products
// per level). Dots bright against their ground are found at the first; fainter ones
// (a projector far away, a ground that reflects little infrared) add less than the first contrast and hold no share
// of its M, so once a level's verdict is no dots the next, fainter level decides (its ground specks are more
// numerous, its chance products fall more slowly: it needs more samples). A level's verdict of dots counts only
// after every brighter level said no dots, so dots the first level sees are found by it as with one level.
//
// Dots: the resolved blocks cover at least half the image (a climb resolves the rim before the centre), the
// chance share over them is below a tenth of `min_share`, M's share over them is at least `min_share`, and M's
// share has stopped falling (a periodic ground can bring its specks back onto the same pixels: such chance
// agreements fall with each sample, dots do not). No dots: M's share of the whole image below `min_share` after
// kStableSamples + 1 samples (M only ever shrinks, and every dot is in every sample). After kMaxSamples samples
// without either the detector gives up without a verdict (the filter never followed the ground well enough).
// Images are sampled only when the ground moved enough in some block: a hovering camera costs one sample. All
// buffers are allocated by configure().
#pragma once

#include <array>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/types.h"

namespace diekf {
namespace internal {

class DotDetector {
 public:
  enum class Verdict { kUndecided, kDots, kNoDots };

  /// Ground motion along both axes, in elements, before a block is resolved...
  static constexpr double kMotionElements = 3.0;
  /// ...or along one of them, this many times as far.
  static constexpr double kStraightFactor = 5.0;
  /// A speck must also stand this far above the opening (grey levels): about four times a camera's read noise.
  static constexpr int kNoiseFloorGrey = 8;
  /// M's share has stopped falling when it keeps this fraction over the last kStableSamples samples.
  static constexpr double kStableFraction = 0.7;
  static constexpr int kStableSamples = 3;
  /// Sampled images after which the detector gives up (disarmed, no verdict).
  static constexpr int kMaxSamples = 64;
  /// Side of the tiles over which the chance agreements are counted, raw px.
  static constexpr int kTilePx = 16;
  /// Blocks whose ground positions are followed.
  static constexpr int kBlocksX = 4, kBlocksY = 3, kBlocks = kBlocksX * kBlocksY;

  /// Whether raw images of width x height are large enough (two tiles per block each way).
  static bool fits(int width, int height) {
    return width >= 2 * kTilePx * kBlocksX && height >= 2 * kTilePx * kBlocksY;
  }
  /// Contrast levels at most (configure's `levels`).
  static constexpr int kMaxLevels = 3;
  /// Arms the detector for raw images of width x height (allocates): specks smaller than `element_px` (odd,
  /// >= 3) that add at least `contrast` of their surroundings' brightness (at level l: contrast / 2^l, `levels`
  /// levels); dots found when they hold at least `min_share` of the image. Throws std::invalid_argument on a bad
  /// argument.
  void configure(int width, int height, int element_px, double contrast, double min_share, int levels = 1);
  /// The contrast level deciding now (0 first; after a verdict, the verdict's level): the share, M, the fill mask
  /// and the opening's side below are that level's.
  int level() const { return level_; }

  /// Still looking (configured, no verdict yet).
  bool armed() const { return armed_; }
  /// Stops looking (no verdict).
  void disarm() { armed_ = false; }
  /// Whether the next raw image should be sampled: armed, no sampled image waiting for notePosition(), and in
  /// some block the ground stands at least element + 2 px away from where it stood in every independent sample of
  /// the block so far.
  bool wantsImage() const;
  /// Samples a raw 8-bit grey image (width x height of configure(); any row stride). No allocation.
  void addImage(const cv::Mat& grey);
  /// The centre of block b (raw px), where addMotion wants the ground's shift.
  Vec2 blockCentre(int b) const;
  /// One image pair's shift of the ground at each block's centre (raw px, the current image's position minus the
  /// reference's) and its 1-sigma per axis, as the filter estimates them.
  void addMotion(const std::array<Vec2, kBlocks>& shift_px, const std::array<Vec2, kBlocks>& sigma_px);
  /// The sampled image has been processed (or dropped: `known` false): its positions (those of the last
  /// addMotion()) count when `known` (its pair was updated, or it starts the positions).
  void notePosition(bool known);
  /// The motion is unknown from here on (a restart of the filter): the positions and the chance products start
  /// again (M is kept).
  void restartMotion();
  /// The verdict, once the conditions above hold (then the detector disarms; it also disarms without one after
  /// kMaxSamples samples).
  Verdict decide();
  /// The share of the image held by fixed specks (M) over the resolved blocks (over the whole image before
  /// any is resolved), after the last sample.
  double share() const { return share_; }
  int samples() const { return samples_; }
  /// Side (odd, raw px) of the opening that takes the dots out of the last sampled image, from element_px up to
  /// max_px: the first side at which a larger one darkens M's pixels by less than kRemnantGrey more than it darkens
  /// the rest of the image (the dots' tails and clusters are then gone; what a larger element still takes is
  /// ground). One-off, after a verdict of dots: a few openings of the image. No allocation.
  int removalElement(int max_px);
  /// See removalElement: grey levels a larger element may still take from the dots, beyond what it takes from the
  /// ground (a camera's quantisation; its read noise is 1-2).
  static constexpr double kRemnantGrey = 1.0;
  /// The pixels the dots light, for filling them (ImagePreprocessor::setDotFill), into `mask` (width x height,
  /// CV_8UC1, 255: lit): the pixels that were (dilated) specks in all but at most kFillMisses of the samples (M
  /// and the dots that missed a sample's speck test), grown by one pixel at a time (3 x 3 dilation) while the new
  /// ring's mean grey on the last sample stands more than kFillTailFraction of the mean of the pixels outside it
  /// above that mean (the dots' tails: they multiply the ground's light), at most kMaxFillGrowth times. Returns the
  /// mask's share of the image. One-off, after a verdict of dots (allocates `mask` when it has not that size).
  double fillMask(cv::Mat* mask) { return fillMask(mask, kFillMisses); }
  /// The same from the pixels that were specks in all but at most `misses` samples (0: M itself; the interim fill
  /// while the test runs, when few samples would let the ground's specks in).
  double fillMask(cv::Mat* mask, int misses);
  /// M's share of the whole image after the last sample (0 before any).
  double wholeShare() const {
    return samples_ > 0 ? levels_[static_cast<size_t>(level_)].share_history[static_cast<size_t>(samples_ - 1)] : 0.0;
  }
  /// The share of the whole image held by blobs fixed in every sample: specks that stand above the opening by a
  /// diamond of the same size too (the element turned 45 degrees), at the deciding level. A dot is a blob, and
  /// neither element fits in it; the tip of a bright shape's corner (a wedge) holds the element of its own
  /// orientation, and a ground of small squares or diamonds (a fine checkerboard) makes specks of one opening only.
  double blobShare() const { return blob_share_[static_cast<size_t>(level_)]; }
  /// M's share after the last sample over its share after the one before (1 before two samples): the ground's
  /// chance agreements fall by half or more per independent sample, dots stay.
  double wholeShareRatio() const {
    if (samples_ < 2) return 1.0;
    const auto& history = levels_[static_cast<size_t>(level_)].share_history;
    const double before = history[static_cast<size_t>(samples_ - 2)];
    return before > 0.0 ? history[static_cast<size_t>(samples_ - 1)] / before : 1.0;
  }
  static constexpr int kMaxFillGrowth = 4;
  static constexpr double kFillTailFraction = 0.05;
  /// Samples a pixel may miss and still start the fill's mask (M itself misses none).
  static constexpr int kFillMisses = 2;

 private:
  struct Block {
    int x0 = 0, y0 = 0, x1 = 0, y1 = 0;      // pixel bounds [x0, x1) x [y0, y1)
    Vec2 position = Vec2::Zero();            // the ground's accumulated shift at the centre, raw px
    Vec2 uncertainty = Vec2::Zero();         // its 1-sigma, the pairs' errors taken as independent
    std::array<Vec2, kMaxSamples> samples{};  // positions of the independent samples
    int count = 0;
  };
  /// One contrast level: its speck test's share and chance products. (Its contrast: contrast_q8_[l]; its M:
  /// lowest_[0] >= levels - l.)
  struct Level {
    std::array<double, kMaxSamples> share_history{};  // M's share of the whole image after each sample
    std::vector<double> tile_chance;  // per tile: product of the speck shares of its block's independent samples
    std::vector<double> tile_q;       // per tile: speck share of the last sample (until notePosition)
    std::vector<int> tile_fixed;      // per tile: pixels in M after the last sample
  };
  bool independent(const Block& b) const;
  bool resolved(const Block& b) const;
  /// Share of level L's M over the pixels of the blocks flagged.
  double fixedShare(const Level& L, const std::array<bool, kBlocks>& use) const;
  /// The verdict of the deciding level (decide() without the levels).
  Verdict decideLevel();

  int width_ = 0, height_ = 0, radius_ = 0;
  double min_share_ = 0.0;
  double motion_px_ = 0.0;  // kMotionElements elements, raw px
  double step_px_ = 0.0;    // element + 2 px: the least distance between independent samples
  cv::Mat opened_, scratch_a_, scratch_b_;  // CV_8UC1, width x height
  cv::Mat last_, larger_;  // the last sampled image (contiguous) and a second opening of it (removalElement)
  bool armed_ = false;
  int samples_ = 0;                                   // images in M
  double share_ = 0.0;                                // see share()
  std::array<Level, kMaxLevels> levels_;
  std::array<int, kMaxLevels> contrast_q8_{};  // the levels' contrasts in 1/256, for speckLevels
  // Per pixel the lowest, second and third lowest of the (dilated) levels passed over the samples (CV_8UC1; 255
  // before a sample): M of level l is lowest_[0] >= levels - l; the pixels that missed at most 1 or 2 samples
  // lowest_[1] and lowest_[2] (fillMask).
  std::array<cv::Mat, kFillMisses + 1> lowest_;
  cv::Mat blob_lowest_;                        // per pixel the lowest (dilated) blob level passed over the samples
  std::array<double, kMaxLevels> blob_share_{};  // per level: blobShare()
  int n_levels_ = 1, level_ = 0;
  std::array<Block, kBlocks> blocks_;
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<int> tile_block_;      // per tile: its block
  std::vector<int> tile_area_;       // per tile: its pixels (the last column and row of tiles may be cut)
  bool pending_position_ = false;    // an image was sampled whose position is not noted yet
};

/// The speck mask of an image `src` and its opening `opened` (n bytes each) into `out` (255: speck, 0: not):
/// src - opened > contrast opened + DotDetector::kNoiseFloorGrey (the contrast in 1/256, contrast_q8 <= 2560),
/// or src saturated (255) and src - opened > kNoiseFloorGrey (speckLevels at one level). Exact in integers.
void speckMask(const uint8_t* src, const uint8_t* opened, size_t n, int contrast_q8, uint8_t* out);

/// speckMask's test at `levels` contrasts (contrast_q8[0..levels), falling) at once: out = the number of them a
/// pixel passes (a saturated pixel above the floor passes all). Exact in integers; 16 bytes at a time.
void speckLevels(const uint8_t* src, const uint8_t* opened, size_t n, const int* contrast_q8, int levels,
                 uint8_t* out);

}  // namespace internal
}  // namespace diekf
