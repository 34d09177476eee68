#!/usr/bin/env python3
"""Reads stillpoint's poses from the shared-memory ring, in plain Python (no packages).

    read_poses.py [--name RING] [--count N] [--timeout S] [--objects] [--owner USER|UID]

Attaches to /dev/shm/RING (default stillpoint_pose, what stillpointd writes), starts at the
newest record and prints one line per pose as it arrives: frame, stamp, tracking state, pose
health and, when the frame has a pose, T_map_camera (position [m], quaternion x y z w). The
ring's layout and protocol are those of the C reader, ipc/include/stillpoint_shm.h (pose
schema 4): a record is read between two equal even values of its slot's sequence word, so a
record the writer is overwriting is never returned. Exit status: 0 after N poses, 1 when the
ring is missing or not a pose ring of this schema, or nothing arrived within S seconds. As the C
reader, it reads only a regular file owned by --owner (default: the user running it; name the
daemon's user, e.g. stillpoint, when it runs as another one) whose size is its header's. When the
daemon restarts (a new ring at the name), it goes on with the new ring from its first record.

With --objects it reads the dynamic-objects ring next to it (RING_objects) instead: one line per
frame with a pose, the frame's objects in the map frame (id, label, which module found it,
centroid and extent [m], speed [m/s]; sp_object_record in stillpoint_shm.h).
"""
import argparse
import math
import mmap
import os
import pwd
import stat
import struct
import sys
import time

MAGIC = 0x48535053  # "SPSH"
OBJECTS_MAGIC = 0x4F535053  # "SPSO"
SCHEMA = 4
HEADER_SIZE, SLOT_SIZE, RECORD_SIZE = 128, 256, 224
STATES = ["initialising", "ok", "lost", "relocalised", "no_depth", "new_map"]
HEALTH = ["good", "degraded", "unreliable", "lost"]
# health_causes bits (SP_CAUSE_* in stillpoint_shm.h), lowest first.
CAUSES = ["few_inliers", "view_moving", "poor_conditioning", "high_reprojection", "fallback_evidence",
          "masks_late", "recovering"]
# sp_pose_record: sequence, stamps, frame counter, position[3], orientation[4], state,
# tracked, rejected, keyframes, map id, health, dynamic share, reprojection RMS, conditioning,
# health causes, semantic masks' age, covariance (upper triangle, 21), padding.
RECORD = struct.Struct("<QqqQ3d4dIIIIQIfffIf21f4x")
assert RECORD.size == RECORD_SIZE
# sp_object_record: sequence, stamps, frame counter, map id, id, index, count, sources, samples,
# centroid[3], extent[3], velocity[3], has_velocity, label, padding.
OBJECT = struct.Struct("<QqqQQIHHII3f3f3fI32s96x")
assert OBJECT.size == RECORD_SIZE
SOURCES = {1: "geometry", 2: "semantic", 3: "both"}


def owner_uid(owner):
    """The uid of a user name or number (None: the user running this)."""
    if owner is None:
        return os.geteuid()
    if owner.isdigit():
        return int(owner)
    try:
        return pwd.getpwnam(owner).pw_uid
    except KeyError:
        raise ValueError(f"no user {owner}") from None


def open_ring(name, magic=MAGIC, owner=None):
    path = "/dev/shm/" + name
    # Never follow a link or wait on a FIFO planted at the name; only the owner's ring counts.
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{path} is not a regular file")
        if st.st_uid != owner_uid(owner):
            raise ValueError(f"{path} belongs to uid {st.st_uid}, not to the ring's owner (--owner)")
        if st.st_size < HEADER_SIZE:
            raise ValueError(f"{path} is not a stillpoint ring (too short)")
        ring = mmap.mmap(fd, 0, prot=mmap.PROT_READ)
        identity = (st.st_dev, st.st_ino)
    finally:
        os.close(fd)
    ring_magic, schema, header_size, record_size, slot_size, capacity = struct.unpack_from("<IHHIII", ring, 0)
    if ring_magic != magic:
        raise ValueError(f"{path} is not a stillpoint {'pose' if magic == MAGIC else 'objects'} ring")
    if schema != SCHEMA:
        raise ValueError(f"{path} has pose schema {schema}; this reader knows {SCHEMA}")
    if ((header_size, record_size, slot_size) != (HEADER_SIZE, RECORD_SIZE, SLOT_SIZE) or capacity < 1
            or capacity & (capacity - 1) or len(ring) != HEADER_SIZE + capacity * SLOT_SIZE):
        raise ValueError(f"{path} has an inconsistent layout")
    return ring, capacity, identity


def replaced(name, identity):
    """Whether another file than the one read now stands at the ring's name (a restarted writer)."""
    try:
        st = os.lstat("/dev/shm/" + name)
    except OSError:
        return False  # gone for now: the writer may be restarting
    return (st.st_dev, st.st_ino) != identity


def write_count(ring):
    return struct.unpack_from("<Q", ring, 32)[0]


