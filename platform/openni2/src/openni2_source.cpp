#include "stillpoint/platform/openni2_source.hpp"

#include <OpenNI.h>

#include <atomic>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace stillpoint::platform {
namespace {

// OpenNI2 is process-global: initialise once, never shut down while a source may reopen.
Status initialiseOpenNI() {
  static std::once_flag once;
  static openni::Status status = openni::STATUS_OK;
  std::call_once(once, [] { status = openni::OpenNI::initialize(); });
  if (status != openni::STATUS_OK)
    return Error{std::string("openni2: initialize failed: ") + openni::OpenNI::getExtendedError()};
  return {};
}

std::string lastError(const std::string& what) {
  return "openni2: " + what + ": " + openni::OpenNI::getExtendedError();
}

}  // namespace

struct OpenNI2Source::Impl : public openni::OpenNI::DeviceDisconnectedListener {
  openni::Device device;
  openni::VideoStream colour, depth;
  std::string uri;
  std::atomic<bool> gone{false};
  std::uint64_t delivered = 0;
  // A .oni recording: played once (no repeat), ends when every recorded frame was read.
  bool file = false;
  int file_colour_frames = 0, file_depth_frames = 0;
  int colour_read = 0, depth_read = 0;
  std::chrono::steady_clock::time_point last_read;
  // Pacing of a recording: the first pair's stamp and when it was delivered.
  bool paced = false;
  std::int64_t first_stamp_us = 0;
  std::chrono::steady_clock::time_point first_delivered;
  // Latest frame of each stream, paired by timestamp.
  openni::VideoFrameRef last_colour, last_depth;

  // Holds a recording's pair until its stamp is due at the recorded rate,
  // counted from the first pair. A gap longer than a second is not waited for
  // (as in ReplaySource); a consumer behind the recording is not made to wait.
  void pace(std::uint64_t stamp_us) {
    const auto now = std::chrono::steady_clock::now();
    const std::int64_t offset_us = static_cast<std::int64_t>(stamp_us) - first_stamp_us;
    if (!paced || offset_us < 0 || now + std::chrono::seconds(1) < first_delivered + std::chrono::microseconds(offset_us)) {
      paced = true;
      first_stamp_us = static_cast<std::int64_t>(stamp_us);
      first_delivered = now;
      return;
    }
    std::this_thread::sleep_until(first_delivered + std::chrono::microseconds(offset_us));
  }

  void onDeviceDisconnected(const openni::DeviceInfo* info) override {
    if (uri == info->getUri()) gone = true;
  }
};

OpenNI2Source::OpenNI2Source(OpenNI2SourceOptions options, CameraModel camera)
    : options_(std::move(options)), camera_(std::move(camera)) {}

OpenNI2Source::~OpenNI2Source() { close(); }

std::string OpenNI2Source::describe() const {
  return "openni2 " + (options_.uri.empty() ? std::string("(first device)") : options_.uri);
}

