/*
 * stillpoint_shm.h - header-only reader of stillpoint's shared-memory pose ring.
 *
 * C99 or C++ (GCC or Clang), Linux. Needs nothing from stillpoint: copy this one file
 * into a controller and read the camera pose at camera rate without blocking the writer.
 *
 *   sp_shm_reader r;
 *   sp_shm_reader_init(&r);
 *   int rc = sp_shm_reader_open(&r, "stillpoint_pose", SP_SHM_START_LATEST);
 *   if (rc != SP_SHM_OK) { fprintf(stderr, "%s\n", sp_shm_strerror(rc)); ... }
 *   sp_pose_record pose;
 *   for (;;) {
 *     rc = sp_shm_reader_next(&r, &pose);   // never blocks
 *     if (rc == SP_SHM_OK) use(&pose);
 *     else if (rc == SP_SHM_EMPTY) sleep_a_little();
 *     else if (rc == SP_SHM_RESTARTED) note_writer_restart();  // stream starts again
 *   }
 *   sp_shm_reader_close(&r);
 *
 * Layout (little-endian, all fields naturally aligned): a 128-byte header, then
 * `capacity` slots of 256 bytes. Record n (1-based, per writer generation) lives in
 * slot n % capacity. Each slot is a seqlock: its `seq` word is 2n-1 while the writer
 * fills it with record n and 2n once complete. A reader copies the payload between two
 * reads of `seq` and keeps the copy only when both reads equal 2n, so it never returns
 * a torn record. Every shared word is accessed through the __atomic builtins (the same
 * code then compiles as C99, which has no <stdatomic.h>, and as C++). Payload words are
 * stored with release and loaded with acquire semantics instead of relying on fences:
 * a reader that sees any word of a newer write is then guaranteed to see that write's
 * odd `seq` on its second read. This costs nothing on x86, little on ARM (28 words),
 * and ThreadSanitizer understands it (it does not model fences).
 *
 * A restarting writer builds a fresh ring file and renames it over the old name, with
 * `generation` one higher. Readers notice the new file (different inode) while polling
 * and reattach to it; sp_shm_reader_next() then returns SP_SHM_RESTARTED once.
 *
 * Writer liveness: a writer holds an open-file-description write lock (F_OFD_SETLK) on
 * its ring file for as long as it lives, taken before the file gets its public name. The
 * kernel drops the lock when the writer exits, however it exits, so
 * sp_shm_writer_alive() and sp_shm_reader_writer_died() tell a running writer from a
 * killed one whose ring still says SP_SHM_WRITER_RUNNING. They only query the lock
 * (F_OFD_GETLK) on the reader's own descriptor. Writers exclude each other with a second
 * lock, on "/dev/shm/<name>.lock", which only the writer's user can open.
 *
 * Files: anyone can create files in /dev/shm, so the ring is opened without following a
 * symbolic link and without blocking on a FIFO, and must be a regular file owned by the
 * expected user (r.owner_uid: this process's effective uid unless set after
 * sp_shm_reader_init(); name the writer's user when it runs as another one). Anything
 * else at the ring's path is refused (SP_SHM_ERR_NOT_REGULAR, SP_SHM_ERR_OWNER) with
 * r.found_mode and r.found_uid saying what was there. The writer applies the same rules
 * to its files.
 *
 * In strict C99 mode (-std=c99) POSIX declarations need _POSIX_C_SOURCE; this header
 * defines it when nothing else has, so include it first or define it yourself.
 */
#ifndef STILLPOINT_SHM_H
#define STILLPOINT_SHM_H

#if !defined(_POSIX_C_SOURCE) && !defined(_GNU_SOURCE) && !defined(_DEFAULT_SOURCE)
#define _POSIX_C_SOURCE 200809L
#endif

#include <errno.h>
#include <fcntl.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#ifdef O_CLOEXEC
#define SP_SHM_O_CLOEXEC O_CLOEXEC
#else /* a system header came first without _POSIX_C_SOURCE >= 200809L */
#define SP_SHM_O_CLOEXEC 0
#endif

#ifndef O_NOFOLLOW /* no silent fallback: following a planted link is what it prevents */
#error "stillpoint_shm.h needs O_NOFOLLOW: include it first, or define _POSIX_C_SOURCE >= 200809L"
#endif