def try_read(ring, capacity, n, layout=RECORD):
    """Record n, or None when its slot does not hold it (not written yet, or overwritten)."""
    offset = HEADER_SIZE + (n & (capacity - 1)) * SLOT_SIZE
    seq = struct.unpack_from("<Q", ring, offset)[0]
    if seq != 2 * n:
        return None
    words = ring[offset + 8:offset + 8 + RECORD_SIZE]
    if struct.unpack_from("<Q", ring, offset)[0] != seq:
        return None
    return layout.unpack(words)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="stillpoint_pose")
    parser.add_argument("--count", type=int, default=0, help="exit after N poses (0: run until interrupted)")
    parser.add_argument("--timeout", type=float, default=10.0, help="give up when nothing arrives for S seconds")
    parser.add_argument("--objects", action="store_true", help="read the dynamic objects (RING_objects) instead")
    parser.add_argument("--owner", help="the user the ring must belong to (default: the user running this)")
    args = parser.parse_args()
    name = args.name + "_objects" if args.objects else args.name
    magic = OBJECTS_MAGIC if args.objects else MAGIC
    try:
        ring, capacity, identity = open_ring(name, magic, args.owner)
    except (OSError, ValueError, struct.error) as e:
        print(f"read_poses: {e}", file=sys.stderr)
        return 1
    next_n = max(1, write_count(ring))
    received, last_arrival, last_look = 0, time.monotonic(), time.monotonic()
    frame_objects, frame_open, open_frame = [], False, None
    while args.count == 0 or received < args.count:
        newest = write_count(ring)
        if next_n > newest:
            now = time.monotonic()
            if now - last_arrival > args.timeout:
                print(f"read_poses: nothing for {args.timeout} s", file=sys.stderr)
                return 1
            if now - last_look > 0.2:  # idle: now and then look for a restarted writer
                last_look = now
                if replaced(name, identity):
                    try:
                        ring, capacity, identity = open_ring(name, magic, args.owner)
                    except (OSError, ValueError, struct.error):
                        continue  # not ready yet: look again
                    print("read_poses: the writer restarted; reading its new ring", file=sys.stderr)
                    next_n, frame_open = 1, False
                    continue
            time.sleep(0.002)
            continue
        if newest - next_n >= capacity:
            next_n = newest - capacity + 1  # we fell a lap behind: skip what was overwritten
            frame_open = False  # a frame's records may be among the skipped
        r = try_read(ring, capacity, next_n, OBJECT if args.objects else RECORD)
        next_n += 1
        if r is None:
            frame_open = False  # overwritten while we looked
            continue
        if args.objects:
            (_, stamp_ns, _, frame, map_id, oid, index, count, sources, samples, cx, cy, cz, ex, ey, ez, vx, vy, vz,
             has_velocity, label) = r
            if index == 0:
                frame_objects, frame_open, open_frame = [], True, frame
            elif not frame_open or frame != open_frame or index != len(frame_objects):
                frame_open = False  # joined in the middle of a frame's records, or missed some of them
                continue
            if count > 0:
                speed = f"{math.sqrt(vx * vx + vy * vy + vz * vz):.2f}" if has_velocity else "?"
                name = label.split(b"\0")[0].decode(errors="replace")
                frame_objects.append(f"{oid}:{name}({SOURCES.get(sources, sources)}) "
                                     f"c=[{cx:.3f} {cy:.3f} {cz:.3f}] e=[{ex:.2f} {ey:.2f} {ez:.2f}] v={speed}")
            if len(frame_objects) < count:
                continue
            frame_open = False
            print(f"frame={frame} t={stamp_ns * 1e-9:.6f} map={map_id} objects={count}"
                  + "".join(" " + o for o in frame_objects), flush=True)
            received += 1
            last_arrival = time.monotonic()
            continue
        (_, stamp_ns, _, frame, px, py, pz, qx, qy, qz, qw, state, tracked, _, _, map_id, health, dynamic,
         rms, conditioning, causes, mask_age) = r[:22]
        covariance = r[22:]
        line = (f"frame={frame} t={stamp_ns * 1e-9:.6f} state={STATES[state] if state < len(STATES) else state} "
                f"health={HEALTH[health] if health < len(HEALTH) else health} map={map_id}")
        if math.isnan(px):
            line += " (no pose)"
        else:
            line += (f" p=[{px:.4f} {py:.4f} {pz:.4f}] q=[{qx:.4f} {qy:.4f} {qz:.4f} {qw:.4f}]"
                     f" inliers={tracked} dynamic_share={dynamic:.2f} rms_px={rms:.2f} conditioning={conditioning:.3f}")
            if causes:
                line += " causes=" + "+".join(CAUSES[b] if b < len(CAUSES) else f"bit{b}"
                                              for b in range(16) if causes >> b & 1)
            if mask_age >= 0:
                line += f" mask_age_s={mask_age:.2f}"
            # The standard deviation of x, y and z: the triangle's diagonal starts rows 0, 1, 2.
            line += " sigma_m=[" + " ".join(f"{math.sqrt(max(0.0, covariance[k])):.4f}" for k in (0, 6, 11)) + "]"
        print(line, flush=True)
        received += 1
        last_arrival = time.monotonic()
    return 0


if __name__ == "__main__":
    sys.exit(main())
