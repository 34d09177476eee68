#!/usr/bin/env python3
"""Python LCM subscriber for stillpoint's messages (PyPI `lcm` + the lcm-gen Python types).

    lcm_python_check.py GEN_PYTHON_DIR URL COUNT STATUSES [SUFFIX] [READY_FILE]

Subscribes to STILLPOINT_POSE<SUFFIX> and STILLPOINT_STATUS<SUFFIX> on URL (udpm:// or
file://...?speed=0), decodes with stillpoint_lcm.pose_t/status_t and checks every pose
against the formula of ipc/tools/probe_messages.cpp (testPose), bit for bit. Exit 0 when
COUNT poses and STATUSES statuses arrived exactly; 77 when the lcm module is missing."""
import math
import os
import struct
import sys
import time

try:
    import lcm
except ImportError:
    print("SKIP: Python module lcm not installed (pip install lcm)")
    sys.exit(77)

gen_dir, url, count, statuses = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
suffix = sys.argv[5] if len(sys.argv) > 5 else ""
ready = sys.argv[6] if len(sys.argv) > 6 else ""
sys.path.insert(0, gen_dir)
from stillpoint_lcm import pose_t, status_t  # noqa: E402


def f32(x):
    """x rounded to single precision (as the C++ float arithmetic of testPose)."""
    return struct.unpack("f", struct.pack("f", x))[0]


def int16(bits):
    """The 16 bits as LCM's signed int16 carries them."""
    return bits - (1 << 16) if bits >= 1 << 15 else bits


def expected_pose(k):
    """Same arithmetic as probe::testPose(k): CPython's math calls the C library."""
    a = k * 0.001
    half = 0.5 * math.fmod(a * 7.0, 6.28318530717958)
    ax = (0.267261241912424, 0.534522483824849, 0.801783725737273)
    s = math.sin(half)
    map_id = 0xC0FFEE0000000000 | (k // 100)
    posed = k % 4 in (1, 3)  # ok, relocalised; initialising and lost carry NaN
    return {
        "schema_version": 4,
        "sensor_stamp_ns": 1700000000123456789 + k * 33333333,
        "frame_counter": k,
        "position": [math.sin(a) * 3.14159265358979, -math.ldexp(float(k), -7) / 3.0, 1.0 / (k + 3.0)]
        if posed else [math.nan] * 3,
        "orientation": [ax[0] * s, ax[1] * s, ax[2] * s, math.cos(half)] if posed else [math.nan] * 4,
        "tracking_state": k % 4,
        "tracked_features": 400 + k % 700,
        "dynamic_rejected_features": k % 37,
        "keyframes": k // 10,
        "map_id": map_id - (1 << 64),  # LCM int64 carries the unsigned bits
        "health": k % 4,
        "dynamic_share": f32((k % 101) / 100.0),
        "reprojection_rms_px": f32(0.5 + f32((k % 13) / 7.0)),
        "conditioning": f32(1.0 / (k + 2)),
        "health_causes": int16((k * 0x2F1B) & 0xFFFF),  # LCM int16 carries the unsigned bits
        "mask_age_s": math.inf if k % 3 == 0 else -1.0 if k % 3 == 1 else f32(f32(0.1) * k),
        # float division, correctly rounded: the double quotient rounded once to single precision
        "covariance": [f32((-1.0 if i % 2 else 1.0) * (k + 1) / (3 * i + 7)) for i in range(21)],
    }


seen = set()
problems = []
n_status = 0


def on_pose(channel, data):
    m = pose_t.decode(data)
    want = expected_pose(m.frame_counter)
    def same(a, b):
        return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))

    for field, value in want.items():
        got = getattr(m, field)
        if (len(got) != len(value) or not all(map(same, got, value))) if isinstance(value, list) else not same(got, value):
            problems.append(f"pose {m.frame_counter}: {field} = {got!r}, expected {value!r}")
    if m.frame_counter in seen:
        problems.append(f"pose {m.frame_counter} twice")
    seen.add(m.frame_counter)


def on_status(channel, data):
    global n_status
    m = status_t.decode(data)
    n_status += 1
    j = m.frames_received // 30
    if m.num_threads != len(m.threads) or [t.name for t in m.threads] != ["tracking", "local_mapping", "publisher"]:
        problems.append(f"status {j}: threads {[t.name for t in m.threads]}")
    if m.uptime_s != 0.25 * j + 1.0 / 3.0 or m.queues[1].dropped != 0xFFFFFFFFFFFFFFF0 - (1 << 64):
        problems.append(f"status {j}: fields differ")
    if m.schema_version != 3 or m.tracking_state != j % 6 or m.health != j % 4:
        problems.append(f"status {j}: schema {m.schema_version}, state {m.tracking_state}, health {m.health}")
    if m.health_causes != int16(0xFFFF - j) or m.mask_age_s != (math.inf if j % 2 else 0.25 * j):
        problems.append(f"status {j}: health causes {m.health_causes}, masks' age {m.mask_age_s}")


lc = lcm.LCM(url)
# LCM drops messages beyond a subscription's queue capacity (default 30) when the
# handler falls behind; a slow Python handler on a busy machine needs more.
for channel, handler in (("STILLPOINT_POSE", on_pose), ("STILLPOINT_STATUS", on_status)):
    lc.subscribe(channel + suffix, handler).set_queue_capacity(4096)
if ready:
    open(ready, "w").write("ready\n")
deadline = time.monotonic() + 20
while (len(seen) < count or n_status < statuses) and time.monotonic() < deadline:
    try:
        lc.handle_timeout(100)
    except Exception:  # file:// provider at the end of the log
        break
missing = count - len(seen & set(range(1, count + 1)))
print(f"python received={len(seen)} missing={missing} statuses={n_status} problems={len(problems)}")
if missing:
    print("  missing: " + " ".join(str(k) for k in sorted(set(range(1, count + 1)) - seen)[:20]))
for p in problems[:5]:
    print("  " + p)
sys.exit(0 if missing == 0 and n_status == statuses and not problems else 1)