/* Open-file-description locks (Linux 3.15): glibc declares them only for _GNU_SOURCE;
 * the value is the same on every Linux architecture. */
#ifdef F_OFD_GETLK
#define SP_SHM_F_OFD_GETLK F_OFD_GETLK
#else
#define SP_SHM_F_OFD_GETLK 36
#endif

#if !defined(__GNUC__) && !defined(__clang__)
#error "stillpoint_shm.h needs the GCC/Clang __atomic builtins"
#endif

#ifdef __cplusplus
extern "C" {
#endif

#define SP_SHM_MAGIC 0x48535053u /* "SPSH" in little-endian byte order: a pose ring */
#define SP_SHM_OBJECTS_MAGIC 0x4F535053u /* "SPSO": a dynamic-objects ring (sp_object_record) */
#define SP_SHM_SCHEMA_VERSION 4u
#define SP_SHM_HEADER_SIZE 128u
#define SP_SHM_SLOT_SIZE 256u
#define SP_SHM_POSE_WORDS 28
#define SP_SHM_DEFAULT_NAME "stillpoint_pose"
#define SP_SHM_DEFAULT_OBJECTS_NAME "stillpoint_pose_objects" /* <pose ring name>_objects */
#define SP_SHM_LABEL_SIZE 32
#define SP_SHM_DIR "/dev/shm/"
#define SP_SHM_LOCK_SUFFIX ".lock" /* writers' lock file, mode 0600: SP_SHM_DIR <name> SP_SHM_LOCK_SUFFIX */
#define SP_SHM_MAX_CAPACITY (1u << 20)

/* Tracking state of a pose record. */
enum {
  SP_TRACKING_INITIALISING = 0,
  SP_TRACKING_OK = 1,
  SP_TRACKING_LOST = 2,
  SP_TRACKING_RELOCALISED = 3,
  SP_TRACKING_NO_DEPTH = 4, /* too little depth to track: no pose */
  SP_TRACKING_NEW_MAP = 5   /* first pose of a new map (map_id changed) after a loss */
};

/* How far to trust a pose record (docs/pose-health.md). */
enum { SP_HEALTH_GOOD = 0, SP_HEALTH_DEGRADED = 1, SP_HEALTH_UNRELIABLE = 2, SP_HEALTH_LOST = 3 };

/* What lowered a pose record's health: bits of health_causes (docs/pose-health.md). */
enum {
  SP_CAUSE_FEW_INLIERS = 1,         /* under 80 map points in the pose (30: unreliable) */
  SP_CAUSE_VIEW_MOVING = 2,         /* over a quarter of the view moving (half: unreliable) */
  SP_CAUSE_POOR_CONDITIONING = 4,   /* conditioning under 0.05 (0.02: unreliable) */
  SP_CAUSE_HIGH_REPROJECTION = 8,   /* the inliers' RMS over 2 px */
  SP_CAUSE_FALLBACK_EVIDENCE = 16,  /* kept on fallback evidence: unreliable */
  SP_CAUSE_MASKS_LATE = 32,         /* the semantic module alone, masks over 0.6 s old (2 s: unreliable) */
  SP_CAUSE_RECOVERING = 64          /* the frame's own level is better, not held long enough yet */
};

/* Writer state in the header. */
enum { SP_SHM_WRITER_RUNNING = 1, SP_SHM_WRITER_CLOSED = 2 };

/* Pose record, schema version 4 (version 3 added health_causes and mask_age_s, version 4
 * the covariance). Exactly
 * SP_SHM_POSE_WORDS 64-bit words. A record
 * without a pose (tracking_state not OK, RELOCALISED or NEW_MAP) has NaN in
 * position and orientation. */
typedef struct sp_pose_record {
  uint64_t sequence;         /* 1-based position in this writer generation's stream */
  int64_t sensor_stamp_ns;   /* capture time of the frame */
  int64_t publish_stamp_ns;  /* CLOCK_REALTIME when the publisher sent it */
  uint64_t frame_counter;    /* frames seen by the tracker since start */
  double position[3];        /* translation of T_map_camera [m] */
  double orientation[4];     /* rotation of T_map_camera, unit quaternion x, y, z, w */
  uint32_t tracking_state;   /* SP_TRACKING_* */
  uint32_t tracked_features;
  uint32_t dynamic_rejected_features;
  uint32_t keyframes;
  uint64_t map_id;           /* changes when the map is reset */
  uint32_t health;           /* SP_HEALTH_* */
  float dynamic_share;       /* features kept out as moving / (those + inliers) */
  float reprojection_rms_px; /* of the inliers */
  float conditioning;        /* 0..1: how well the inliers pin all six degrees of freedom */
  uint32_t health_causes;    /* SP_CAUSE_* bits: what lowered the health (0: nothing) */
  float mask_age_s;          /* newest semantic masks' age [s]; inf: none near the camera, -1: not known */
  float covariance[21];      /* the pose's covariance: upper triangle, row by row, over x y z [m] and the
                                rotation about the map's x y z [rad] (docs/pose-health.md); 0 without a pose */
  uint32_t reserved;         /* 0 */
} sp_pose_record;

/* Dynamic-object record, schema version 4 (docs/dynamic-objects.md), in a ring of its
 * own (SP_SHM_OBJECTS_MAGIC; sp_shm_reader_open_objects()). Exactly SP_SHM_POSE_WORDS
 * 64-bit words. Each frame with a pose gives `count` records, index 0..count-1, one per
 * object, or one record with count 0 when nothing moves. Positions in the map frame
 * of the pose records (the first camera's optical axes). */
typedef struct sp_object_record {
  uint64_t sequence;          /* 1-based position in this writer generation's stream */
  int64_t sensor_stamp_ns;    /* capture time of the frame */
  int64_t publish_stamp_ns;   /* CLOCK_REALTIME when the publisher sent it */
  uint64_t frame_counter;     /* the frame's pose record has the same */
  uint64_t map_id;
  uint32_t id;                /* stable while the object is followed; 0 when count is 0 */
  uint16_t index;             /* this object's place in the frame's records */
  uint16_t count;             /* objects in the frame (0: nothing moves) */
  uint32_t sources;           /* 1 geometry module, 2 semantic module, 3 both */
  uint32_t samples;           /* surface points it was measured from */
  float centroid[3];          /* median of its surface points [m] */
  float extent[3];            /* 5-95 % range of its surface points per axis [m] */
  float velocity[3];          /* of the centroid [m/s] */
  uint32_t has_velocity;      /* 0 until seen twice */
  char label[SP_SHM_LABEL_SIZE]; /* class ("person") or "unknown", NUL-terminated */
  uint64_t reserved[12];      /* 0: pads the record to the pose record's size */
} sp_object_record;

typedef struct sp_shm_slot {
  uint64_t seq; /* 0 empty, 2n-1 writing record n, 2n holds record n */
  uint64_t words[SP_SHM_POSE_WORDS];
  uint64_t reserved[3];
} sp_shm_slot;

typedef struct sp_shm_header {
  uint32_t magic;          /* written last when the ring is created */
  uint16_t schema_version; /* SP_SHM_SCHEMA_VERSION */
  uint16_t header_size;    /* SP_SHM_HEADER_SIZE */
  uint32_t record_size;    /* sizeof(sp_pose_record) */
  uint32_t slot_size;      /* SP_SHM_SLOT_SIZE */
  uint32_t capacity;       /* slots, a power of two */
  uint32_t writer_pid;
  uint64_t generation;     /* 1 for the first writer, +1 on each restart */
  uint64_t write_count;    /* atomic: sequence of the newest complete record */
  uint64_t writer_state;   /* atomic: SP_SHM_WRITER_* */
  int64_t created_ns;      /* CLOCK_REALTIME when this generation started */
  uint64_t reserved[9];
} sp_shm_header;

/* Compile-time layout checks (C99 has no static_assert). */
typedef char sp_shm_check_record_size[(sizeof(sp_pose_record) == 8 * SP_SHM_POSE_WORDS) ? 1 : -1];
typedef char sp_shm_check_object_size[(sizeof(sp_object_record) == 8 * SP_SHM_POSE_WORDS) ? 1 : -1];
typedef char sp_shm_check_slot_size[(sizeof(sp_shm_slot) == SP_SHM_SLOT_SIZE) ? 1 : -1];
typedef char sp_shm_check_header_size[(sizeof(sp_shm_header) == SP_SHM_HEADER_SIZE) ? 1 : -1];

/* Return codes. Negative values are errors. */
enum {
  SP_SHM_OK = 0,
  SP_SHM_EMPTY = 1,             /* no record newer than the last one returned */
  SP_SHM_RESTARTED = 2,         /* writer restarted; reader reattached, no record returned */
  SP_SHM_ERR_NAME = -1,         /* name empty, too long, or with characters other than [A-Za-z0-9._-] */
  SP_SHM_ERR_NO_RING = -2,      /* no ring of that name (is the writer running?) */
  SP_SHM_ERR_OPEN = -3,         /* open/fstat/mmap failed (see errno) */
  SP_SHM_ERR_NOT_A_RING = -4,   /* wrong magic, or file too small */
  SP_SHM_ERR_VERSION = -5,      /* schema version this reader does not know */
  SP_SHM_ERR_LAYOUT = -6,       /* header/record/slot size or capacity inconsistent */
  SP_SHM_ERR_NOT_OPEN = -7,     /* reader not attached */
  SP_SHM_ERR_NOT_REGULAR = -8,  /* a FIFO, symbolic link, directory, device or socket is at the ring's path */
  SP_SHM_ERR_OWNER = -9         /* the file belongs to another user than r.owner_uid */
};

enum { SP_SHM_START_LATEST = 0, SP_SHM_START_OLDEST = 1 };

typedef struct sp_shm_reader {
  char path[256];
  int fd;
  int start_mode;
  const unsigned char* base;
  size_t map_size;
  uint64_t generation;     /* generation of the ring currently attached */
  uint64_t next_sequence;  /* next record this reader will return */
  uint64_t lost;           /* records overwritten before this reader reached them */
  uint64_t restarts;       /* writer restarts seen */
  uint64_t dev, ino;       /* identity of the attached file */
  uint32_t empty_polls;
  uint32_t owner_uid;      /* user that must own the ring; sp_shm_reader_init(): the effective uid */
  uint32_t found_mode;     /* st_mode of the file refused with SP_SHM_ERR_NOT_REGULAR or _OWNER */
  uint32_t found_uid;      /* its owner */
  uint32_t magic;          /* the kind of ring it reads: SP_SHM_MAGIC (poses) or SP_SHM_OBJECTS_MAGIC */
  uint32_t restart_pending; /* a restarted writer's ring could not be attached yet */
} sp_shm_reader;

static inline const char* sp_shm_strerror(int code) {
  switch (code) {
    case SP_SHM_OK: return "ok";
    case SP_SHM_EMPTY: return "no new record";
    case SP_SHM_RESTARTED: return "writer restarted";
    case SP_SHM_ERR_NAME: return "invalid ring name (use 1-200 characters from [A-Za-z0-9._-], not starting with '.')";
    case SP_SHM_ERR_NO_RING: return "no pose ring of that name in /dev/shm (is the stillpoint publisher running?)";
    case SP_SHM_ERR_OPEN: return "cannot open or map the pose ring";
    case SP_SHM_ERR_NOT_A_RING: return "file is not a stillpoint pose ring (bad magic or too small)";
    case SP_SHM_ERR_VERSION: return "pose ring has a schema version this reader does not support";
    case SP_SHM_ERR_LAYOUT: return "pose ring header is inconsistent (record size, slot size or capacity)";
    case SP_SHM_ERR_NOT_OPEN: return "reader is not attached to a ring";
    case SP_SHM_ERR_NOT_REGULAR: return "the ring's path is not a regular file (FIFO, symbolic link, directory, ...); refused";
    case SP_SHM_ERR_OWNER: return "the ring file belongs to another user than the expected writer; refused";
    default: return "unknown error";
  }
}

/* Validates a ring name and writes "/dev/shm/<name>" into out. */
static inline int sp_shm_make_path(const char* name, char* out, size_t out_size) {
  size_t i, n;
  if (name == NULL) return SP_SHM_ERR_NAME;
  n = strlen(name);
  if (n == 0 || n > 200 || name[0] == '.') return SP_SHM_ERR_NAME;
  for (i = 0; i < n; ++i) {
    const char c = name[i];
    const int ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                   c == '_' || c == '-' || c == '.';
    if (!ok) return SP_SHM_ERR_NAME;
  }
  if ((size_t)snprintf(out, out_size, "%s%s", SP_SHM_DIR, name) >= out_size) return SP_SHM_ERR_NAME;
  return SP_SHM_OK;
}

static inline const sp_shm_header* sp_shm_reader_header(const sp_shm_reader* r) {
  return (const sp_shm_header*)(const void*)r->base;
}

static inline const sp_shm_slot* sp_shm_reader_slot(const sp_shm_reader* r, uint64_t n) {
  const sp_shm_header* h = sp_shm_reader_header(r);
  return (const sp_shm_slot*)(const void*)(r->base + SP_SHM_HEADER_SIZE +
                                            (size_t)(n & (uint64_t)(h->capacity - 1u)) * SP_SHM_SLOT_SIZE);
}

/* What an st_mode is, in words, for error messages. */
static inline const char* sp_shm_file_kind(uint32_t found_mode) {
  const mode_t mode = (mode_t)found_mode;
  if (S_ISREG(mode)) return "regular file";
  if (S_ISFIFO(mode)) return "FIFO";
  if (S_ISLNK(mode)) return "symbolic link";
  if (S_ISDIR(mode)) return "directory";
  if (S_ISCHR(mode)) return "character device";
  if (S_ISBLK(mode)) return "block device";
  if (S_ISSOCK(mode)) return "socket";
  return "file of unknown type";
}

/* Opens `path` (flags: O_RDONLY, or O_RDWR with O_CREAT) without following a symbolic
 * link and without blocking on a FIFO, and keeps it only if it is a regular file owned
 * by `owner_uid`: anyone can create a FIFO in /dev/shm, on which a plain open() blocks
 * forever, or plant a file for us to read. Returns the descriptor, or
 * SP_SHM_ERR_NO_RING (nothing there), SP_SHM_ERR_NOT_REGULAR / SP_SHM_ERR_OWNER with
 * *st describing what is there, or SP_SHM_ERR_OPEN (errno says why). Shared with the
 * writer so both apply the same rules. */
static inline int sp_shm_open_file(const char* path, int flags, unsigned mode, uint32_t owner_uid, struct stat* st) {
  int fd, err;
  memset(st, 0, sizeof(*st));
  fd = open(path, flags | O_NOFOLLOW | O_NONBLOCK | SP_SHM_O_CLOEXEC, mode);
  if (fd < 0) {
    err = errno;
    if (err == ENOENT) return SP_SHM_ERR_NO_RING;
    /* Say what is there when it is not a regular file (ELOOP: a symbolic link,
     * EISDIR: a directory opened for writing, EACCES: a device on a nodev mount). */
    if (lstat(path, st) == 0 && !S_ISREG(st->st_mode)) return SP_SHM_ERR_NOT_REGULAR;
    memset(st, 0, sizeof(*st));
    errno = err;
    return SP_SHM_ERR_OPEN;
  }
  if (fstat(fd, st) != 0) {
    err = errno;
    close(fd);
    errno = err;
    return SP_SHM_ERR_OPEN;
  }
  if (!S_ISREG(st->st_mode)) {
    close(fd);
    return SP_SHM_ERR_NOT_REGULAR;
  }
  if ((uint32_t)st->st_uid != owner_uid) {
    close(fd);
    return SP_SHM_ERR_OWNER;
  }
  return fd;
}

/* Checks a mapped header of a ring of kind `magic`. Kept separate so the writer uses
 * the same rules. */
static inline int sp_shm_check_header_of(const sp_shm_header* h, size_t file_size, uint32_t magic) {
  if (file_size < SP_SHM_HEADER_SIZE) return SP_SHM_ERR_NOT_A_RING;
  if (__atomic_load_n(&h->magic, __ATOMIC_ACQUIRE) != magic) return SP_SHM_ERR_NOT_A_RING;
  if (h->schema_version != SP_SHM_SCHEMA_VERSION) return SP_SHM_ERR_VERSION;
  if (h->header_size != SP_SHM_HEADER_SIZE || h->record_size != sizeof(sp_pose_record) ||
      h->slot_size != SP_SHM_SLOT_SIZE || h->capacity == 0 || h->capacity > SP_SHM_MAX_CAPACITY ||
      (h->capacity & (h->capacity - 1u)) != 0 ||
      file_size != (size_t)SP_SHM_HEADER_SIZE + (size_t)h->capacity * SP_SHM_SLOT_SIZE)
    return SP_SHM_ERR_LAYOUT;
  return SP_SHM_OK;
}

/* A pose ring's header. */
static inline int sp_shm_check_header(const sp_shm_header* h, size_t file_size) {
  return sp_shm_check_header_of(h, file_size, SP_SHM_MAGIC);
}

static inline void sp_shm_reader_init(sp_shm_reader* r) {
  memset(r, 0, sizeof(*r));
  r->fd = -1;
  r->owner_uid = (uint32_t)geteuid();
  r->magic = SP_SHM_MAGIC;
}

static inline void sp_shm_reader_detach(sp_shm_reader* r) {
  if (r->base != NULL) munmap((void*)(uintptr_t)r->base, r->map_size);
  if (r->fd >= 0) close(r->fd);
  r->base = NULL;
  r->map_size = 0;
  r->fd = -1;
}

/* Maps the file at r->path; on success positions the reader per r->start_mode. */
static inline int sp_shm_reader_attach(sp_shm_reader* r) {
  struct stat st;
  void* map;
  int rc;
  const sp_shm_header* h;
  uint64_t newest, capacity;
  r->found_mode = r->found_uid = 0;
  rc = sp_shm_open_file(r->path, O_RDONLY, 0, r->owner_uid, &st);
  if (rc < 0) {
    r->found_mode = (uint32_t)st.st_mode;
    r->found_uid = (uint32_t)st.st_uid;
    return rc;
  }
  r->fd = rc;
  if ((size_t)st.st_size < SP_SHM_HEADER_SIZE) {
    sp_shm_reader_detach(r);
    return SP_SHM_ERR_NOT_A_RING;
  }
  map = mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_SHARED, r->fd, 0);
  if (map == MAP_FAILED) {
    sp_shm_reader_detach(r);
    return SP_SHM_ERR_OPEN;
  }
  r->base = (const unsigned char*)map;
  r->map_size = (size_t)st.st_size;
  h = sp_shm_reader_header(r);
  rc = sp_shm_check_header_of(h, r->map_size, r->magic);
  if (rc != SP_SHM_OK) {
    sp_shm_reader_detach(r);
    return rc;
  }
  r->dev = (uint64_t)st.st_dev;
  r->ino = (uint64_t)st.st_ino;
  r->generation = h->generation;
  newest = __atomic_load_n(&h->write_count, __ATOMIC_ACQUIRE);
  capacity = h->capacity;
  if (r->start_mode == SP_SHM_START_OLDEST)
    r->next_sequence = newest >= capacity ? newest - capacity + 1 : 1;
  else
    r->next_sequence = newest + 1;
  r->empty_polls = 0;
  return SP_SHM_OK;
}

