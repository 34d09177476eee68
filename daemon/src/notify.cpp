#include "notify.hpp"

#include <systemd/sd-daemon.h>

#include <cstdint>

namespace stillpoint::daemon {

SystemdNotifier::SystemdNotifier() {
  std::uint64_t usec = 0;
  if (sd_watchdog_enabled(0, &usec) > 0) watchdog_ = std::chrono::microseconds(usec);
}

void SystemdNotifier::send(const std::string& text) { sd_notify(0, text.c_str()); }
void SystemdNotifier::ready() { send("READY=1"); }
void SystemdNotifier::watchdog() { send("WATCHDOG=1"); }
void SystemdNotifier::status(const std::string& text) { send("STATUS=" + text); }
void SystemdNotifier::stopping() { send("STOPPING=1"); }

}  // namespace stillpoint::daemon
