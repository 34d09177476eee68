#include "stillpoint/synth/video_walker.hpp"

#include <algorithm>
#include <filesystem>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

// A still camera's video: a textured wall, and from frame 5 a dark walker
// (a 30 x 90 px body whose legs swing) crossing it at 4 px a frame.
struct WalkerVideo {
  fs::path path;
  int frames = 0;
  cv::Rect body(int k) const { return cv::Rect(40 + 4 * k, 60, 30, 90); }
};

WalkerVideo writeVideo(const fs::path& dir, bool walker) {
  WalkerVideo v;
  v.path = dir / (walker ? "walker.avi" : "still.avi");
  v.frames = 90;
  cv::Mat wall(240, 480, CV_8UC3);
  cv::RNG rng(3);
  cv::Mat coarse(24, 48, CV_8UC3);
  rng.fill(coarse, cv::RNG::UNIFORM, cv::Scalar::all(90), cv::Scalar::all(220));
  cv::resize(coarse, wall, wall.size(), 0, 0, cv::INTER_NEAREST);
  cv::VideoWriter writer(v.path.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 25.0, wall.size());
  EXPECT_TRUE(writer.isOpened());
  for (int k = 0; k < v.frames; ++k) {
    cv::Mat frame = wall.clone();
    if (walker && k >= 5) {
      const cv::Rect b = v.body(k);
      cv::rectangle(frame, cv::Rect(b.x, b.y, b.width, 55), cv::Scalar(30, 20, 60), cv::FILLED);
      const int swing = (k % 10 < 5 ? k % 10 : 10 - k % 10) * 3;  // legs apart by 0..15 px
      cv::rectangle(frame, cv::Rect(b.x + 2 - swing / 2, b.y + 55, 10, 35), cv::Scalar(40, 30, 30), cv::FILLED);
      cv::rectangle(frame, cv::Rect(b.x + 18 + swing / 2, b.y + 55, 10, 35), cv::Scalar(40, 30, 30), cv::FILLED);
    }
    writer.write(frame);
  }
  return v;
}

class VideoWalker : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("stillpoint_video_walker_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(VideoWalker, FollowsTheWalkerAndCutsItOutFrameByFrame) {
  const WalkerVideo v = writeVideo(dir_, true);
  Result<WalkerClip> clip = cutWalkerFromVideo(v.path.string());
  ASSERT_TRUE(clip.ok()) << clip.error();
  EXPECT_DOUBLE_EQ(clip->fps, 25.0);
  // It leaves the window's reach near the right edge: most of its 85 frames.
  EXPECT_GE(clip->colour.size(), 60u);
  ASSERT_EQ(clip->colour.size(), clip->keep.size());
  const cv::Size window = clip->colour.front().size();
  EXPECT_NEAR(window.height, 1.25 * 90, 12);
  EXPECT_NEAR(window.width, 0.75 * window.height, 2);
  int legs_apart = 0, legs_together = 0;
  std::vector<int> areas;
  for (std::size_t k = 0; k < clip->colour.size(); ++k) {
    ASSERT_EQ(clip->colour[k].size(), window);
    const cv::Mat& keep = clip->keep[k];
    // Never a sliver of the walker's area (1650 + 700 px)...
    const int kept = cv::countNonZero(keep);
    areas.push_back(kept);
    EXPECT_GT(kept, 0.4 * 2350) << "frame " << k;
    EXPECT_LT(kept, 1.3 * 2350) << "frame " << k;
    // ...and what it keeps is the walker's dark colour, not the wall.
    const cv::Scalar mean = cv::mean(clip->colour[k], keep);
    EXPECT_LT(mean[2], 90) << "frame " << k;
    // The legs move inside the window: the lowest row of the walker is
    // wider when they are apart.
    int bottom = keep.rows - 1;
    while (bottom > 0 && cv::countNonZero(keep.row(bottom)) == 0) --bottom;
    const int width = cv::countNonZero(keep.row(bottom - 4));
    if (width > 0) (width > 24 ? legs_apart : legs_together) += 1;
  }
  // ...and the whole of it in a typical frame.
  std::nth_element(areas.begin(), areas.begin() + areas.size() / 2, areas.end());
  EXPECT_NEAR(areas[areas.size() / 2], 2350, 350);
  EXPECT_GT(legs_apart, 5);
  EXPECT_GT(legs_together, 5);
}

TEST_F(VideoWalker, NoWalkerOrNoVideoIsAClearError) {
  const WalkerVideo still = writeVideo(dir_, false);
  Result<WalkerClip> none = cutWalkerFromVideo(still.path.string());
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().find("no walker"), std::string::npos) << none.error();
  Result<WalkerClip> missing = cutWalkerFromVideo((dir_ / "missing.avi").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().find("cannot read video"), std::string::npos) << missing.error();
  std::FILE* f = std::fopen((dir_ / "junk.avi").c_str(), "w");
  std::fputs("not a video", f);
  std::fclose(f);
  EXPECT_FALSE(cutWalkerFromVideo((dir_ / "junk.avi").string()).ok());
}

}  // namespace
}  // namespace stillpoint::synth