/* Opens the ring `name` (in /dev/shm). start: SP_SHM_START_LATEST returns only records
 * published from now on, SP_SHM_START_OLDEST the oldest still in the ring first. */
static inline int sp_shm_reader_open_kind(sp_shm_reader* r, const char* name, int start, uint32_t magic) {
  int rc;
  sp_shm_reader_detach(r);
  r->magic = magic;
  r->restart_pending = 0;
  rc = sp_shm_make_path(name, r->path, sizeof(r->path));
  if (rc != SP_SHM_OK) return rc;
  r->start_mode = start;
  return sp_shm_reader_attach(r);
}

static inline int sp_shm_reader_open(sp_shm_reader* r, const char* name, int start) {
  return sp_shm_reader_open_kind(r, name, start, SP_SHM_MAGIC);
}

/* Opens the dynamic-objects ring `name` (SP_SHM_DEFAULT_OBJECTS_NAME unless configured);
 * read it with sp_shm_reader_next_object(). */
static inline int sp_shm_reader_open_objects(sp_shm_reader* r, const char* name, int start) {
  return sp_shm_reader_open_kind(r, name, start, SP_SHM_OBJECTS_MAGIC);
}

static inline void sp_shm_reader_close(sp_shm_reader* r) { sp_shm_reader_detach(r); }

