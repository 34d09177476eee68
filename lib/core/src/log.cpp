#include "stillpoint/core/log.hpp"

#include <cstdio>
#include <mutex>

namespace stillpoint::log {
namespace {
std::atomic<int> g_level{static_cast<int>(Level::kInfo)};
std::mutex g_write_mutex;
const char* levelName(Level l) {
  switch (l) {
    case Level::kDebug: return "debug";
    case Level::kInfo: return "info";
    case Level::kWarn: return "warn";
    case Level::kError: return "error";
    case Level::kOff: return "off";
  }
  return "?";
}
}  // namespace

void setLevel(Level l) { g_level.store(static_cast<int>(l)); }
Level level() { return static_cast<Level>(g_level.load(std::memory_order_relaxed)); }

bool parseLevel(const std::string& text, Level* out) {
  for (Level l : {Level::kDebug, Level::kInfo, Level::kWarn, Level::kError, Level::kOff}) {
    if (text == levelName(l)) {
      *out = l;
      return true;
    }
  }
  return false;
}

void Logger::write(Level l, const std::string& message) const {
  std::lock_guard lock(g_write_mutex);
  std::fprintf(stderr, "[%s] [%s] %s\n", levelName(l), name_.c_str(), message.c_str());
}

bool RateLimiter::allow() {
  const std::int64_t now = std::chrono::duration_cast<std::chrono::nanoseconds>(
                               std::chrono::steady_clock::now().time_since_epoch())
                               .count();
  std::int64_t next = next_ns_.load(std::memory_order_relaxed);
  if (now < next) return false;
  return next_ns_.compare_exchange_strong(next, now + period_ns_);
}

}  // namespace stillpoint::log
