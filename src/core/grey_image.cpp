#include "diekf/grey_image.h"

#include <opencv2/imgproc.hpp>

namespace diekf {

bool toGrey8(const cv::Mat& in, ChannelOrder order, cv::Mat* out) {
  const int depth = in.depth();
  const int channels = in.channels();
  if (in.empty() || in.dims != 2 || (depth != CV_8U && depth != CV_16U) ||
      (channels != 1 && channels != 3 && channels != 4)) {
    return false;
  }
  if (channels == 1) {
    if (depth == CV_8U) {
      in.copyTo(*out);
    } else {
      in.convertTo(*out, CV_8U, 1.0 / 256.0);
    }
    return true;
  }
  const bool rgb = order == ChannelOrder::kRgb;
  const int code = channels == 3 ? (rgb ? cv::COLOR_RGB2GRAY : cv::COLOR_BGR2GRAY)
                                 : (rgb ? cv::COLOR_RGBA2GRAY : cv::COLOR_BGRA2GRAY);
  if (depth == CV_8U) {
    cv::cvtColor(in, *out, code);
  } else {  // 16-bit colour (image files): scale, then weigh the channels
    cv::Mat eight;
    in.convertTo(eight, CV_8U, 1.0 / 256.0);
    cv::cvtColor(eight, *out, code);
  }
  return true;
}

bool describeImageBuffer(const std::string& e, std::uint32_t width, std::uint32_t height, std::uint32_t step,
                         bool big_endian, std::size_t data_size, int* cv_type, ChannelOrder* order,
                         std::string* error) {
  int type = -1;
  ChannelOrder o = ChannelOrder::kBgr;
  if (e == "mono8" || e == "8UC1") {
    type = CV_8UC1;
  } else if (e == "mono16" || e == "16UC1") {
    type = CV_16UC1;
  } else if (e == "bgr8") {
    type = CV_8UC3;
  } else if (e == "rgb8") {
    type = CV_8UC3;
    o = ChannelOrder::kRgb;
  } else if (e == "bgra8") {
    type = CV_8UC4;
  } else if (e == "rgba8") {
    type = CV_8UC4;
    o = ChannelOrder::kRgb;
  } else {
    *error = "unsupported image encoding '" + e + "' (mono8, mono16, bgr8, rgb8, bgra8, rgba8)";
    return false;
  }
  const std::size_t min_step = static_cast<std::size_t>(width) * CV_ELEM_SIZE(type);
  if (width == 0 || height == 0 || step < min_step || data_size < static_cast<std::size_t>(step) * height) {
    *error = "malformed image message (size, step and data length disagree)";
    return false;
  }
  if (step % CV_ELEM_SIZE1(type) != 0 || width > 65535 || height > 65535) {
    *error = "malformed image message (row step not a multiple of the sample size, or absurd size)";
    return false;
  }
  if (CV_MAT_DEPTH(type) == CV_16U && big_endian) {
    *error = "big-endian mono16 images are not supported";
    return false;
  }
  *cv_type = type;
  *order = o;
  return true;
}

}  // namespace diekf
