"""Crash-safe session spill: what transfer_align_node receives, appended to disk as it arrives.

Layout of a spill directory::

    spill.json              {"format": "dpos-spill", "version": 1, "session_id": ..., "topics": {topic: msgtype},
                             "custom_data": {...}}   (rewritten atomically when a topic appears)
    <n>.log                 one per topic: records  int64 t_ns | uint32 size | size bytes of CDR

Each record is written with a single ``os.write`` on an ``O_APPEND`` descriptor, so a process that
dies (killed, crashed) loses nothing it received: the bytes are in the kernel's page cache
(``fsync_every`` also forces them to the device, for power loss).  A record cut short by a machine
crash is detected on reading, reported, and dropped; everything before it is kept.  Memory stays
bounded: nothing is kept in the process.

:func:`read_spill` returns the same ``{topic: (msgtype, times, blobs)}`` as :func:`dpos_ros.io.bag.read_raw`,
so ``dpos-process`` on a spill runs exactly the code that processes a bag.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

FORMAT = "dpos-spill"
VERSION = 1
_HEAD = struct.Struct("<qI")


class SpillWriter:
    def __init__(self, directory: Path, session_id: str, custom_data: dict[str, str] | None = None, fsync_every: int = 0) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.session_id = session_id
        self.custom = dict(custom_data or {})
        self.topics: dict[str, str] = {}
        self._fds: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.last_t_ns: dict[str, int] = {}
        self._fsync_every = int(fsync_every)
        self._since_sync = 0
        self._write_meta()

    def _write_meta(self) -> None:
        meta = {"format": FORMAT, "version": VERSION, "session_id": self.session_id,
                "topics": {t: {"msgtype": m, "file": f"{i}.log"} for i, (t, m) in enumerate(self.topics.items())},
                "custom_data": self.custom}
        tmp = self.dir / "spill.json.tmp"
        tmp.write_text(json.dumps(meta, indent=1))
        os.replace(tmp, self.dir / "spill.json")

    def set_custom(self, key: str, value: str) -> None:
        self.custom[key] = value
        self._write_meta()

    def write(self, topic: str, msgtype: str, t_ns: int, data: bytes) -> None:
        fd = self._fds.get(topic)
        if fd is None:
            self.topics[topic] = msgtype
            self._write_meta()
            path = self.dir / f"{list(self.topics).index(topic)}.log"
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            self._fds[topic] = fd
            self.counts[topic] = 0
        os.write(fd, _HEAD.pack(int(t_ns), len(data)) + data)
        self.counts[topic] += 1
        self.last_t_ns[topic] = max(self.last_t_ns.get(topic, int(t_ns)), int(t_ns))
        if self._fsync_every:
            self._since_sync += 1
            if self._since_sync >= self._fsync_every:
                os.fsync(fd)
                self._since_sync = 0

    def close(self) -> None:
        for fd in self._fds.values():
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        self._fds.clear()


def is_spill(path: Path) -> bool:
    return (Path(path) / "spill.json").is_file()


def read_spill(path: Path) -> tuple[dict[str, tuple[str, list[int], list[bytes]]], dict[str, str], str, list[str]]:
    """``(raw, custom_data, session_id, warnings)`` of a spill directory (see module docstring)."""
    path = Path(path)
    meta = json.loads((path / "spill.json").read_text())
    if meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise ValueError(f"{path}: not a {FORMAT} v{VERSION} directory")
    raw: dict[str, tuple[str, list[int], list[bytes]]] = {}
    warnings: list[str] = []
    for topic, info in meta["topics"].items():
        f = path / info["file"]
        buf = f.read_bytes() if f.is_file() else b""
        times, blobs = [], []
        o = 0
        while o + _HEAD.size <= len(buf):
            t, n = _HEAD.unpack_from(buf, o)
            if o + _HEAD.size + n > len(buf):
                break
            blobs.append(buf[o + _HEAD.size : o + _HEAD.size + n])
            times.append(t)
            o += _HEAD.size + n
        if o != len(buf):
            warnings.append(f"{topic}: the last record of {f.name} is cut short ({len(buf) - o} bytes, a crash while writing); dropped")
        raw[topic] = (info["msgtype"], times, blobs)
    return raw, dict(meta.get("custom_data") or {}), str(meta.get("session_id", path.name)), warnings
