"""The main system's IMU and GNSS from a recording (a bag): what ``dpos-ifa`` and
``dpos-process --master-reference`` re-run the in-flight alignment on."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dpos_core.errors import InputError
from dpos_core.series import GnssSeries, ImuSeries
from dpos_core.units import DEG
from dpos_ros.io.bag import bag_info, read_raw, typestore

#: the product's topics (a recorded live graph) and real drivers' (``dpos-import``)
PRODUCT_TOPICS = ("/master/imu", "/gnss/fix", "/gnss/vel")
DRIVER_TOPICS = ("/imu/data", "/fix", "/vel")


def deserialize(raws: Sequence[bytes], msgtype: str) -> list[Any]:
    ts = typestore()
    return [ts.deserialize_cdr(r, msgtype) for r in raws]


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def read_recording(bag: Path, topics: tuple[str, str, str], rotation: np.ndarray) -> tuple[int, ImuSeries, GnssSeries, list[str]]:
    """``(origin_ns, imu, gnss, notes)`` of a bag: IMU in body axes (``rotation`` applied), fixes
    paired with their velocity (same stamp within 1 ms), times in s after the first IMU sample.
    Samples and fixes that are not finite or not after the previous one are dropped and noted."""
    notes: list[str] = []
    try:
        raw = read_raw(bag, topics, notes)  # a bag without metadata is recovered (noted)
    except Exception as e:  # rosbags raises its own errors for a missing or unreadable bag
        raise InputError(f"{bag}: cannot read the bag ({type(e).__name__}: {e})") from None
    missing = [t for t in topics if t not in raw]
    if missing:
        raise InputError(f"{bag}: no topic {missing} (has: {sorted(raw)}); name them with --imu-topic / --fix-topic / --vel-topic")
    imus = deserialize(raw[topics[0]][2], raw[topics[0]][0])
    t = np.array([stamp_ns(m) for m in imus], dtype=np.int64)
    om = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in imus]) @ rotation.T
    f = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imus]) @ rotation.T
    keep = np.isfinite(om).all(axis=1) & np.isfinite(f).all(axis=1)
    last = np.iinfo(np.int64).min
    for i in range(t.size):
        if keep[i] and t[i] > last:
            last = t[i]
        elif keep[i]:
            keep[i] = False
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} IMU samples dropped (not finite, or stamp not after the previous)")
    t, om, f = t[keep], om[keep], f[keep]
    if t.size < 2:
        raise InputError(f"{bag}: fewer than 2 usable IMU samples on {topics[0]}")
    origin = int(t[0])
    fixes = {stamp_ns(m): m for m in deserialize(raw[topics[1]][2], raw[topics[1]][0])}
    vels = {stamp_ns(m): m for m in deserialize(raw[topics[2]][2], raw[topics[2]][0])}
    vt = np.array(sorted(vels), dtype=np.int64)
    rows = []
    for tf in sorted(fixes):
        m = fixes[tf]
        k = int(np.argmin(np.abs(vt - tf))) if vt.size else -1
        if k < 0 or abs(int(vt[k]) - tf) > 1_000_000 or m.status.status < 0:
            continue
        v = vels[int(vt[k])]
        pc = np.asarray(m.position_covariance, dtype=float).reshape(3, 3)
        vc = np.asarray(v.twist.covariance, dtype=float).reshape(6, 6)[:3, :3]
        row = [(tf - origin) * 1e-9, m.latitude * DEG, m.longitude * DEG, m.altitude, *np.sqrt(np.maximum(np.diag(pc), 0.0)),
               v.twist.twist.linear.x, v.twist.twist.linear.y, v.twist.twist.linear.z, *np.sqrt(np.maximum(np.diag(vc), 0.0))]
        if np.all(np.isfinite(row)):
            rows.append(row)
    dropped = len(fixes) - len(rows)
    if dropped:
        notes.append(f"{dropped} fixes not used (no velocity within 1 ms, no fix status, or not finite)")
    if not rows:
        raise InputError(f"{bag}: no usable fix with a velocity on {topics[1]} / {topics[2]}")
    a = np.array(rows)
    gnss = GnssSeries(a[:, 0], a[:, 1:4], a[:, 4:7], a[:, 7:10], a[:, 10:13])
    return origin, ImuSeries((t - origin) * 1e-9, om, f), gnss, notes


def _topics(bag: Path) -> set[str]:
    """Topic names of a bag (empty when it cannot be read: read_recording then says why)."""
    try:
        return {t["topic_metadata"]["name"] for t in bag_info(bag)["topics_with_message_count"]}
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return set()