/* 1 when the attached writer has closed the ring cleanly (no more records until a restart). */
static inline int sp_shm_reader_writer_closed(const sp_shm_reader* r) {
  if (r->base == NULL) return 0;
  return __atomic_load_n(&sp_shm_reader_header(r)->writer_state, __ATOMIC_ACQUIRE) == SP_SHM_WRITER_CLOSED;
}

/* Reattaches when the name now points at a different file (a restarted writer).
 * Returns SP_SHM_RESTARTED when it did, SP_SHM_OK when nothing changed. A missing file
 * keeps the old mapping (the writer may be restarting). A restarted writer's ring that
 * cannot be attached yet is attached on a later call, which then says SP_SHM_RESTARTED.
 * A ring file shorter than the mapping (truncated under the reader) is detached with
 * SP_SHM_ERR_LAYOUT before a read of it faults. */
static inline int sp_shm_reader_check_restart(sp_shm_reader* r) {
  struct stat st;
  int rc;
  if (r->base == NULL) { /* opened before the ring existed, or after a restart that failed to attach */
    rc = sp_shm_reader_attach(r);
    if (rc != SP_SHM_OK) return rc;
    if (!r->restart_pending) return SP_SHM_EMPTY;
    r->restart_pending = 0;
    r->restarts++;
    return SP_SHM_RESTARTED;
  }
  if (fstat(r->fd, &st) == 0 && (size_t)st.st_size < r->map_size) {
    sp_shm_reader_detach(r);
    return SP_SHM_ERR_LAYOUT;
  }
  if (lstat(r->path, &st) != 0) return SP_SHM_OK;
  if ((uint64_t)st.st_ino == r->ino && (uint64_t)st.st_dev == r->dev) return SP_SHM_OK;
  sp_shm_reader_detach(r);
  r->start_mode = SP_SHM_START_OLDEST; /* a new stream: deliver it from its start */
  rc = sp_shm_reader_attach(r);
  if (rc != SP_SHM_OK) {
    r->restart_pending = 1;
    return rc;
  }
  r->restarts++;
  return SP_SHM_RESTARTED;
}

