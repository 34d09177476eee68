#include "stillpoint/platform/v4l2_capture.hpp"

#include <gtest/gtest.h>
#include <linux/videodev2.h>

#include "fake_v4l2_device.hpp"

namespace stillpoint::platform {
namespace {

using namespace std::chrono_literals;
using fake::FakeDevice;
using fake::FakeState;

V4l2Options small() {
  V4l2Options o;
  o.width = 8;
  o.height = 4;
  return o;
}

TEST(V4l2Capture, StreamsFramesAndRecyclesBuffers) {
  FakeState s;
  V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
  ASSERT_TRUE(cap.open());
  EXPECT_TRUE(s.streaming);
  EXPECT_EQ(s.mapped, 3);
  EXPECT_EQ(s.queued.size(), 3u);
  V4l2Frame f;
  std::string msg;
  EXPECT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kTimeout);
  s.pending = 10;  // more frames than buffers: each must be handed back
  for (std::uint32_t k = 1; k <= 10; ++k) {
    ASSERT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kFrame) << msg;
    EXPECT_EQ(f.gray.at<std::uint8_t>(3, 7), k);
    EXPECT_EQ(f.gray.cols, 8);
    EXPECT_EQ(f.sequence, k - 1);
    EXPECT_EQ(f.stamp.nanoseconds(), 100'000'000'000 + std::int64_t(k) * 33'333'000);
  }
  EXPECT_EQ(s.queued.size(), 3u);
  cap.close();
  EXPECT_FALSE(s.streaming);
  EXPECT_EQ(s.mapped, 0);
  EXPECT_EQ(s.open_fds, 0);
  cap.close();  // twice is fine
}

TEST(V4l2Capture, ColourConversionAndDepthFormat) {
  FakeState s;
  V4l2Options o = small();
  o.colour = true;
  V4l2Capture colour(std::make_unique<FakeDevice>(&s), o);
  ASSERT_TRUE(colour.open());
  s.pending = 1;
  V4l2Frame f;
  std::string msg;
  ASSERT_EQ(colour.next(f, 10ms, &msg), V4l2Event::kFrame) << msg;
  ASSERT_EQ(f.bgr.type(), CV_8UC3);
  EXPECT_EQ(f.bgr.size(), f.gray.size());
  const cv::Vec3b px = f.bgr.at<cv::Vec3b>(2, 5);
  EXPECT_EQ(px[0], px[1]);  // neutral chroma: grey
  EXPECT_EQ(px[1], px[2]);
  EXPECT_TRUE(f.depth.empty());

  FakeState d;
  V4l2Options z = small();
  z.format = V4l2Format::kZ16;
  z.fps = 30;  // the fake has no VIDIOC_S_PARM: best effort, not an error
  V4l2Capture depth(std::make_unique<FakeDevice>(&d), z);
  ASSERT_TRUE(depth.open());
  EXPECT_EQ(d.format, V4L2_PIX_FMT_Z16);
  EXPECT_EQ(depth.grantedFps(), 0.0);
  d.pending = 2;
  for (int k = 1; k <= 2; ++k) {
    ASSERT_EQ(depth.next(f, 10ms, &msg), V4l2Event::kFrame) << msg;
    ASSERT_EQ(f.depth.type(), CV_16UC1);
    EXPECT_EQ(f.depth.at<std::uint16_t>(3, 7), 1000 + k);
    EXPECT_TRUE(f.gray.empty());
  }
}

TEST(V4l2Capture, CorruptFrameIsReportedAndItsBufferReturned) {
  FakeState s;
  s.short_frame = 2;
  V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
  ASSERT_TRUE(cap.open());
  s.pending = 3;
  V4l2Frame f;
  std::string msg;
  EXPECT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kFrame);
  EXPECT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kError);
  EXPECT_NE(msg.find("corrupt"), std::string::npos) << msg;
  EXPECT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kFrame);
  EXPECT_EQ(f.gray.at<std::uint8_t>(0, 0), 3);
  EXPECT_EQ(s.queued.size(), 3u);
}

TEST(V4l2Capture, UnpluggedDeviceIsGone) {
  FakeState s;
  V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
  ASSERT_TRUE(cap.open());
  s.gone = true;
  V4l2Frame f;
  std::string msg;
  EXPECT_EQ(cap.next(f, 10ms, &msg), V4l2Event::kGone);
  cap.close();
  EXPECT_EQ(s.mapped, 0);
  EXPECT_EQ(s.open_fds, 0);
}

TEST(V4l2Capture, OpenErrorsNameTheStepAndReleaseEverything) {
  {
    FakeState s;
    V4l2Options o = small();
    o.device = "/dev/video9";
    V4l2Capture cap(std::make_unique<FakeDevice>(&s), o);
    Status st = cap.open();
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().find("/dev/video9"), std::string::npos) << st.error();
  }
  {
    FakeState s;
    s.capture_capability = false;
    V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
    Status st = cap.open();
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().find("capture"), std::string::npos) << st.error();
    EXPECT_EQ(s.open_fds, 0);
  }
  {
    FakeState s;
    s.offered_width = 6;
    V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
    Status st = cap.open();
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().find("6x4"), std::string::npos) << st.error();
  }
  {
    FakeState s;
    s.granted_buffers = 1;
    V4l2Capture cap(std::make_unique<FakeDevice>(&s), small());
    Status st = cap.open();
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().find("1 buffer"), std::string::npos) << st.error();
    EXPECT_EQ(s.mapped, 0);
    EXPECT_EQ(s.open_fds, 0);
  }
}

}  // namespace
}  // namespace stillpoint::platform
