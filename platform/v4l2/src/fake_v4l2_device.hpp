#pragma once
// A V4L2 driver in memory for the capture and source tests: YUYV frames whose
// luma encodes the frame number (chroma 128), or Z16 frames whose every pixel
// is 1000 + the frame number, with knobs for the failures the capture logic
// must handle. The fake never blocks: poll() says at once whether a frame is
// pending.
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <deque>
#include <string>
#include <vector>

#include "stillpoint/platform/v4l2_capture.hpp"

namespace stillpoint::platform::fake {

struct FakeState {
  std::string path = "/dev/video0";  // the only path open() accepts
  int width = 8, height = 4;
  std::uint32_t granted_buffers = 3;
  std::uint32_t offered_width = 0;   // != 0: S_FMT adjusts the width to this
  std::uint32_t offered_format = 0;  // != 0: S_FMT answers with this pixel format
  std::uint32_t format = 0;          // what S_FMT settled on
  bool capture_capability = true;
  bool gone = false;               // unplugged: poll errors, DQBUF ENODEV
  std::uint32_t short_frame = 0;   // this frame (1-based) arrives truncated
  std::deque<std::int64_t> stamps_us;  // stamps of the next frames (else 100 s + n x 33.333 ms)
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
    if (path != s_->path || s_->gone) {
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
        if (s_->offered_format) f->fmt.pix.pixelformat = s_->offered_format;
        f->fmt.pix.bytesperline = f->fmt.pix.width * 2;
        s_->format = f->fmt.pix.pixelformat;
        return 0;
      }
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        r->count = std::min(r->count, s_->granted_buffers);
        s_->queued.clear();  // a new set of buffers, all owned by user space
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
        if (s_->format == V4L2_PIX_FMT_Z16) {
          const std::uint16_t value = static_cast<std::uint16_t>(1000 + s_->produced);
          for (std::size_t i = 0; i + 1 < mem.size(); i += 2) std::memcpy(&mem[i], &value, 2);
        } else {
          for (std::size_t i = 0; i < mem.size(); i += 2) {
            mem[i] = static_cast<std::uint8_t>(s_->produced);  // luma
            mem[i + 1] = 128;                                     // chroma
          }
        }
        b->bytesused = s_->produced == s_->short_frame ? 5 : mem.size();
        b->sequence = s_->produced - 1;
        std::int64_t stamp_us = 100'000'000 + std::int64_t(s_->produced) * 33333;
        if (!s_->stamps_us.empty()) {
          stamp_us = s_->stamps_us.front();
          s_->stamps_us.pop_front();
        }
        b->timestamp.tv_sec = stamp_us / 1'000'000;
        b->timestamp.tv_usec = stamp_us % 1'000'000;
        return 0;
      }
      case VIDIOC_STREAMON: s_->streaming = true; return 0;
      case VIDIOC_STREAMOFF:  // returns every buffer to user space
        s_->streaming = false;
        s_->queued.clear();
        return 0;
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

}  // namespace stillpoint::platform::fake
