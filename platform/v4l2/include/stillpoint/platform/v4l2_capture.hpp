#pragma once
// Capture from one V4L2 device (memory-mapped streaming I/O): colour (YUYV ->
// grey, and BGR on request) or 16-bit depth (Z16, e.g. the depth node of a
// UVC RGB-D camera). The kernel calls go through V4l2Device, a thin interface
// over open/ioctl/mmap/poll, so the capture logic is tested against a fake
// (no devices in CI).
//
// An RGB-D camera is two such captures paired by timestamp: V4l2Source
// (v4l2_source.hpp).
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

struct v4l2_buffer;

namespace stillpoint::platform {

// The system calls V4l2Capture makes. Return values and errno as the kernel's.
class V4l2Device {
 public:
  virtual ~V4l2Device() = default;
  virtual int open(const std::string& path) = 0;  // fd or -1
  virtual int close(int fd) = 0;
  virtual int ioctl(int fd, unsigned long request, void* arg) = 0;
  virtual void* mmap(std::size_t length, int fd, std::int64_t offset) = 0;  // MAP_FAILED on error
  virtual int munmap(void* address, std::size_t length) = 0;
  // Waits until fd is readable: 1 ready, 0 timeout, -1 error.
  virtual int poll(int fd, int timeout_ms) = 0;
};
// The real thing (open(2), ioctl(2), mmap(2), poll(2)).
std::unique_ptr<V4l2Device> systemV4l2Device();

enum class V4l2Format {
  kYuyv,  // colour, 4:2:2 YUYV: grey from the luma, BGR on request
  kZ16,   // depth, 16 bits per pixel in the device's unit (V4L2_PIX_FMT_Z16)
};

struct V4l2Options {
  std::string device = "/dev/video0";
  int width = 640, height = 480;
  V4l2Format format = V4l2Format::kYuyv;
  int fps = 0;                // frame interval asked with VIDIOC_S_PARM; 0 = the driver's
  bool colour = false;        // YUYV: also convert to BGR (V4l2Frame::bgr)
  std::uint32_t buffers = 4;  // driver may grant fewer (at least 2 needed)
};

struct V4l2Frame {
  Timestamp stamp;  // driver timestamp (CLOCK_MONOTONIC for most drivers)
  cv::Mat gray;     // CV_8UC1 (YUYV)
  cv::Mat bgr;      // CV_8UC3 (YUYV with options.colour)
  cv::Mat depth;    // CV_16UC1 raw device units (Z16)
  std::uint32_t sequence = 0;
};

enum class V4l2Event { kFrame, kTimeout, kGone, kError };

class V4l2Capture {
 public:
  V4l2Capture(std::unique_ptr<V4l2Device> device, V4l2Options options);
  ~V4l2Capture();
  // Opens, checks capabilities, sets the format at the size asked for (a
  // driver that offers another format or size is an error), asks for the frame
  // rate, maps the buffers and starts streaming. Errors name the device and the step.
  Status open();
  V4l2Event next(V4l2Frame& frame, std::chrono::milliseconds timeout, std::string* message);
  // Stops streaming, unmaps, closes. Safe to call twice.
  void close();
  const V4l2Options& options() const { return options_; }
  // Frame rate the driver granted (0 when it does not say, or was not asked).
  double grantedFps() const { return granted_fps_; }

 private:
  struct Buffer {
    void* start = nullptr;
    std::size_t length = 0;
  };
  Status fail(const std::string& step);
  std::unique_ptr<V4l2Device> device_;
  V4l2Options options_;
  int fd_ = -1;
  bool streaming_ = false;
  std::uint32_t bytes_per_line_ = 0;
  double granted_fps_ = 0;
  std::vector<Buffer> buffers_;
};

}  // namespace stillpoint::platform