Status OpenNI2Source::open() {
  close();
  if (Status s = initialiseOpenNI(); !s) return s;
  auto impl = std::make_unique<Impl>();
  const char* uri = options_.uri.empty() ? openni::ANY_DEVICE : options_.uri.c_str();
  if (impl->device.open(uri) != openni::STATUS_OK) return Error{lastError("cannot open device '" + options_.uri + "'")};
  impl->uri = impl->device.getDeviceInfo().getUri();
  impl->file = impl->device.isFile();
  openni::OpenNI::addDeviceDisconnectedListener(impl.get());
  auto setUp = [&](openni::VideoStream& stream, openni::SensorType type, openni::PixelFormat format,
                   const char* name) -> Status {
    if (stream.create(impl->device, type) != openni::STATUS_OK) return Error{lastError(std::string("no ") + name + " stream")};
    if (impl->file) {
      // A recording has the mode it was recorded with: check it, set nothing.
      const openni::VideoMode m = stream.getVideoMode();
      if (m.getResolutionX() != camera_.width || m.getResolutionY() != camera_.height || m.getPixelFormat() != format)
        return Error{"openni2: " + options_.uri + ": the " + name + " stream was recorded at " +
                     std::to_string(m.getResolutionX()) + "x" + std::to_string(m.getResolutionY()) +
                     " (pixel format " + std::to_string(int(m.getPixelFormat())) + "), expected " +
                     std::to_string(camera_.width) + "x" + std::to_string(camera_.height) +
                     (type == openni::SENSOR_COLOR ? " RGB888" : " depth 1 mm")};
      return {};
    }
    openni::VideoMode mode;
    mode.setResolution(camera_.width, camera_.height);
    mode.setFps(30);
    mode.setPixelFormat(format);
    if (stream.setVideoMode(mode) != openni::STATUS_OK)
      return Error{lastError(std::string(name) + " mode " + std::to_string(camera_.width) + "x" +
                             std::to_string(camera_.height) + "@30")};
    stream.setMirroringEnabled(false);
    return {};
  };
  Status s = setUp(impl->colour, openni::SENSOR_COLOR, openni::PIXEL_FORMAT_RGB888, "colour");
  if (s) s = setUp(impl->depth, openni::SENSOR_DEPTH, openni::PIXEL_FORMAT_DEPTH_1_MM, "depth");
  // A recording holds frames as they were registered when it was made (record with registration on).
  if (s && !impl->file && impl->device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) &&
      impl->device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) != openni::STATUS_OK)
    s = Error{lastError("depth-to-colour registration")};
  if (s && impl->file) {
    openni::PlaybackControl* playback = impl->device.getPlaybackControl();
    if (!playback) {
      s = Error{lastError("no playback control for " + options_.uri)};
    } else {
      playback->setRepeatEnabled(false);
      // Manual speed: the player makes a frame available only once the last
      // one was read, so none is lost when this process is slow (at the
      // recorded speed the player overwrites a frame not read within a frame
      // period: 1 of 20 frames under load). next() paces the pairs instead.
      impl->file_colour_frames = playback->getNumberOfFrames(impl->colour);
      impl->file_depth_frames = playback->getNumberOfFrames(impl->depth);
      if (playback->setSpeed(-1.0f) != openni::STATUS_OK)
        s = Error{lastError("manual playback speed for " + options_.uri)};
      else if (impl->file_colour_frames <= 0 || impl->file_depth_frames <= 0)
        s = Error{"openni2: " + options_.uri + ": recording holds " + std::to_string(impl->file_colour_frames) +
                  " colour and " + std::to_string(impl->file_depth_frames) + " depth frames"};
    }
  }
  // Frame sync is best effort: recordings and some drivers do not offer it;
  // frames are paired by timestamp below either way.
  if (s) impl->device.setDepthColorSyncEnabled(true);
  if (s && impl->colour.start() != openni::STATUS_OK) s = Error{lastError("start colour")};
  if (s && impl->depth.start() != openni::STATUS_OK) s = Error{lastError("start depth")};
  if (!s) {
    openni::OpenNI::removeDeviceDisconnectedListener(impl.get());
    return s;
  }
  impl->last_read = std::chrono::steady_clock::now();
  impl_ = std::move(impl);
  return {};
}

void OpenNI2Source::close() {
  if (!impl_) return;
  openni::OpenNI::removeDeviceDisconnectedListener(impl_.get());
  impl_->colour.stop();
  impl_->depth.stop();
  if (impl_->file) {
    // Debian's .oni player (OniFile, OpenNI2 2.2) walks its stream list in its
    // player thread without a lock while destroying a stream removes from it:
    // destroying the streams of a playing file crashed the daemon about once
    // in ten runs. Stopped streams are safe, so a played recording's device
    // and streams stay open (idle) until the process exits; OpenNI's own
    // shutdown stops the player thread before it frees the streams. One
    // device per opened recording, and the daemon opens a recording once.
    static std::mutex parked_mutex;
    static auto* parked = new std::vector<std::unique_ptr<Impl>>();  // never freed; reachable (not a leak to LSan)
    std::lock_guard lock(parked_mutex);
    parked->push_back(std::move(impl_));
    return;
  }
  impl_->colour.destroy();
  impl_->depth.destroy();
  impl_->device.close();
  impl_.reset();
}

