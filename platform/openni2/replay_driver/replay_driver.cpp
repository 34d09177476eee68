// An OpenNI2 driver plugin that serves a recorded TUM RGB-D sequence as a
// camera, for tests of the OpenNI2 source without hardware. Built from the
// driver API in libopenni2-dev (OniDriverAPI.h). OpenNI2 loads it from
// OpenNI2/Drivers beside libOpenNI2.so.0 (the test copies the library into a
// temporary folder with its own Drivers folder).
//
// Environment:
//   STILLPOINT_ONI_REPLAY_DIR   the TUM-layout folder (required for a device to appear)
//   STILLPOINT_ONI_GONE_AFTER   optional: after this many frames the device disconnects
//                               (unplug); it reconnects ~1 s later, serving from the start
//   STILLPOINT_ONI_PAIRS        optional: serve only this many pairs, counted from the first
//                               one that finds every open stream started; then the device
//                               stays connected and sends nothing more (a recording of
//                               exactly that many pairs)
// The device URI is "stillpoint-replay://<folder>". Colour is RGB888 and depth
// 1 mm 640x480 at 30 fps; both frames of a pair carry the colour image's TUM
// stamp in microseconds, so they are synchronised by construction.
#include <Driver/OniDriverAPI.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <new>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "stillpoint/dataset/tum_dataset.hpp"

// ONI_EXPORT_DRIVER allocates through these (the driver API leaves them to us).
#define XN_NEW(type, arg) new (std::nothrow) type(arg)
#define XN_DELETE(p) delete (p)

namespace {

using namespace oni::driver;
constexpr int kWidth = 640, kHeight = 480, kFps = 30;
constexpr const char* kScheme = "stillpoint-replay://";

class ReplayStream final : public StreamBase {
 public:
  explicit ReplayStream(OniSensorType type) : type_(type) {}
  OniStatus start() override {
    running_ = true;
    return ONI_STATUS_OK;
  }
  void stop() override { running_ = false; }
  bool running() const { return running_; }
  OniSensorType type() const { return type_; }

  OniVideoMode mode() const {
    OniVideoMode m{};
    m.pixelFormat = type_ == ONI_SENSOR_COLOR ? ONI_PIXEL_FORMAT_RGB888 : ONI_PIXEL_FORMAT_DEPTH_1_MM;
    m.resolutionX = kWidth;
    m.resolutionY = kHeight;
    m.fps = kFps;
    return m;
  }

  OniBool isPropertySupported(int id) override {
    return id == ONI_STREAM_PROPERTY_VIDEO_MODE || id == ONI_STREAM_PROPERTY_CROPPING ||
           id == ONI_STREAM_PROPERTY_MIRRORING || id == ONI_STREAM_PROPERTY_MAX_VALUE ||
           id == ONI_STREAM_PROPERTY_HORIZONTAL_FOV || id == ONI_STREAM_PROPERTY_VERTICAL_FOV;
  }
  OniStatus getProperty(int id, void* data, int* size) override {
    switch (id) {
      case ONI_STREAM_PROPERTY_VIDEO_MODE: return put(mode(), data, size);
      case ONI_STREAM_PROPERTY_CROPPING: {
        OniCropping c{};  // never cropped: playback tools need the property to exist
        return put(c, data, size);
      }
      case ONI_STREAM_PROPERTY_MIRRORING: return put(OniBool(mirroring_), data, size);
      case ONI_STREAM_PROPERTY_MAX_VALUE: return put(int(10000), data, size);
      case ONI_STREAM_PROPERTY_HORIZONTAL_FOV: return put(float(1.0226), data, size);  // fr3: fx 535.4
      case ONI_STREAM_PROPERTY_VERTICAL_FOV: return put(float(0.7943), data, size);
      default: return ONI_STATUS_NOT_SUPPORTED;
    }
  }
  OniStatus setProperty(int id, const void* data, int size) override {
    if (id == ONI_STREAM_PROPERTY_VIDEO_MODE) {
      if (size != sizeof(OniVideoMode)) return ONI_STATUS_BAD_PARAMETER;
      const OniVideoMode* m = static_cast<const OniVideoMode*>(data);
      const OniVideoMode ours = mode();
      // Only the mode we serve.
      return m->resolutionX == ours.resolutionX && m->resolutionY == ours.resolutionY && m->fps == ours.fps &&
                     m->pixelFormat == ours.pixelFormat
                 ? ONI_STATUS_OK
                 : ONI_STATUS_NOT_SUPPORTED;
    }
    if (id == ONI_STREAM_PROPERTY_MIRRORING && size == sizeof(OniBool)) {
      mirroring_ = *static_cast<const OniBool*>(data);
      return ONI_STATUS_OK;
    }
    if (id == ONI_STREAM_PROPERTY_CROPPING && size == sizeof(OniCropping))
      return static_cast<const OniCropping*>(data)->enabled ? ONI_STATUS_NOT_SUPPORTED : ONI_STATUS_OK;
    return ONI_STATUS_NOT_SUPPORTED;
  }

