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

// Hamming distances from `query` to `count` descriptors stored back to back
// at `descriptors` (kDescriptorBytes each): out[k] for the k-th, the same as
// hammingDistance's. On x86-64 with AVX-512 VPOPCNTDQ (checked once at run
// time) eight descriptors at a time; on AArch64 one at a time in Advanced
// SIMD registers; elsewhere hammingDistance in a loop.
void hammingDistances(const std::uint8_t* query, const std::uint8_t* descriptors, int count, int* out);
// The same without the vector path (tests compare the two).
void hammingDistancesScalar(const std::uint8_t* query, const std::uint8_t* descriptors, int count, int* out);
// Which path hammingDistances takes on this CPU: "avx512", "neon" or "scalar".
const char* hammingDistancesPath();

// Index of the descriptor with the least summed distance to all others (the
// "median" descriptor of a set of observations); -1 for an empty set.
int medianDescriptorIndex(const std::uint8_t* const* descriptors, int count);

}  // namespace stillpoint::features