SourceResult OpenNI2Source::next(CameraFrame& frame, std::chrono::milliseconds timeout) {
  if (!impl_) return {SourceEvent::kDeviceGone, "not open"};
  const auto until = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (impl_->gone) return {SourceEvent::kDeviceGone, "device " + impl_->uri + " disconnected"};
    if (impl_->file && impl_->colour_read >= impl_->file_colour_frames && impl_->depth_read >= impl_->file_depth_frames)
      return {SourceEvent::kEnd, ""};
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now());
    if (left.count() <= 0) return {SourceEvent::kTimeout, ""};
    openni::VideoStream* streams[] = {&impl_->colour, &impl_->depth};
    int ready = -1;
    const openni::Status st = openni::OpenNI::waitForAnyStream(streams, 2, &ready, static_cast<int>(left.count()));
    if (st == openni::STATUS_TIME_OUT) {
      // Frames the player dropped are never read: a recording silent for a
      // second has ended too (or plays nothing: streams without the cropping
      // property, e.g. recorded from a driver lacking it, yield no frames).
      if (impl_->file && std::chrono::steady_clock::now() - impl_->last_read > std::chrono::seconds(1))
        return {SourceEvent::kEnd, impl_->colour_read + impl_->depth_read == 0 ? "the recording yielded no frames" : ""};
      return {SourceEvent::kTimeout, ""};
    }
    if (st != openni::STATUS_OK || ready < 0) {
      if (impl_->gone) continue;
      return {SourceEvent::kDeviceGone, lastError("waitForAnyStream")};
    }
    openni::VideoFrameRef& slot = ready == 0 ? impl_->last_colour : impl_->last_depth;
    if (streams[ready]->readFrame(&slot) != openni::STATUS_OK) return {SourceEvent::kBadFrame, lastError("readFrame")};
    if (impl_->file) {
      ++(ready == 0 ? impl_->colour_read : impl_->depth_read);
      impl_->last_read = std::chrono::steady_clock::now();
    }
    openni::VideoFrameRef& c = impl_->last_colour;
    openni::VideoFrameRef& d = impl_->last_depth;
    if (!c.isValid() || !d.isValid()) continue;
    const std::int64_t dt_us = static_cast<std::int64_t>(c.getTimestamp()) - static_cast<std::int64_t>(d.getTimestamp());
    if (dt_us > 20000 || dt_us < -20000) continue;  // not a pair yet (sensor clocks in microseconds)
    if (c.getWidth() != camera_.width || c.getHeight() != camera_.height || d.getWidth() != camera_.width ||
        d.getHeight() != camera_.height) {
      c.release();
      d.release();
      return {SourceEvent::kBadFrame, "frame size differs from the camera's"};
    }
    if (impl_->file) impl_->pace(c.getTimestamp());
    // Arrived now: the conversions below are this process's time, not the source's.
    const auto arrival = std::chrono::steady_clock::now();
    const cv::Mat rgb(c.getHeight(), c.getWidth(), CV_8UC3, const_cast<void*>(c.getData()), c.getStrideInBytes());
    const cv::Mat mm(d.getHeight(), d.getWidth(), CV_16UC1, const_cast<void*>(d.getData()), d.getStrideInBytes());
    cv::cvtColor(rgb, frame.gray, cv::COLOR_RGB2GRAY);
    if (options_.colour) cv::cvtColor(rgb, frame.bgr, cv::COLOR_RGB2BGR);
    else frame.bgr.release();
    mm.convertTo(frame.depth_m, CV_32FC1, 0.001);
    frame.stamp = Timestamp::fromNanoseconds(static_cast<std::int64_t>(c.getTimestamp()) * 1000);
    frame.sequence = impl_->delivered++;
    frame.arrival = arrival;
    c.release();
    d.release();
    return {SourceEvent::kFrame, ""};
  }
}

}  // namespace stillpoint::platform