  // Called by the device thread.
  void deliver(const cv::Mat& image, std::uint64_t stamp_us, int index) {
    if (!running_) return;
    OniFrame* frame = getServices().acquireFrame();
    if (!frame) return;
    const int bpp = type_ == ONI_SENSOR_COLOR ? 3 : 2;
    frame->dataSize = kWidth * kHeight * bpp;
    std::memcpy(frame->data, image.data, frame->dataSize);
    frame->sensorType = type_;
    frame->timestamp = stamp_us;
    frame->frameIndex = index;
    frame->width = kWidth;
    frame->height = kHeight;
    frame->videoMode = mode();
    frame->croppingEnabled = FALSE;
    frame->cropOriginX = frame->cropOriginY = 0;
    frame->stride = kWidth * bpp;
    raiseNewFrame(frame);
    getServices().releaseFrame(frame);
  }

 private:
  template <typename T>
  static OniStatus put(const T& value, void* data, int* size) {
    if (*size < int(sizeof(T))) return ONI_STATUS_BAD_PARAMETER;
    std::memcpy(data, &value, sizeof(T));
    *size = sizeof(T);
    return ONI_STATUS_OK;
  }
  const OniSensorType type_;
  std::atomic<bool> running_{false};
  bool mirroring_ = false;
};

class ReplayDriver;

class ReplayDevice final : public DeviceBase {
 public:
  ReplayDevice(ReplayDriver* driver, stillpoint::dataset::TumDataset data, long gone_after, long pairs)
      : driver_(driver), data_(std::move(data)), gone_after_(gone_after), pairs_(pairs) {
    for (int i = 0; i < 2; ++i) {
      modes_[i] = ReplayStream(i == 0 ? ONI_SENSOR_COLOR : ONI_SENSOR_DEPTH).mode();
      sensors_[i].sensorType = i == 0 ? ONI_SENSOR_COLOR : ONI_SENSOR_DEPTH;
      sensors_[i].numSupportedVideoModes = 1;
      sensors_[i].pSupportedVideoModes = &modes_[i];
    }
    thread_ = std::thread([this] { run(); });
  }
  ~ReplayDevice() override {
    stop_ = true;
    thread_.join();
  }
  OniStatus getSensorInfoList(OniSensorInfo** infos, int* n) override {
    *infos = sensors_;
    *n = 2;
    return ONI_STATUS_OK;
  }
  StreamBase* createStream(OniSensorType type) override {
    if (type != ONI_SENSOR_COLOR && type != ONI_SENSOR_DEPTH) return nullptr;
    std::lock_guard lock(mutex_);
    auto* s = new (std::nothrow) ReplayStream(type);
    if (s) streams_.push_back(s);
    return s;
  }
  void destroyStream(StreamBase* stream) override {
    std::lock_guard lock(mutex_);
    for (auto it = streams_.begin(); it != streams_.end(); ++it)
      if (*it == stream) {
        streams_.erase(it);
        break;
      }
    delete stream;
  }
  OniBool isImageRegistrationModeSupported(OniImageRegistrationMode) override { return TRUE; }
  OniBool isPropertySupported(int id) override {
    return id == ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION;
  }
  OniStatus setProperty(int id, const void*, int) override {
    // Depth is registered to colour and the pair is synchronised by construction.
    return isPropertySupported(id) ? ONI_STATUS_OK : ONI_STATUS_NOT_SUPPORTED;
  }
  OniStatus getProperty(int id, void* data, int* size) override {
    if (id == ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION && *size >= int(sizeof(int))) {
      *static_cast<int*>(data) = ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR;
      *size = sizeof(int);
      return ONI_STATUS_OK;
    }
    return ONI_STATUS_NOT_SUPPORTED;
  }

 private:
  void run();
  bool allStarted() {
    std::lock_guard lock(mutex_);
    return !streams_.empty() &&
           std::all_of(streams_.begin(), streams_.end(), [](const ReplayStream* s) { return s->running(); });
  }
  ReplayDriver* driver_;
  stillpoint::dataset::TumDataset data_;
  long gone_after_;
  long pairs_;
  OniVideoMode modes_[2];
  OniSensorInfo sensors_[2];
  std::mutex mutex_;
  std::vector<ReplayStream*> streams_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

class ReplayDriver final : public DriverBase {
 public:
  explicit ReplayDriver(OniDriverServices* services) : DriverBase(services) {}

