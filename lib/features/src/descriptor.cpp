#include "stillpoint/features/descriptor.hpp"

#include <algorithm>
#include <limits>
#include <vector>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define STILLPOINT_HAVE_AVX512_POPCNT 1
#elif defined(__aarch64__)
#include <arm_neon.h>
#endif

namespace stillpoint::features {
namespace {

#ifdef STILLPOINT_HAVE_AVX512_POPCNT
// GCC 12's AVX-512 headers leave an undefined register uninitialised on
// purpose (_mm512_undefined_epi32) and then warn about it.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
// Two descriptors per 512-bit register; the popcounts of their 4 words each
// are summed pairwise (unpack) and then across the register's halves (two
// permutes), giving the 8 distances in order.
__attribute__((target("avx512f,avx512vpopcntdq"))) void hammingDistancesAvx512(const std::uint8_t* query,
                                                                              const std::uint8_t* descriptors,
                                                                              int count, int* out) {
  const __m512i q = _mm512_broadcast_i64x4(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(query)));
  const __m512i low = _mm512_setr_epi64(0, 4, 1, 5, 8, 12, 9, 13);
  const __m512i high = _mm512_setr_epi64(2, 6, 3, 7, 10, 14, 11, 15);
  int k = 0;
  for (; k + 8 <= count; k += 8) {
    const std::uint8_t* p = descriptors + static_cast<std::size_t>(k) * kDescriptorBytes;
    const __m512i a = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(p), q));
    const __m512i b = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(p + 64), q));
    const __m512i c = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(p + 128), q));
    const __m512i d = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(p + 192), q));
    // [a0+a1, b0+b1, a2+a3, b2+b3, a4+a5, ...]: halves of each descriptor.
    const __m512i ab = _mm512_add_epi64(_mm512_unpacklo_epi64(a, b), _mm512_unpackhi_epi64(a, b));
    const __m512i cd = _mm512_add_epi64(_mm512_unpacklo_epi64(c, d), _mm512_unpackhi_epi64(c, d));
    const __m512i sums = _mm512_add_epi64(_mm512_permutex2var_epi64(ab, low, cd), _mm512_permutex2var_epi64(ab, high, cd));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + k), _mm512_cvtepi64_epi32(sums));
  }
  hammingDistancesScalar(query, descriptors + static_cast<std::size_t>(k) * kDescriptorBytes, count - k, out + k);
}
#pragma GCC diagnostic pop

bool haveAvx512Popcount() {
  static const bool have = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vpopcntdq");
  return have;
}
#endif

#ifdef __aarch64__
// Advanced SIMD is part of every AArch64 CPU (the Jetsons included): each
// descriptor is two 16-byte registers, counted per byte (CNT) and summed
// across (at most 256, so widened to 16 bits before the last add).
void hammingDistancesNeon(const std::uint8_t* query, const std::uint8_t* descriptors, int count, int* out) {
  const uint8x16_t q0 = vld1q_u8(query), q1 = vld1q_u8(query + 16);
  for (int k = 0; k < count; ++k) {
    const std::uint8_t* d = descriptors + static_cast<std::size_t>(k) * kDescriptorBytes;
    const uint8x16_t bits = vaddq_u8(vcntq_u8(veorq_u8(vld1q_u8(d), q0)), vcntq_u8(veorq_u8(vld1q_u8(d + 16), q1)));
    out[k] = vaddvq_u16(vpaddlq_u8(bits));
  }
}
#endif

}  // namespace

void hammingDistancesScalar(const std::uint8_t* query, const std::uint8_t* descriptors, int count, int* out) {
  for (int k = 0; k < count; ++k)
    out[k] = hammingDistance(query, descriptors + static_cast<std::size_t>(k) * kDescriptorBytes);
}

const char* hammingDistancesPath() {
#if defined(STILLPOINT_HAVE_AVX512_POPCNT)
  if (haveAvx512Popcount()) return "avx512";
#elif defined(__aarch64__)
  return "neon";
#endif
  return "scalar";
}

void hammingDistances(const std::uint8_t* query, const std::uint8_t* descriptors, int count, int* out) {
#if defined(STILLPOINT_HAVE_AVX512_POPCNT)
  if (haveAvx512Popcount()) return hammingDistancesAvx512(query, descriptors, count, out);
#elif defined(__aarch64__)
  return hammingDistancesNeon(query, descriptors, count, out);
#endif
  hammingDistancesScalar(query, descriptors, count, out);
}

int medianDescriptorIndex(const std::uint8_t* const* descriptors, int count) {
  if (count <= 0) return -1;
  std::vector<int> dist(static_cast<std::size_t>(count) * count, 0);
  for (int i = 0; i < count; ++i)
    for (int j = i + 1; j < count; ++j)
      dist[i * count + j] = dist[j * count + i] = hammingDistance(descriptors[i], descriptors[j]);
  int best = 0;
  int best_median = std::numeric_limits<int>::max();
  std::vector<int> row(count);
  for (int i = 0; i < count; ++i) {
    std::copy(dist.begin() + i * count, dist.begin() + (i + 1) * count, row.begin());
    std::nth_element(row.begin(), row.begin() + (count - 1) / 2, row.end());
    const int median = row[(count - 1) / 2];
    if (median < best_median) {
      best_median = median;
      best = i;
    }
  }
  return best;
}

}  // namespace stillpoint::features
