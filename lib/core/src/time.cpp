#include "stillpoint/core/time.hpp"

#include <cctype>
#include <cmath>
#include <cstdio>

namespace stillpoint {

Timestamp Timestamp::fromSeconds(double s) {
  return Timestamp(static_cast<std::int64_t>(std::llround(s * 1e9)));
}

std::optional<Timestamp> Timestamp::parseSeconds(std::string_view text) {
  if (text.empty()) return std::nullopt;
  bool negative = false;
  std::size_t i = 0;
  if (text[0] == '-' || text[0] == '+') {
    negative = text[0] == '-';
    i = 1;
  }
  std::int64_t whole = 0;
  std::int64_t frac = 0;
  int frac_digits = 0;
  bool any_digit = false;
  bool seen_dot = false;
  for (; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '.') {
      if (seen_dot) return std::nullopt;
      seen_dot = true;
      continue;
    }
    if (!std::isdigit(static_cast<unsigned char>(c))) return std::nullopt;
    any_digit = true;
    if (!seen_dot) {
      whole = whole * 10 + (c - '0');  // at most 10 x kMaxSeconds + 9 before the check: no overflow
      if (whole > static_cast<std::int64_t>(kMaxSeconds)) return std::nullopt;
    } else if (frac_digits < 9) {
      frac = frac * 10 + (c - '0');
      ++frac_digits;
    }
  }
  if (!any_digit) return std::nullopt;
  for (int d = frac_digits; d < 9; ++d) frac *= 10;
  const std::int64_t ns = whole * 1'000'000'000LL + frac;
  return Timestamp(negative ? -ns : ns);
}

std::string Timestamp::toSecondsString() const {
  // The magnitude unsigned: every int64 has one (INT64_MIN's too), and
  // rounding to microseconds cannot overflow it.
  const std::uint64_t abs_ns = ns_ < 0 ? 0 - static_cast<std::uint64_t>(ns_) : static_cast<std::uint64_t>(ns_);
  const std::uint64_t us = abs_ns / 1000 + (abs_ns % 1000 >= 500 ? 1 : 0);
  char buf[48];
  std::snprintf(buf, sizeof(buf), "%s%llu.%06llu", ns_ < 0 ? "-" : "",
                static_cast<unsigned long long>(us / 1'000'000), static_cast<unsigned long long>(us % 1'000'000));
  return buf;
}

}  // namespace stillpoint
