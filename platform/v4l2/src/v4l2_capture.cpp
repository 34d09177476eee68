#include "stillpoint/platform/v4l2_capture.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <opencv2/imgproc.hpp>

namespace stillpoint::platform {
namespace {

class SystemDevice final : public V4l2Device {
 public:
  int open(const std::string& path) override { return ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC); }
  int close(int fd) override { return ::close(fd); }
  int ioctl(int fd, unsigned long request, void* arg) override {
    int r;
    do r = ::ioctl(fd, request, arg);
    while (r == -1 && errno == EINTR);
    return r;
  }
  void* mmap(std::size_t length, int fd, std::int64_t offset) override {
    return ::mmap(nullptr, length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, offset);
  }
  int munmap(void* address, std::size_t length) override { return ::munmap(address, length); }
  int poll(int fd, int timeout_ms) override {
    pollfd p{fd, POLLIN, 0};
    const int r = ::poll(&p, 1, timeout_ms);
    if (r > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL))) return -1;
    return r;
  }
};

std::uint32_t fourcc(V4l2Format f) { return f == V4l2Format::kZ16 ? V4L2_PIX_FMT_Z16 : V4L2_PIX_FMT_YUYV; }
const char* formatName(V4l2Format f) { return f == V4l2Format::kZ16 ? "Z16" : "YUYV"; }
std::string fourccText(std::uint32_t code) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((code >> (8 * i)) & 0xff);
    s += (c >= 32 && c < 127) ? c : '?';
  }
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

}  // namespace

std::unique_ptr<V4l2Device> systemV4l2Device() { return std::make_unique<SystemDevice>(); }

V4l2Capture::V4l2Capture(std::unique_ptr<V4l2Device> device, V4l2Options options)
    : device_(std::move(device)), options_(std::move(options)) {}

V4l2Capture::~V4l2Capture() { close(); }

Status V4l2Capture::fail(const std::string& step) {
  const std::string message = "v4l2 " + options_.device + ": " + step + ": " + std::strerror(errno);
  close();
  return Error{message};
}

