/* Stress-test reader of the shared-memory pose ring, built only from the header-only
 * reader (stillpoint_shm.h) and compiled both as C99 (shm_reader_c) and as C++
 * (shm_reader_cxx): it links nothing from stillpoint.
 *
 *   shm_reader_c NAME SECONDS [--from-oldest] [--expect-restarts K]
 *
 * Reads for SECONDS (waiting for the ring if it does not exist yet) and checks every
 * record against the writer's test pattern: no torn record, sequences strictly
 * increasing within a writer generation. Prints one summary line; exit 0 when clean and
 * at least one record was read, 1 otherwise, 2 on usage errors. */
#include "shm_pattern.h"

#include <stdlib.h>
#include <time.h>

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int main(int argc, char** argv) {
  sp_shm_reader r;
  sp_pose_record rec;
  double seconds, end;
  int i, rc, start = SP_SHM_START_LATEST, attached = 0;
  long expect_restarts = 0;
  unsigned long long received = 0, torn = 0, out_of_order = 0, restarts = 0, generations_seen = 0;
  uint64_t last_seq = 0, generation = 0;
  struct timespec nap;
  nap.tv_sec = 0;
  nap.tv_nsec = 20000;

  if (argc < 3) {
    fprintf(stderr, "usage: %s NAME SECONDS [--from-oldest] [--expect-restarts K]\n", argv[0]);
    return 2;
  }
  seconds = atof(argv[2]);
  for (i = 3; i < argc; ++i) {
    if (strcmp(argv[i], "--from-oldest") == 0) {
      start = SP_SHM_START_OLDEST;
    } else if (strcmp(argv[i], "--expect-restarts") == 0 && i + 1 < argc) {
      expect_restarts = atol(argv[++i]);
    } else {
      fprintf(stderr, "%s: unknown argument %s\n", argv[0], argv[i]);
      return 2;
    }
  }
  sp_shm_reader_init(&r);
  end = now_s() + seconds;
  rc = sp_shm_reader_open(&r, argv[1], start);
  if (rc != SP_SHM_OK && rc != SP_SHM_ERR_NO_RING) {
    fprintf(stderr, "%s: %s\n", argv[0], sp_shm_strerror(rc));
    return 1;
  }
  while (now_s() < end) {
    rc = sp_shm_reader_next(&r, &rec);
    if (r.base != NULL && (!attached || r.generation != generation)) {
      attached = 1;
      generation = r.generation;
      last_seq = 0;
      generations_seen++;
    }
    if (rc == SP_SHM_OK) {
      received++;
      if (!sp_test_check(&rec, generation)) torn++;
      if (rec.sequence <= last_seq) out_of_order++;
      last_seq = rec.sequence;
    } else if (rc == SP_SHM_RESTARTED) {
      restarts++;
    } else if (rc == SP_SHM_EMPTY || rc == SP_SHM_ERR_NO_RING) {
      nanosleep(&nap, NULL);
    } else {
      fprintf(stderr, "%s: %s\n", argv[0], sp_shm_strerror(rc));
      sp_shm_reader_close(&r);
      return 1;
    }
  }
  printf("reader received=%llu torn=%llu out_of_order=%llu lost=%llu restarts=%llu generations=%llu\n", received,
         torn, out_of_order, (unsigned long long)r.lost, restarts, generations_seen);
  sp_shm_reader_close(&r);
  return (received > 0 && torn == 0 && out_of_order == 0 && (long)restarts >= expect_restarts) ? 0 : 1;
}