/* 1 while the writer of the attached ring runs (holds its write lock on the ring file),
 * 0 once it has ended, negative SP_SHM_ERR_* on error. One fcntl() on the reader's
 * descriptor. Only a write lock counts: anyone who can read the ring can put a read lock
 * on it, but only its owner can write-lock it. */
static inline int sp_shm_writer_alive(const sp_shm_reader* r) {
  struct flock query;
  if (r->base == NULL || r->fd < 0) return SP_SHM_ERR_NOT_OPEN;
  memset(&query, 0, sizeof(query));
  query.l_type = F_WRLCK;
  query.l_whence = SEEK_SET; /* l_start = l_len = 0: the whole file */
  if (fcntl(r->fd, SP_SHM_F_OFD_GETLK, &query) != 0) return SP_SHM_ERR_OPEN;
  return query.l_type == F_WRLCK ? 1 : 0;
}

/* For a reader that has had SP_SHM_EMPTY for a while (say 100 ms): 1 when the writer of
 * the attached ring ended without closing it (SIGKILL, crash) and no new writer has
 * replaced the ring; 0 while it runs, after a clean close (a restart may follow), or when
 * a new ring is already at the name (sp_shm_reader_next() reattaches to it shortly);
 * negative SP_SHM_ERR_* on error. Asks the lock first and the ring's state second: a
 * writer marks its ring closed before the lock goes. */
