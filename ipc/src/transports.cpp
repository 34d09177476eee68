#include "stillpoint/ipc/transport.hpp"

namespace stillpoint::ipc {

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