Status V4l2Capture::open() {
  close();
  fd_ = device_->open(options_.device);
  if (fd_ < 0) return fail("cannot open");
  v4l2_capability cap{};
  if (device_->ioctl(fd_, VIDIOC_QUERYCAP, &cap) < 0) return fail("VIDIOC_QUERYCAP (not a V4L2 device?)");
  const std::uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
    errno = ENOTSUP;
    return fail("no video capture with streaming I/O");
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  fmt.fmt.pix.width = options_.width;
  fmt.fmt.pix.height = options_.height;
  fmt.fmt.pix.pixelformat = fourcc(options_.format);
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (device_->ioctl(fd_, VIDIOC_S_FMT, &fmt) < 0) return fail("VIDIOC_S_FMT");
  // The driver may adjust the format: accept only what we asked for.
  if (fmt.fmt.pix.pixelformat != fourcc(options_.format) || int(fmt.fmt.pix.width) != options_.width ||
      int(fmt.fmt.pix.height) != options_.height) {
    errno = EINVAL;
    return fail("driver offers " + fourccText(fmt.fmt.pix.pixelformat) + " " + std::to_string(fmt.fmt.pix.width) +
                "x" + std::to_string(fmt.fmt.pix.height) + " instead of " + formatName(options_.format) + " " +
                std::to_string(options_.width) + "x" + std::to_string(options_.height));
  }
  // Both formats have 2 bytes per pixel.
  bytes_per_line_ = fmt.fmt.pix.bytesperline ? fmt.fmt.pix.bytesperline : 2 * options_.width;
  if (bytes_per_line_ < 2u * options_.width) {
    errno = EINVAL;
    return fail("driver reports " + std::to_string(bytes_per_line_) + " bytes per line for " +
                std::to_string(options_.width) + " pixels");
  }
  granted_fps_ = 0;
  if (options_.fps > 0) {
    // Best effort: a driver without frame-interval control runs at its own
    // rate (ENOTTY / EINVAL); the pairing does not depend on it.
    v4l2_streamparm parm{};
    parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    parm.parm.capture.timeperframe.numerator = 1;
    parm.parm.capture.timeperframe.denominator = options_.fps;
    if (device_->ioctl(fd_, VIDIOC_S_PARM, &parm) == 0 && parm.parm.capture.timeperframe.numerator > 0)
      granted_fps_ = double(parm.parm.capture.timeperframe.denominator) / parm.parm.capture.timeperframe.numerator;
  }
  v4l2_requestbuffers req{};
  req.count = options_.buffers;
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (device_->ioctl(fd_, VIDIOC_REQBUFS, &req) < 0) return fail("VIDIOC_REQBUFS");
  if (req.count < 2) {
    errno = ENOMEM;
    return fail("driver granted " + std::to_string(req.count) + " buffer(s), need 2");
  }
  for (std::uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (device_->ioctl(fd_, VIDIOC_QUERYBUF, &buf) < 0) return fail("VIDIOC_QUERYBUF");
    void* start = device_->mmap(buf.length, fd_, buf.m.offset);
    if (start == MAP_FAILED) return fail("mmap");
    buffers_.push_back({start, buf.length});
    if (device_->ioctl(fd_, VIDIOC_QBUF, &buf) < 0) return fail("VIDIOC_QBUF");
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (device_->ioctl(fd_, VIDIOC_STREAMON, &type) < 0) return fail("VIDIOC_STREAMON");
  streaming_ = true;
  return {};
}

V4l2Event V4l2Capture::next(V4l2Frame& frame, std::chrono::milliseconds timeout, std::string* message) {
  if (fd_ < 0) {
    *message = "not open";
    return V4l2Event::kError;
  }
  const int ready = device_->poll(fd_, static_cast<int>(timeout.count()));
  if (ready == 0) return V4l2Event::kTimeout;
  if (ready < 0) {
    *message = "device " + options_.device + " gone (poll)";
    return V4l2Event::kGone;
  }
  v4l2_buffer buf{};
  buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buf.memory = V4L2_MEMORY_MMAP;
  if (device_->ioctl(fd_, VIDIOC_DQBUF, &buf) < 0) {
    if (errno == EAGAIN) return V4l2Event::kTimeout;
    *message = std::string("VIDIOC_DQBUF: ") + std::strerror(errno);
    return errno == ENODEV || errno == EIO ? V4l2Event::kGone : V4l2Event::kError;
  }
  V4l2Event event = V4l2Event::kFrame;
  const std::size_t needed = std::size_t(bytes_per_line_) * options_.height;
  if (buf.index >= buffers_.size() || buf.bytesused < needed || (buf.flags & V4L2_BUF_FLAG_ERROR)) {
    *message = "corrupt frame (index " + std::to_string(buf.index) + ", " + std::to_string(buf.bytesused) +
               " bytes, need " + std::to_string(needed) + ")";
    event = V4l2Event::kError;
  } else {
    auto* base = static_cast<std::uint8_t*>(buffers_[buf.index].start);
    if (options_.format == V4l2Format::kZ16) {
      // Copied out: the buffer goes back to the driver below.
      cv::Mat(options_.height, options_.width, CV_16UC1, base, bytes_per_line_).copyTo(frame.depth);
      frame.gray.release();
      frame.bgr.release();
    } else {
      // YUYV: every other byte is luma.
      frame.gray.create(options_.height, options_.width, CV_8UC1);
      for (int y = 0; y < options_.height; ++y) {
        const std::uint8_t* row = base + std::size_t(y) * bytes_per_line_;
        std::uint8_t* out = frame.gray.ptr<std::uint8_t>(y);
        for (int x = 0; x < options_.width; ++x) out[x] = row[2 * x];
      }
      if (options_.colour)
        cv::cvtColor(cv::Mat(options_.height, options_.width, CV_8UC2, base, bytes_per_line_), frame.bgr,
                     cv::COLOR_YUV2BGR_YUYV);
      else
        frame.bgr.release();
      frame.depth.release();
    }
    frame.stamp = Timestamp::fromNanoseconds(std::int64_t(buf.timestamp.tv_sec) * 1'000'000'000 +
                                             std::int64_t(buf.timestamp.tv_usec) * 1000);
    frame.sequence = buf.sequence;
  }
  // Hand the buffer back to the driver whatever happened to its content.
  if (buf.index < buffers_.size() && device_->ioctl(fd_, VIDIOC_QBUF, &buf) < 0) {
    *message = std::string("VIDIOC_QBUF: ") + std::strerror(errno);
    return errno == ENODEV ? V4l2Event::kGone : V4l2Event::kError;
  }
  return event;
}

void V4l2Capture::close() {
  if (fd_ >= 0 && streaming_) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    device_->ioctl(fd_, VIDIOC_STREAMOFF, &type);
  }
  streaming_ = false;
  for (const Buffer& b : buffers_) device_->munmap(b.start, b.length);
  buffers_.clear();
  if (fd_ >= 0) device_->close(fd_);
  fd_ = -1;
}

}  // namespace stillpoint::platform