static inline int sp_shm_reader_writer_died(const sp_shm_reader* r) {
  struct stat st;
  const int alive = sp_shm_writer_alive(r);
  if (alive != 0) return alive < 0 ? alive : 0;
  if (__atomic_load_n(&sp_shm_reader_header(r)->writer_state, __ATOMIC_ACQUIRE) == SP_SHM_WRITER_CLOSED) return 0;
  if (lstat(r->path, &st) == 0 && ((uint64_t)st.st_ino != r->ino || (uint64_t)st.st_dev != r->dev)) return 0;
  return 1;
}

/* Copies record n if the slot still holds it. 1 on success, 0 if it was overwritten. */
static inline int sp_shm_try_read(const sp_shm_reader* r, uint64_t n, void* out) {
  uint64_t words[SP_SHM_POSE_WORDS];
  const sp_shm_slot* slot = sp_shm_reader_slot(r, n);
  uint64_t s1, s2;
  int i;
  s1 = __atomic_load_n(&slot->seq, __ATOMIC_ACQUIRE);
  if (s1 != 2 * n) return 0;
  /* Acquire loads: the second read of seq cannot move above them, and reading any word
   * of a newer write makes that write's odd seq visible to it. */
  for (i = 0; i < SP_SHM_POSE_WORDS; ++i) words[i] = __atomic_load_n(&slot->words[i], __ATOMIC_ACQUIRE);
  s2 = __atomic_load_n(&slot->seq, __ATOMIC_RELAXED);
  if (s2 != s1) return 0;
  memcpy(out, words, sizeof(words));
  return 1;
}

