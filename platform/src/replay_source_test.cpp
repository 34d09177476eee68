#include "stillpoint/platform/replay_source.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "stillpoint/dataset/testing.hpp"

namespace stillpoint::platform {
namespace {

using namespace std::chrono_literals;

class ReplaySourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("sp_replay_source_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    dataset::testing::SyntheticDatasetOptions o;
    o.n_frames = 6;
    o.rate_hz = 5.0;
    o.jitter_s = 0.001;
    auto written = dataset::testing::writeSyntheticTumDataset(dir_.string(), o);
    ASSERT_TRUE(written) << written.error();
    data_ = *written;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  ReplaySource make(bool paced, bool loop = false, std::uint64_t max_frames = 0) {
    ReplaySourceOptions o;
    o.path = dir_.string();
    o.paced = paced;
    o.loop = loop;
    o.max_frames = max_frames;
    return ReplaySource(o, data_.camera);
  }

  std::filesystem::path dir_;
  dataset::testing::SyntheticDataset data_;
};

TEST_F(ReplaySourceTest, DeliversEveryFrameInOrderThenEnds) {
  ReplaySource source = make(false);
  ASSERT_TRUE(source.open());
  EXPECT_FALSE(source.live());
  CameraFrame frame;
  for (std::size_t k = 0; k < data_.colour_stamps.size(); ++k) {
    SourceResult r = source.next(frame, 100ms);
    ASSERT_EQ(r.event, SourceEvent::kFrame) << r.message;
    EXPECT_EQ(frame.stamp, data_.colour_stamps[k]);
    EXPECT_EQ(frame.sequence, k);
    EXPECT_EQ(frame.gray.type(), CV_8UC1);
    EXPECT_EQ(frame.depth_m.type(), CV_32FC1);
    EXPECT_EQ(frame.gray.cols, data_.camera.width);
  }
  EXPECT_EQ(source.next(frame, 100ms).event, SourceEvent::kEnd);
  EXPECT_EQ(source.next(frame, 100ms).event, SourceEvent::kEnd);
}

TEST_F(ReplaySourceTest, ColourOnlyWhenAskedFor) {
  ReplaySource grey = make(false);
  ASSERT_TRUE(grey.open());
  CameraFrame frame;
  ASSERT_EQ(grey.next(frame, 100ms).event, SourceEvent::kFrame);
  EXPECT_TRUE(frame.bgr.empty());

  ReplaySourceOptions o;
  o.path = dir_.string();
  o.paced = false;
  o.colour = true;  // what the daemon sets when the semantic module is on
  ReplaySource colour(o, data_.camera);
  ASSERT_TRUE(colour.open());
  ASSERT_EQ(colour.next(frame, 100ms).event, SourceEvent::kFrame);
  ASSERT_EQ(frame.bgr.type(), CV_8UC3);
  EXPECT_EQ(frame.bgr.size(), frame.gray.size());
}

TEST_F(ReplaySourceTest, MaxFramesAndLoopKeepStampsIncreasing) {
  ReplaySource source = make(false, true, 15);
  ASSERT_TRUE(source.open());
  CameraFrame frame;
  Timestamp previous;
  for (int k = 0; k < 15; ++k) {
    ASSERT_EQ(source.next(frame, 100ms).event, SourceEvent::kFrame);
    if (k > 0) {
      EXPECT_GT(frame.stamp, previous);
    }
    previous = frame.stamp;
  }
  EXPECT_EQ(source.next(frame, 100ms).event, SourceEvent::kEnd);
}

// An unreadable first or last frame: each lap still starts one frame period
// after the last stamp of the list (the lap's stamps used to jump back).
TEST_F(ReplaySourceTest, LoopKeepsStampsIncreasingPastUnreadableEnds) {
  std::ofstream(dir_ / "rgb" / (data_.colour_stamps.front().toSecondsString() + ".png")) << "not a png";
  std::ofstream(dir_ / "rgb" / (data_.colour_stamps.back().toSecondsString() + ".png")) << "not a png";
  ReplaySource source = make(false, true, 12);
  ASSERT_TRUE(source.open());
  CameraFrame frame;
  std::vector<Timestamp> stamps;
  for (int calls = 0; calls < 40 && stamps.size() < 12; ++calls) {
    const SourceResult r = source.next(frame, 100ms);
    if (r.event == SourceEvent::kBadFrame) continue;
    ASSERT_EQ(r.event, SourceEvent::kFrame) << r.message;
    stamps.push_back(frame.stamp);
  }
  ASSERT_EQ(stamps.size(), 12u);
  for (std::size_t k = 1; k < stamps.size(); ++k) EXPECT_GT(stamps[k], stamps[k - 1]) << "frame " << k;
}

// A gap of 1e6 s in the stamps (11.6 days) is not slept through.
TEST_F(ReplaySourceTest, PacedDoesNotSleepThroughAStampGap) {
  for (const char* list : {"rgb.txt", "depth.txt"}) {
    std::ifstream in(dir_ / list);
    std::string text, line;
    int frame = 0;
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#' && frame++ >= 3) {
        const auto space = line.find(' ');
        line = std::to_string(std::stod(line.substr(0, space)) + 1e6) + line.substr(space);
      }
      text += line + "\n";
    }
    std::ofstream(dir_ / list) << text;
  }
  ReplaySource source = make(true);
  ASSERT_TRUE(source.open());
  CameraFrame frame;
  int delivered = 0;
  for (int calls = 0; calls < 60 && delivered < 6; ++calls)
    delivered += source.next(frame, 100ms).event == SourceEvent::kFrame;
  EXPECT_EQ(delivered, 6) << "paced replay waited for the gap";
}

TEST_F(ReplaySourceTest, PacedTimesOutBeforeTheNextFrameIsDue) {
  ReplaySource source = make(true);
  ASSERT_TRUE(source.open());
  CameraFrame frame;
  ASSERT_EQ(source.next(frame, 100ms).event, SourceEvent::kFrame);  // first frame: at once
  // The next frame is due ~200 ms later (5 Hz): a 10 ms wait cannot deliver it.
  EXPECT_EQ(source.next(frame, 10ms).event, SourceEvent::kTimeout);
  SourceResult r;
  for (int tries = 0; tries < 100 && (r = source.next(frame, 50ms)).event == SourceEvent::kTimeout; ++tries) {
  }
  ASSERT_EQ(r.event, SourceEvent::kFrame);
  EXPECT_EQ(frame.stamp, data_.colour_stamps[1]);
  EXPECT_EQ(frame.sequence, 1u);
}

TEST_F(ReplaySourceTest, MissingFolderIsAnErrorNamingIt) {
  ReplaySourceOptions o;
  o.path = (dir_ / "nope").string();
  ReplaySource source(o, data_.camera);
  Status s = source.open();
  ASSERT_FALSE(s);
  EXPECT_NE(s.error().find("nope"), std::string::npos) << s.error();
  o.path.clear();
  EXPECT_FALSE(ReplaySource(o, data_.camera).open());
}

}  // namespace
}  // namespace stillpoint::platform
