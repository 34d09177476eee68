#pragma once
// 256-bit binary descriptors (ORB) and their Hamming distance.
#include <bit>
#include <cstdint>
#include <cstring>

namespace stillpoint::features {

constexpr int kDescriptorBytes = 32;

inline int hammingDistance(const std::uint8_t* a, const std::uint8_t* b) {
  int d = 0;
  for (int i = 0; i < kDescriptorBytes; i += 8) {
    std::uint64_t x, y;
    std::memcpy(&x, a + i, 8);
    std::memcpy(&y, b + i, 8);
    d += std::popcount(x ^ y);
  }
  return d;
}

// Index of the descriptor with the least summed distance to all others (the
// "median" descriptor of a set of observations); -1 for an empty set.
int medianDescriptorIndex(const std::uint8_t* const* descriptors, int count);

}  // namespace stillpoint::features