/* Returns the next record in order (SP_SHM_OK), SP_SHM_EMPTY when there is none yet, or
 * SP_SHM_RESTARTED after reattaching to a restarted writer. Never blocks. Records the
 * writer overwrote before this reader got to them are skipped and counted in r->lost. */
static inline int sp_shm_reader_next_record(sp_shm_reader* r, void* out) {
  const sp_shm_header* h;
  uint64_t newest, capacity;
  int attempt;
  if (r->base == NULL) {
    if (r->path[0] == '\0') return SP_SHM_ERR_NOT_OPEN;
    return sp_shm_reader_check_restart(r);
  }
  h = sp_shm_reader_header(r);
  capacity = h->capacity;
  for (attempt = 0; attempt < 16; ++attempt) {
    newest = __atomic_load_n(&h->write_count, __ATOMIC_ACQUIRE);
    if (r->next_sequence > newest) {
      /* Nothing new: now and then (or when the writer said goodbye) look for a restart. */
      if (++r->empty_polls >= 64 || __atomic_load_n(&h->writer_state, __ATOMIC_ACQUIRE) == SP_SHM_WRITER_CLOSED) {
        r->empty_polls = 0;
        if (sp_shm_reader_check_restart(r) == SP_SHM_RESTARTED) return SP_SHM_RESTARTED;
      }
      return SP_SHM_EMPTY;
    }
    r->empty_polls = 0;
    if (newest - r->next_sequence >= capacity) {
      r->lost += newest - capacity + 1 - r->next_sequence;
      r->next_sequence = newest - capacity + 1;
    }
    if (sp_shm_try_read(r, r->next_sequence, out)) {
      r->next_sequence++;
      return SP_SHM_OK;
    }
    /* Overwritten while we looked: the writer lapped us; skip ahead and retry. */
    r->lost++;
    r->next_sequence++;
  }
  return SP_SHM_EMPTY;
}

