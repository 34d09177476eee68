#include "stillpoint/platform/v4l2_source.hpp"

#include <gtest/gtest.h>
#include <linux/videodev2.h>

#include <cmath>
#include <functional>

#include "fake_v4l2_device.hpp"

namespace stillpoint::platform {
namespace {

using namespace std::chrono_literals;
using fake::FakeDevice;
using fake::FakeState;

// A colour node and a depth node of one camera, both fakes (8x4 pixels).
class V4l2SourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    colour_.path = "/dev/video4";
    depth_.path = "/dev/video0";
    camera_.width = 8;
    camera_.height = 4;
    camera_.fx = camera_.fy = 5;
    camera_.cx = 4;
    camera_.cy = 2;
    options_.colour_device = colour_.path;
    options_.depth_device = depth_.path;
    options_.width = 8;
    options_.height = 4;
    options_.depth_registered = true;
    options_.colour = true;
  }
  std::unique_ptr<V4l2Source> make() {
    return std::make_unique<V4l2Source>(options_, camera_, std::make_unique<FakeDevice>(&colour_),
                                        std::make_unique<FakeDevice>(&depth_));
  }
  // Queues frames with these stamps (milliseconds after 100 s) on a stream.
  static void frames(FakeState& s, std::initializer_list<double> ms) {
    for (double m : ms) s.stamps_us.push_back(100'000'000 + std::llround(m * 1000));
    s.pending += static_cast<std::uint32_t>(ms.size());
  }
  static std::int64_t stampNs(double ms) { return 100'000'000'000 + std::llround(ms * 1000) * 1000; }

  FakeState colour_, depth_;
  CameraModel camera_;
  V4l2SourceOptions options_;
};

TEST_F(V4l2SourceTest, PairsColourAndDepthByTimestamp) {
  auto source = make();
  ASSERT_TRUE(source->open());
  EXPECT_TRUE(source->live());
  EXPECT_EQ(colour_.format, V4L2_PIX_FMT_YUYV);
  EXPECT_EQ(depth_.format, V4L2_PIX_FMT_Z16);
  // Depth a little before or after colour, as two free-running nodes deliver.
  frames(colour_, {0, 33.3, 66.7, 100});
  frames(depth_, {2, 31, 69, 100.5});
  CameraFrame f;
  for (int k = 0; k < 4; ++k) {
    const SourceResult r = source->next(f, 50ms);
    ASSERT_EQ(r.event, SourceEvent::kFrame) << k << ": " << r.message;
    EXPECT_EQ(f.sequence, static_cast<std::uint64_t>(k));
    EXPECT_EQ(f.stamp.nanoseconds(), stampNs(std::vector<double>{0, 33.3, 66.7, 100}[k]));  // the colour stamp
    EXPECT_EQ(f.gray.at<std::uint8_t>(1, 1), k + 1);  // colour frame k...
    ASSERT_EQ(f.depth_m.type(), CV_32FC1);
    EXPECT_FLOAT_EQ(f.depth_m.at<float>(1, 1), (1000 + k + 1) * 0.001f);  // ...with depth frame k, in metres
    ASSERT_EQ(f.bgr.type(), CV_8UC3);
  }
  EXPECT_EQ(source->next(f, 5ms).event, SourceEvent::kTimeout);
  EXPECT_EQ(source->counters().paired, 4u);
  EXPECT_EQ(source->counters().colour_unpaired, 0u);
}

TEST_F(V4l2SourceTest, NearestDepthFrameWinsAndDepthScaleApplies) {
  options_.depth_scale = 0.0001;  // 0.1 mm units
  options_.colour = false;
  auto source = make();
  ASSERT_TRUE(source->open());
  frames(depth_, {-15, -4, 12});  // all three within 20 ms of colour at 0; -4 is nearest
  frames(colour_, {0});
  CameraFrame f;
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  EXPECT_FLOAT_EQ(f.depth_m.at<float>(0, 0), 1002 * 0.0001f);  // depth frame 2
  EXPECT_TRUE(f.bgr.empty());  // colour not asked for
  EXPECT_EQ(source->counters().depth_unpaired, 1u);  // -15 lost to -4; 12 stays for the next colour frame
}

TEST_F(V4l2SourceTest, ColourFrameWithoutDepthIsABadFrameAndTheStreamGoesOn) {
  auto source = make();
  ASSERT_TRUE(source->open());
  frames(colour_, {0, 33, 66, 100});
  frames(depth_, {1, 67, 101});  // the depth frame of colour 33 was lost
  CameraFrame f;
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  const SourceResult missing = source->next(f, 50ms);
  ASSERT_EQ(missing.event, SourceEvent::kBadFrame);
  EXPECT_NE(missing.message.find("no depth frame"), std::string::npos) << missing.message;
  EXPECT_NE(missing.message.find("100.033"), std::string::npos) << missing.message;  // names the colour frame
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  EXPECT_EQ(f.stamp.nanoseconds(), stampNs(66));
  EXPECT_FLOAT_EQ(f.depth_m.at<float>(0, 0), 1.002f);  // depth frame 2 (67 ms)
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  EXPECT_EQ(f.sequence, 2u);
  EXPECT_EQ(source->counters().colour_unpaired, 1u);
}

TEST_F(V4l2SourceTest, StalledDepthStreamTimesOutThenGivesUpOnTheColourFrame) {
  auto source = make();
  ASSERT_TRUE(source->open());
  frames(colour_, {0});
  CameraFrame f;
  // No depth at all: the frame waits (timeouts) until it is stale (100 ms).
  EXPECT_EQ(source->next(f, 30ms).event, SourceEvent::kTimeout);
  SourceResult r;
  const auto until = std::chrono::steady_clock::now() + 1s;
  do r = source->next(f, 30ms);
  while (r.event == SourceEvent::kTimeout && std::chrono::steady_clock::now() < until);
  ASSERT_EQ(r.event, SourceEvent::kBadFrame);
  EXPECT_NE(r.message.find("stalled"), std::string::npos) << r.message;
  // Depth late by more than the tolerance does not pair either.
  frames(colour_, {33});
  frames(depth_, {60});
  r = source->next(f, 30ms);
  ASSERT_EQ(r.event, SourceEvent::kBadFrame);
  EXPECT_NE(r.message.find("27.0 ms later"), std::string::npos) << r.message;
}

TEST_F(V4l2SourceTest, UnplugOfEitherDeviceIsDeviceGoneAndReopenWorks) {
  auto source = make();
  ASSERT_TRUE(source->open());
  frames(colour_, {0});
  frames(depth_, {0});
  CameraFrame f;
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  depth_.gone = true;
  frames(colour_, {33});
  SourceResult r = source->next(f, 50ms);
  ASSERT_EQ(r.event, SourceEvent::kDeviceGone);
  EXPECT_NE(r.message.find("/dev/video0"), std::string::npos) << r.message;
  source->close();
  EXPECT_EQ(colour_.open_fds + depth_.open_fds, 0);
  EXPECT_EQ(colour_.mapped + depth_.mapped, 0);
  Status reopened = source->open();  // still unplugged
  ASSERT_FALSE(reopened);
  EXPECT_NE(reopened.error().find("/dev/video0"), std::string::npos) << reopened.error();
  EXPECT_EQ(colour_.open_fds, 0);  // the colour node is released again
  depth_.gone = false;  // replugged
  ASSERT_TRUE(source->open());
  colour_.gone = true;
  r = source->next(f, 50ms);
  ASSERT_EQ(r.event, SourceEvent::kDeviceGone);
  EXPECT_NE(r.message.find("/dev/video4"), std::string::npos) << r.message;
}

TEST_F(V4l2SourceTest, CorruptDepthFrameIsABadFrame) {
  auto source = make();
  ASSERT_TRUE(source->open());
  depth_.short_frame = 1;
  frames(depth_, {0, 33});
  frames(colour_, {0, 33});
  CameraFrame f;
  SourceResult r = source->next(f, 50ms);
  ASSERT_EQ(r.event, SourceEvent::kBadFrame);
  EXPECT_NE(r.message.find("corrupt"), std::string::npos) << r.message;
  r = source->next(f, 50ms);  // colour 0 has lost its depth frame; depth 33 is past its window
  ASSERT_EQ(r.event, SourceEvent::kBadFrame) << r.message;
  ASSERT_EQ(source->next(f, 50ms).event, SourceEvent::kFrame);
  EXPECT_EQ(f.stamp.nanoseconds(), stampNs(33));
  EXPECT_EQ(source->counters().corrupt, 1u);
}

TEST_F(V4l2SourceTest, WrongFormatOrSizeIsAnOpenError) {
  {
    depth_.offered_format = V4L2_PIX_FMT_YUYV;  // a colour node given as the depth device
    auto source = make();
    Status s = source->open();
    ASSERT_FALSE(s);
    EXPECT_NE(s.error().find("/dev/video0"), std::string::npos) << s.error();
    EXPECT_NE(s.error().find("YUYV 8x4 instead of Z16 8x4"), std::string::npos) << s.error();
    EXPECT_EQ(colour_.open_fds + depth_.open_fds, 0);
  }
  {
    depth_.offered_format = 0;
    colour_.offered_format = V4L2_PIX_FMT_MJPEG;
    auto source = make();
    Status s = source->open();
    ASSERT_FALSE(s);
    EXPECT_NE(s.error().find("/dev/video4"), std::string::npos) << s.error();
    EXPECT_NE(s.error().find("MJPG"), std::string::npos) << s.error();
  }
  {
    colour_.offered_format = 0;
    camera_.width = 16;  // the camera model says another size
    auto source = make();
    Status s = source->open();
    ASSERT_FALSE(s);
    EXPECT_NE(s.error().find("differs from the camera"), std::string::npos) << s.error();
  }
}

TEST(V4l2SourceOptions, EachBadValueNamesItsField) {
  V4l2SourceOptions good;
  good.colour_device = "/dev/video4";
  good.depth_device = "/dev/video0";
  good.depth_registered = true;
  ASSERT_TRUE(good.validate());
  const std::vector<std::pair<const char*, std::function<void(V4l2SourceOptions&)>>> cases = {
      {"source.v4l2.colour_device", [](V4l2SourceOptions& o) { o.colour_device.clear(); }},
      {"source.v4l2.depth_device", [](V4l2SourceOptions& o) { o.depth_device.clear(); }},
      {"source.v4l2.depth_device", [](V4l2SourceOptions& o) { o.depth_device = o.colour_device; }},
      {"source.v4l2.width", [](V4l2SourceOptions& o) { o.width = 641; }},
      {"source.v4l2.height", [](V4l2SourceOptions& o) { o.height = 0; }},
      {"source.v4l2.fps", [](V4l2SourceOptions& o) { o.fps = -1; }},
      {"source.v4l2.depth_scale", [](V4l2SourceOptions& o) { o.depth_scale = 0; }},
      {"source.v4l2.pair_tolerance_ms", [](V4l2SourceOptions& o) { o.pair_tolerance_ms = 500; }},
      {"source.v4l2.depth_registered", [](V4l2SourceOptions& o) { o.depth_registered = false; }},
  };
  for (const auto& [field, change] : cases) {
    V4l2SourceOptions o = good;
    change(o);
    Status s = o.validate();
    ASSERT_FALSE(s) << field;
    EXPECT_EQ(s.error().rfind(field, 0), 0u) << s.error();
  }
}

}  // namespace
}  // namespace stillpoint::platform
