#pragma once
// The checksum of the project's binary files (maps, vocabularies): 64-bit
// FNV-1a. It finds truncation and flipped bytes, not tampering.
#include <cstddef>
#include <cstdint>

namespace stillpoint {

inline std::uint64_t fnv1a64(const char* data, std::size_t n) {
  std::uint64_t h = 1469598103934665603ull;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace stillpoint
