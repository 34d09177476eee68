#include "stillpoint/platform/v4l2_capture.hpp"

#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <cerrno>
#include <deque>
#include <map>

namespace stillpoint::platform {
namespace {

using namespace std::chrono_literals;

// A V4L2 driver in memory: YUYV frames whose luma encodes the frame number,
// with knobs for the failures the capture logic must handle.
struct FakeState {
  int width = 8, height = 4;
  std::uint32_t granted_buffers = 3;
  std::uint32_t offered_width = 0;  // != 0: S_FMT adjusts the width to this
  bool capture_capability = true;
  bool gone = false;               // unplugged: poll errors, DQBUF ENODEV
  std::uint32_t short_frame = 0;   // this frame (1-based) arrives truncated
  std::deque<std::uint32_t> queued;  // buffer indices owned by the driver
  std::vector<std::vector<std::uint8_t>> memory;
  std::uint32_t produced = 0;
  std::uint32_t pending = 0;  // frames ready to dequeue
  int open_fds = 0, mapped = 0;
  bool streaming = false;
  std::vector<unsigned long> calls;
};

class FakeDevice final : public V4l2Device {
 public:
  explicit FakeDevice(FakeState* s) : s_(s) {}
  int open(const std::string& path) override {
    if (path != "/dev/video0") {
      errno = ENOENT;
      return -1;
    }
    ++s_->open_fds;
    return 7;
  }
  int close(int) override {
    --s_->open_fds;
    return 0;
  }
  int ioctl(int, unsigned long request, void* arg) override {
    s_->calls.push_back(request);
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* cap = static_cast<v4l2_capability*>(arg);
        cap->capabilities = V4L2_CAP_STREAMING | (s_->capture_capability ? V4L2_CAP_VIDEO_CAPTURE : 0);
        return 0;
      }
      case VIDIOC_S_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        if (s_->offered_width) f->fmt.pix.width = s_->offered_width;
        f->fmt.pix.bytesperline = f->fmt.pix.width * 2;
        return 0;
      }
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        r->count = std::min(r->count, s_->granted_buffers);
        s_->memory.assign(r->count, std::vector<std::uint8_t>(s_->width * s_->height * 2));
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->length = s_->memory.at(b->index).size();
        b->m.offset = b->index * 4096;
        return 0;
      }
      case VIDIOC_QBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        for (auto q : s_->queued)
          if (q == b->index) {
            errno = EINVAL;  // queued twice: a bug in the capture logic
            return -1;
          }
        s_->queued.push_back(b->index);
        return 0;
      }
      case VIDIOC_DQBUF: {
        if (s_->gone) {
          errno = ENODEV;
          return -1;
        }
        if (!s_->pending || s_->queued.empty()) {
          errno = EAGAIN;
          return -1;
        }
        --s_->pending;
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->index = s_->queued.front();
        s_->queued.pop_front();
        ++s_->produced;
        auto& mem = s_->memory[b->index];
        for (std::size_t i = 0; i < mem.size(); i += 2) {
          mem[i] = static_cast<std::uint8_t>(s_->produced);  // luma
          mem[i + 1] = 128;                                     // chroma
        }
        b->bytesused = s_->produced == s_->short_frame ? 5 : mem.size();
        b->sequence = s_->produced - 1;
        b->timestamp.tv_sec = 100;
        b->timestamp.tv_usec = s_->produced * 33333;
        return 0;
      }
      case VIDIOC_STREAMON: s_->streaming = true; return 0;
      case VIDIOC_STREAMOFF: s_->streaming = false; return 0;
    }
    errno = ENOTTY;
    return -1;
  }
  void* mmap(std::size_t length, int, std::int64_t offset) override {
    const std::size_t i = offset / 4096;
    if (i >= s_->memory.size() || length != s_->memory[i].size()) return MAP_FAILED;
    ++s_->mapped;
    return s_->memory[i].data();
  }
  int munmap(void*, std::size_t) override {
    --s_->mapped;
    return 0;
  }
  int poll(int, int) override {
    if (s_->gone) return -1;
    return s_->pending ? 1 : 0;
  }

 private:
  FakeState* s_;
};

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
