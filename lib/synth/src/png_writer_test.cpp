// The stored-block PNG writer produces files OpenCV reads back bit-exactly.
#include <gtest/gtest.h>

#include <filesystem>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <unistd.h>

#include "png_writer.hpp"

namespace stillpoint::synth {
namespace {

TEST(StoredPng, RoundTripsEveryPixelType) {
  const std::string path =
      (std::filesystem::temp_directory_path() / ("stillpoint_png_" + std::to_string(::getpid()) + ".png")).string();
  cv::RNG rng(3);
  // 300 x 250 x 3 bytes spans several 64 KiB stored blocks.
  for (int type : {CV_8UC1, CV_8UC3, CV_16UC1}) {
    cv::Mat img(250, 300, type);
    rng.fill(img, cv::RNG::UNIFORM, 0, type == CV_16UC1 ? 65536 : 256);
    ASSERT_TRUE(writeStoredPng(path, img).ok());
    const cv::Mat back = cv::imread(path, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(back.type(), type);
    ASSERT_EQ(back.size(), img.size());
    EXPECT_EQ(cv::norm(back, img, cv::NORM_INF), 0.0) << type;
  }
  cv::Mat tiny(1, 1, CV_8UC3, cv::Scalar(1, 2, 3));
  ASSERT_TRUE(writeStoredPng(path, tiny).ok());
  EXPECT_EQ(cv::imread(path, cv::IMREAD_UNCHANGED).at<cv::Vec3b>(0, 0), cv::Vec3b(1, 2, 3));
  EXPECT_FALSE(writeStoredPng(path, cv::Mat(2, 2, CV_32FC1)).ok());
  EXPECT_FALSE(writeStoredPng("/nonexistent/dir/x.png", tiny).ok());
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace stillpoint::synth
