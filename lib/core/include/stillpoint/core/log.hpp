#pragma once
// One logging facade for the whole project: a named logger per module, a
// global level, and a rate limit for hot loops. Output goes to stderr.
#include <atomic>
#include <chrono>
#include <sstream>
#include <string>

namespace stillpoint::log {

enum class Level { kDebug = 0, kInfo = 1, kWarn = 2, kError = 3, kOff = 4 };

void setLevel(Level level);
Level level();
// Parses "debug", "info", "warn", "error", "off"; returns false when unknown.
bool parseLevel(const std::string& text, Level* out);

class Logger {
 public:
  explicit Logger(std::string name) : name_(std::move(name)) {}
  bool enabled(Level l) const { return l >= level(); }
  void write(Level l, const std::string& message) const;
  const std::string& name() const { return name_; }

 private:
  std::string name_;
};

// Lets at most one message through per period; cheap to check.
class RateLimiter {
 public:
  explicit RateLimiter(std::chrono::milliseconds period) : period_ns_(period.count() * 1'000'000) {}
  bool allow();

 private:
  std::int64_t period_ns_;
  std::atomic<std::int64_t> next_ns_{0};
};

}  // namespace stillpoint::log

#define SP_LOG(logger, lvl, expr)                                   \
  do {                                                              \
    if ((logger).enabled(lvl)) {                                    \
      std::ostringstream sp_log_os_;                                \
      sp_log_os_ << expr;                                           \
      (logger).write(lvl, sp_log_os_.str());                        \
    }                                                               \
  } while (0)
#define SP_DEBUG(logger, expr) SP_LOG(logger, ::stillpoint::log::Level::kDebug, expr)
#define SP_INFO(logger, expr) SP_LOG(logger, ::stillpoint::log::Level::kInfo, expr)
#define SP_WARN(logger, expr) SP_LOG(logger, ::stillpoint::log::Level::kWarn, expr)
#define SP_ERROR(logger, expr) SP_LOG(logger, ::stillpoint::log::Level::kError, expr)
#define SP_WARN_EVERY(logger, limiter, expr) \
  do {                                       \
    if ((limiter).allow()) SP_WARN(logger, expr); \
  } while (0)
