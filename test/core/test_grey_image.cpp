// The package's one grey conversion (diekf/grey_image.h) and the description of raw image buffers: what the
// estimator, the nodelet, the bag runner and the importers all use.
#include <gtest/gtest.h>

#include <string>

#include <opencv2/core.hpp>

#include "diekf/grey_image.h"

namespace diekf {
namespace {

TEST(GreyImage, GreyColourAndSixteenBit) {
  cv::Mat out;
  const cv::Mat grey = (cv::Mat_<uint8_t>(1, 3) << 0, 100, 255);
  ASSERT_TRUE(toGrey8(grey, ChannelOrder::kBgr, &out));
  EXPECT_EQ(cv::norm(out, grey, cv::NORM_INF), 0.0);
  EXPECT_NE(out.data, grey.data);  // a copy: the caller may reuse its buffer

  const cv::Mat wide = (cv::Mat_<uint16_t>(1, 2) << 32768, 65535);
  ASSERT_TRUE(toGrey8(wide, ChannelOrder::kBgr, &out));
  EXPECT_EQ(out.at<uint8_t>(0, 0), 128);
  EXPECT_EQ(out.at<uint8_t>(0, 1), 255);

  // A pure red pixel: 0.299 * 255 = 76 whichever order it is stored in; alpha ignored.
  cv::Mat bgr(1, 1, CV_8UC3, cv::Scalar(0, 0, 255)), rgb(1, 1, CV_8UC3, cv::Scalar(255, 0, 0));
  cv::Mat bgra(1, 1, CV_8UC4, cv::Scalar(0, 0, 255, 0)), rgba16(1, 1, CV_16UC4, cv::Scalar(65535, 0, 0, 9));
  for (const auto& c : {std::make_pair(bgr, ChannelOrder::kBgr), std::make_pair(rgb, ChannelOrder::kRgb),
                        std::make_pair(bgra, ChannelOrder::kBgr), std::make_pair(rgba16, ChannelOrder::kRgb)}) {
    ASSERT_TRUE(toGrey8(c.first, c.second, &out));
    ASSERT_EQ(out.type(), CV_8UC1);
    EXPECT_NEAR(out.at<uint8_t>(0, 0), 76, 1);
  }
  ASSERT_TRUE(toGrey8(rgb, ChannelOrder::kBgr, &out));  // the same bytes read as BGR: blue
  EXPECT_NEAR(out.at<uint8_t>(0, 0), 29, 1);

  // The output buffer is reused when it fits (the estimator's per-frame path allocates nothing).
  cv::Mat slot(4, 5, CV_8UC1);
  const uint8_t* before = slot.data;
  ASSERT_TRUE(toGrey8(cv::Mat(4, 5, CV_8UC3, cv::Scalar(1, 2, 3)), ChannelOrder::kBgr, &slot));
  EXPECT_EQ(slot.data, before);

  cv::Mat untouched(1, 1, CV_8UC1, cv::Scalar(42));
  EXPECT_FALSE(toGrey8(cv::Mat(2, 2, CV_32FC1), ChannelOrder::kBgr, &untouched));
  EXPECT_FALSE(toGrey8(cv::Mat(2, 2, CV_8UC2), ChannelOrder::kBgr, &untouched));
  EXPECT_FALSE(toGrey8(cv::Mat(), ChannelOrder::kBgr, &untouched));
  EXPECT_EQ(untouched.at<uint8_t>(0, 0), 42);
}

TEST(GreyImage, DescribesBuffersAndRejectsMalformedOnes) {
  int type = -1;
  ChannelOrder order;
  std::string error;
  ASSERT_TRUE(describeImageBuffer("rgba8", 4, 2, 16, false, 32, &type, &order, &error)) << error;
  EXPECT_EQ(type, CV_8UC4);
  EXPECT_EQ(order, ChannelOrder::kRgb);
  ASSERT_TRUE(describeImageBuffer("16UC1", 4, 2, 10, false, 20, &type, &order, &error)) << error;  // padded
  EXPECT_EQ(type, CV_16UC1);
  EXPECT_FALSE(describeImageBuffer("mono16", 4, 2, 9, false, 18, &type, &order, &error));  // odd step
  EXPECT_NE(error.find("step"), std::string::npos) << error;
  EXPECT_FALSE(describeImageBuffer("mono16", 4, 2, 8, true, 16, &type, &order, &error));  // big-endian
  EXPECT_FALSE(describeImageBuffer("mono8", 4, 2, 3, false, 8, &type, &order, &error));   // step < width
  EXPECT_FALSE(describeImageBuffer("mono8", 4, 2, 4, false, 7, &type, &order, &error));   // data too short
  EXPECT_FALSE(describeImageBuffer("mono8", 0, 2, 4, false, 8, &type, &order, &error));   // empty
  EXPECT_FALSE(describeImageBuffer("bayer_rggb8", 4, 2, 4, false, 8, &type, &order, &error));
  EXPECT_NE(error.find("bayer_rggb8"), std::string::npos) << error;
}

}  // namespace
}  // namespace diekf