static inline int sp_shm_reader_next(sp_shm_reader* r, sp_pose_record* out) {
  if (r->magic != SP_SHM_MAGIC) return SP_SHM_ERR_NOT_A_RING;
  return sp_shm_reader_next_record(r, out);
}

/* sp_shm_reader_next() for a reader opened with sp_shm_reader_open_objects(). */
static inline int sp_shm_reader_next_object(sp_shm_reader* r, sp_object_record* out) {
  if (r->magic != SP_SHM_OBJECTS_MAGIC) return SP_SHM_ERR_NOT_A_RING;
  return sp_shm_reader_next_record(r, out);
}

/* Returns the newest record (SP_SHM_OK) and skips anything older; SP_SHM_EMPTY if the
 * ring has no record yet. For consumers that only want the current pose. */
static inline int sp_shm_reader_latest(sp_shm_reader* r, sp_pose_record* out) {
  const sp_shm_header* h;
  uint64_t newest;
  int attempt;
  if (r->magic != SP_SHM_MAGIC) return SP_SHM_ERR_NOT_A_RING;
  if (r->base == NULL) return r->path[0] == '\0' ? SP_SHM_ERR_NOT_OPEN : sp_shm_reader_check_restart(r);
  h = sp_shm_reader_header(r);
  for (attempt = 0; attempt < 16; ++attempt) {
    newest = __atomic_load_n(&h->write_count, __ATOMIC_ACQUIRE);
    if (newest == 0 || newest < r->next_sequence) return sp_shm_reader_next(r, out);
    if (sp_shm_try_read(r, newest, out)) {
      if (newest > r->next_sequence) r->lost += newest - r->next_sequence;
      r->next_sequence = newest + 1;
      return SP_SHM_OK;
    }
  }
  return SP_SHM_EMPTY;
}

#ifdef __cplusplus
}
#endif

#endif /* STILLPOINT_SHM_H */
