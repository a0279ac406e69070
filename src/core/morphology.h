// Grey-scale morphology of 8-bit images by squares, allocation-free (the caller owns every buffer): the opening
// that takes an IR projector's dots out of the raw images (ImagePreprocessor, preprocess/dot_removal_px) and the
// top-hat and dilation the projector-dot detector reads them with (DotDetector). Equal to cv::morphologyEx /
// cv::dilate with a rectangular element and their default border (what lies outside does not count), byte for
// byte (ImagePreprocessor.DotRemovalTakesProjectorDotsOut, DotDetector.MorphologyEqualsOpenCv).
#pragma once

#include <cstdint>

namespace diekf {
namespace internal {

/// Grey-scale opening of a w x h image by a square of side 2 r + 1 (minimum, then maximum, each separable) into
/// dst; a and b: scratch images of the same size. src and dst may not overlap a or b.
void openSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r);

/// Grey-scale opening of a w x h image by a diamond (the pixels within L1 distance r: a square turned 45 degrees)
/// into dst, as r erosions and then r dilations by the 3 x 3 cross; a and b: scratch images of the same size. src
/// and dst may not overlap a or b.
void openDiamond(const uint8_t* src, uint8_t* dst, uint8_t* a, uint8_t* b, int w, int h, int r);
/// Grey-scale dilation (maximum) of a w x h image over a square of side 2 r + 1 into dst; a: scratch of the same
/// size. src and dst may be the same buffer; neither may be a.
void dilateSquare(const uint8_t* src, uint8_t* dst, uint8_t* a, int w, int h, int r);

}  // namespace internal
}  // namespace diekf
