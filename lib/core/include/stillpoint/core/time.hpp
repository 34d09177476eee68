#pragma once
// Timestamps are integer nanoseconds behind a strong type, so seconds and
// nanoseconds can never be mixed up silently.
#include <compare>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace stillpoint {

class Timestamp {
 public:
  constexpr Timestamp() = default;
  static constexpr Timestamp fromNanoseconds(std::int64_t ns) { return Timestamp(ns); }
  static Timestamp fromSeconds(double s);
  // Stamps are at most this many seconds from the epoch either way (year
  // 2255): in nanoseconds they stay far inside int64.
  static constexpr double kMaxSeconds = 9e9;
  // Parses a decimal seconds string ("1341841873.273798") without going through
  // double, so TUM timestamps survive exactly. Returns nullopt when malformed
  // or beyond kMaxSeconds.
  static std::optional<Timestamp> parseSeconds(std::string_view text);

  constexpr std::int64_t nanoseconds() const { return ns_; }
  double seconds() const { return static_cast<double>(ns_) * 1e-9; }
  // Decimal seconds with 6 fractional digits, as the TUM tools write them.
  std::string toSecondsString() const;

  constexpr auto operator<=>(const Timestamp&) const = default;

 private:
  constexpr explicit Timestamp(std::int64_t ns) : ns_(ns) {}
  std::int64_t ns_ = 0;
};

// Signed difference a - b in seconds.
inline double secondsBetween(Timestamp a, Timestamp b) {
  return static_cast<double>(a.nanoseconds() - b.nanoseconds()) * 1e-9;
}

}  // namespace stillpoint
