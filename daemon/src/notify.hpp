#pragma once
// systemd's notification protocol through libsystemd (sd_notify). Without
// NOTIFY_SOCKET (not started by systemd) every call does nothing.
#include <chrono>
#include <string>

namespace stillpoint::daemon {

class SystemdNotifier {
 public:
  SystemdNotifier();
  // WatchdogSec= of the unit (WATCHDOG_USEC), or zero when there is no watchdog.
  std::chrono::microseconds watchdogInterval() const { return watchdog_; }
  void ready();
  void watchdog();
  void status(const std::string& text);
  void stopping();

 private:
  void send(const std::string& text);
  std::chrono::microseconds watchdog_{0};
};

}  // namespace stillpoint::daemon
