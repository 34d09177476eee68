#include "stillpoint/ipc/transport.hpp"

#include "stillpoint/core/log.hpp"

namespace stillpoint::ipc {
namespace {
const log::Logger kLog("ipc");

class RetryingTransport final : public Transport {
 public:
  RetryingTransport(std::string name, std::function<Result<std::unique_ptr<Transport>>()> make,
                    std::chrono::steady_clock::duration period)
      : name_(std::move(name)), make_(std::move(make)), period_(period) {
    attempt(true);
  }
  std::string_view name() const override { return inner_ ? inner_->name() : std::string_view(name_); }
  Status publishPose(const PoseMessage& pose) override {
    if (!inner_) return Error{name_ + " is down: " + error_};
    return inner_->publishPose(pose);
  }
  Status publishStatus(const StatusMessage& status) override {
    if (!inner_) return Error{name_ + " is down: " + error_};
    return inner_->publishStatus(status);
  }
  Status publishObjects(const ObjectsMessage& objects) override {
    if (!inner_) return Error{name_ + " is down: " + error_};
    return inner_->publishObjects(objects);
  }
  Status publishMapCloud(const MapCloudMessage& cloud) override {
    if (!inner_) return Error{name_ + " is down: " + error_};
    return inner_->publishMapCloud(cloud);
  }
  int matchedReaders() const override { return inner_ ? inner_->matchedReaders() : 0; }
  bool up() const override { return inner_ != nullptr; }
  void retry() override {
    if (!inner_ && std::chrono::steady_clock::now() >= next_try_) attempt(false);
  }

 private:
  void attempt(bool first) {
    next_try_ = std::chrono::steady_clock::now() + period_;
    auto made = make_();
    if (made) {
      inner_ = std::move(made.value());
      if (!first) SP_INFO(kLog, name_ << ": up");
      return;
    }
    if (first)
      SP_WARN(kLog, made.error() << "; publishing without " << name_ << " and retrying every "
                                 << std::chrono::duration<double>(period_).count() << " s");
    error_ = made.error();
  }

  std::string name_;
  std::function<Result<std::unique_ptr<Transport>>()> make_;
  std::chrono::steady_clock::duration period_;
  std::unique_ptr<Transport> inner_;
  std::string error_;
  std::chrono::steady_clock::time_point next_try_;
};
}  // namespace

std::unique_ptr<Transport> makeRetryingTransport(std::string name,
                                                 std::function<Result<std::unique_ptr<Transport>>()> make,
                                                 std::chrono::steady_clock::duration period) {
  return std::make_unique<RetryingTransport>(std::move(name), std::move(make), period);
}

Result<std::vector<std::unique_ptr<Transport>>> makeTransports(const IpcOptions& options) {
  std::vector<std::unique_ptr<Transport>> out;
  if (options.shm.enabled) {
    auto t = makeShmTransport(options.shm);
    if (!t) return Error{t.error()};
    out.push_back(std::move(t.value()));
  }
  if (options.lcm.enabled) {
    auto t = makeLcmTransport(options.lcm);
    if (!t) return Error{t.error()};
    out.push_back(std::move(t.value()));
  }
  if (options.dds.enabled) {
    auto t = makeDdsTransport(options.dds);
    if (!t) return Error{t.error()};
    out.push_back(std::move(t.value()));
  }
  if (options.ros2.enabled) {
    auto t = makeRos2Transport(options.ros2);
    if (!t) return Error{t.error()};
    out.push_back(std::move(t.value()));
  }
  return out;
}

}  // namespace stillpoint::ipc
