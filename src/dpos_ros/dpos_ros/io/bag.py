"""rosbag2 (MCAP) writing and reading through rosbags (no ROS installation needed).

Bags are written with zstd chunk compression (rosbags ``CompressionMode.STORAGE``), messages in
stamp order, log time = ``header.stamp``.  Reading returns raw CDR per topic so the vectorized
decoder of :mod:`dpos_ros.contract.cdr` (or ``rclpy.serialization``) can be used.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore

from dpos_ros.io.streams import TopicStream, merged_order

ROSBAG2_VERSION = 9


def typestore():
    return get_typestore(Stores.ROS2_JAZZY)


def write_streams(
    path: Path,
    streams: list[TopicStream],
    progress: Callable[[int, int], None] | None = None,
    custom_data: dict[str, str] | None = None,
) -> int:
    """Write the streams to a new rosbag2 directory ``path``; returns the message count.

    ``custom_data`` goes into the rosbag2 metadata (``dpos.*`` keys describe the session)."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists: choose a new output directory (rosbag2 writes a new one)")
    ts = typestore()
    t, si, mi = merged_order(streams)
    n = len(t)
    w = Writer(path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in (custom_data or {}).items():
        w.set_custom_data(key, value)
    w.open()
    try:
        conns = [w.add_connection(s.topic, s.msgtype, typestore=ts) for s in streams]
        step = max(1, n // 200)
        for k in range(n):
            s = streams[si[k]]
            w.write(conns[si[k]], int(t[k]), s.message(int(mi[k])))
            if progress is not None and k % step == 0:
                progress(k, n)
    finally:
        w.close()
    if progress is not None:
        progress(n, n)
    return n


def read_raw(path: Path, topics: Iterable[str] | None = None) -> dict[str, tuple[str, list[int], list[bytes]]]:
    """Every message of a bag as ``{topic: (msgtype, log times [ns], raw CDR)}``, in log-time order."""
    from rosbags.highlevel import AnyReader

    wanted = None if topics is None else set(topics)
    out: dict[str, tuple[str, list[int], list[bytes]]] = {}
    times: dict[str, list[int]] = defaultdict(list)
    data: dict[str, list[bytes]] = defaultdict(list)
    types: dict[str, str] = {}
    with AnyReader([Path(path)], default_typestore=typestore()) as r:
        conns = [c for c in r.connections if wanted is None or c.topic in wanted]
        for c in conns:
            types[c.topic] = c.msgtype
        for c, t, raw in r.messages(connections=conns):
            times[c.topic].append(t)
            data[c.topic].append(bytes(raw))
    for topic, mt in types.items():
        out[topic] = (mt, times[topic], data[topic])
    return out


def rows(blobs: list[bytes]) -> np.ndarray:
    """Fixed-size CDR messages as an (N, size) uint8 array (for :func:`dpos_ros.contract.cdr.decode`)."""
    if not blobs:
        return np.zeros((0, 0), dtype=np.uint8)
    size = len(blobs[0])
    if any(len(b) != size for b in blobs):
        raise ValueError("messages of different sizes: frame names change within the topic")
    return np.frombuffer(b"".join(blobs), dtype=np.uint8).reshape(len(blobs), size)


def custom_data(path: Path) -> dict[str, str]:
    """The rosbag2 metadata's ``custom_data`` (empty for bags without it)."""
    import yaml

    meta = Path(path) / "metadata.yaml"
    if not meta.is_file():
        return {}
    info = (yaml.safe_load(meta.read_text()) or {}).get("rosbag2_bagfile_information", {})
    return {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}
