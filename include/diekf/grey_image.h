// The package's one conversion of camera images to 8-bit grey, and the description of raw image buffers
// (sensor_msgs/Image encodings) it needs. Used by the estimator (Estimator::addImage), the ROS nodelet, the bag runner
// and the importers, so every front end turns the same pixels into the same grey levels.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

namespace diekf {

/// Order of the colour channels of a 3- or 4-channel image (the 4th, alpha, is ignored).
enum class ChannelOrder { kBgr, kRgb };

/// 8-bit grey from 8- or 16-bit images with 1, 3 or 4 channels: grey as it is (copied into *out), 16-bit scaled
/// by 1/256, colour with OpenCV's luma weights (0.299 R + 0.587 G + 0.114 B) in the given channel order. *out is
/// reused when it already has the size and type (no allocation). False, *out untouched, for any other type.
bool toGrey8(const cv::Mat& in, ChannelOrder order, cv::Mat* out);

/// What a raw image buffer with a sensor_msgs/Image encoding holds: the OpenCV type of its pixels and the channel
/// order. Encodings: mono8, 8UC1, mono16, 16UC1 (little-endian), bgr8, rgb8, bgra8, rgba8. Checks the fields of a
/// possibly malformed message (sizes, row step, data length, byte order). False with the reason otherwise.
bool describeImageBuffer(const std::string& encoding, std::uint32_t width, std::uint32_t height, std::uint32_t step,
                         bool big_endian, std::size_t data_size, int* cv_type, ChannelOrder* order,
                         std::string* error);

}  // namespace diekf