  OniStatus initialize(DeviceConnectedCallback connected, DeviceDisconnectedCallback disconnected,
                       DeviceStateChangedCallback changed, void* cookie) override {
    DriverBase::initialize(connected, disconnected, changed, cookie);
    const char* dir = std::getenv("STILLPOINT_ONI_REPLAY_DIR");
    if (!dir || !*dir) return ONI_STATUS_OK;  // no sequence: no device
    dir_ = dir;
    if (const char* g = std::getenv("STILLPOINT_ONI_GONE_AFTER")) gone_after_ = std::atol(g);
    if (const char* p = std::getenv("STILLPOINT_ONI_PAIRS")) pairs_ = std::atol(p);
    std::memset(&info_, 0, sizeof info_);
    std::snprintf(info_.uri, sizeof info_.uri, "%s%s", kScheme, dir_.c_str());
    std::snprintf(info_.vendor, sizeof info_.vendor, "stillpoint");
    std::snprintf(info_.name, sizeof info_.name, "TUM replay");
    deviceConnected(&info_);
    return ONI_STATUS_OK;
  }
  DeviceBase* deviceOpen(const char* uri, const char*) override {
    if (dir_.empty() || std::strcmp(uri, info_.uri) != 0 || !present_) return nullptr;
    stillpoint::dataset::DatasetOptions o;
    o.expected_width = kWidth;
    o.expected_height = kHeight;
    o.depth_factor = 5000.0;
    auto data = stillpoint::dataset::TumDataset::open(dir_, o);
    if (!data) {
      getServices().errorLoggerAppend("stillpoint replay: %s", data.error().c_str());
      return nullptr;
    }
    return new (std::nothrow) ReplayDevice(this, std::move(*data), gone_after_, pairs_);
  }
  void deviceClose(DeviceBase* device) override { delete device; }
  OniStatus tryDevice(const char* uri) override {
    return !dir_.empty() && present_ && std::strcmp(uri, info_.uri) == 0 ? ONI_STATUS_OK : ONI_STATUS_ERROR;
  }
  void shutdown() override {
    if (replug_.joinable()) replug_.join();
  }
  // The device thread pulls the plug: gone now, back about a second later.
  void unplug() {
    present_ = false;
    deviceDisconnected(&info_);
    if (replug_.joinable()) replug_.join();
    replug_ = std::thread([this] {
      std::this_thread::sleep_for(std::chrono::seconds(1));
      present_ = true;
      deviceConnected(&info_);
    });
  }

 private:
  std::string dir_;
  long gone_after_ = 0;
  long pairs_ = 0;
  OniDeviceInfo info_{};
  std::atomic<bool> present_{true};
  std::thread replug_;
};

void ReplayDevice::run() {
  const auto start = std::chrono::steady_clock::now();
  std::int64_t first_ns = -1;
  long served = 0;
  for (std::size_t i = 0; i < data_.size() && !stop_ && (pairs_ <= 0 || served < pairs_); ++i) {
    auto frame = data_.load(i);
    if (!frame) continue;
    if (first_ns < 0) first_ns = frame->stamp.nanoseconds();
    std::this_thread::sleep_until(start + std::chrono::nanoseconds(frame->stamp.nanoseconds() - first_ns));
    if (stop_) break;
    if (pairs_ > 0 && !allStarted()) continue;  // the counted pairs begin once every stream runs
    cv::Mat rgb(kHeight, kWidth, CV_8UC3), depth_mm;
    for (int y = 0; y < kHeight; ++y)
      for (int x = 0; x < kWidth; ++x) {
        const cv::Vec3b bgr = frame->bgr.at<cv::Vec3b>(y, x);
        rgb.at<cv::Vec3b>(y, x) = {bgr[2], bgr[1], bgr[0]};
      }
    frame->depth_m.convertTo(depth_mm, CV_16UC1, 1000.0);
    const std::uint64_t stamp_us = static_cast<std::uint64_t>(frame->stamp.nanoseconds() / 1000);
    {
      std::lock_guard lock(mutex_);
      for (ReplayStream* s : streams_)
        s->deliver(s->type() == ONI_SENSOR_COLOR ? rgb : depth_mm, stamp_us, static_cast<int>(i + 1));
      ++served;
    }
    if (gone_after_ > 0 && static_cast<long>(i + 1) == gone_after_) {
      driver_->unplug();
      return;  // an unplugged device sends nothing more
    }
  }
}

}  // namespace

ONI_EXPORT_DRIVER(ReplayDriver)
