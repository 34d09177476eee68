/* Test pattern for the shared-memory stress test, C and C++: every word of record n
 * of writer generation g is a different function of (g, n), so a record stitched from
 * two writes never passes sp_test_check(). */
#ifndef STILLPOINT_SHM_PATTERN_H
#define STILLPOINT_SHM_PATTERN_H
#include "stillpoint_shm.h" /* first: it sets _POSIX_C_SOURCE for strict C99 */

#include <string.h>

static inline uint64_t sp_test_mix(uint64_t x) {
  x ^= x >> 33;
  x *= 0xff51afd7ed558ccdULL;
  x ^= x >> 33;
  x *= 0xc4ceb9fe1a85ec53ULL;
  x ^= x >> 33;
  return x;
}

/* Fills record n of generation g (sequence included; the writer sets it to n too). */
static inline void sp_test_fill(sp_pose_record* r, uint64_t g, uint64_t n) {
  uint64_t words[SP_SHM_POSE_WORDS];
  int i;
  words[0] = n;
  for (i = 1; i < SP_SHM_POSE_WORDS; ++i) words[i] = sp_test_mix(g * 0x9E3779B97F4A7C15ULL + n * 31u + (uint64_t)i);
  memcpy(r, words, sizeof(*r));
}

/* 1 when r is exactly record r->sequence of generation g. */
static inline int sp_test_check(const sp_pose_record* r, uint64_t g) {
  sp_pose_record expected;
  sp_test_fill(&expected, g, r->sequence);
  return memcmp(&expected, r, sizeof(expected)) == 0;
}
#endif
