"""Crash-safe session spill: what transfer_align_node receives, appended to disk as it arrives.

Layout of a spill directory::

    spill.json              {"format": "dpos-spill", "version": 1, "session_id": ..., "topics": {topic: msgtype},
                             "custom_data": {...}}   (rewritten atomically when a topic appears)
    <n>.log                 one per topic: records  int64 t_ns | uint32 size | size bytes of CDR

Each record is written with a single ``os.write`` on an ``O_APPEND`` descriptor, so a process that
dies (killed, crashed) loses nothing it received: the bytes are in the kernel's page cache
(``fsync_every`` also forces them to the device, for power loss).  A record cut short by a machine
crash is detected on reading, reported, and dropped; everything before it is kept.  A record
whose size field is corrupt costs that record only: the reader resynchronizes on the next offset
where two plausible records (sizes within the file and a bound, data that begin as a serialized
message does) follow each other, and reports the bytes it skipped.  Memory stays
bounded: nothing is kept in the process.

:func:`read_spill` returns the same ``{topic: RawTopic(msgtype, times, blobs)}`` as :func:`dpos_ros.io.bag.read_raw`,
so ``dpos-process`` on a spill runs exactly the code that processes a bag.

Late messages
    Messages of a session that arrive after transfer_align_node closed it (a device that lagged
    beyond ``finalize_timeout_s``) go into the spill of the same format in ``<spill>/late/``.
    :func:`read_spill` merges them into their topics (in stamp order) and says how many it took,
    so a re-run (``dpos-process <spill>``) uses them.

Disk faults
    A write that fails (ENOSPC, EIO, EROFS, ...) leaves the log as it was: a record is either
    written whole or the file is cut back to its previous length, and the ``OSError`` is raised.
    :class:`BufferedSpill` keeps such records in memory, within a bound, in arrival order, and
    writes them out when the disk takes them again (every later write retries).
"""

from __future__ import annotations

import errno
import json
import os
import struct
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_ros.io.messages import Messages, RawTopic

FORMAT = "dpos-spill"
VERSION = 1
_HEAD = struct.Struct("<qI")
#: sub-directory of a spill holding the messages that arrived after the session was closed
LATE_DIR = "late"


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
        rec = _HEAD.pack(int(t_ns), len(data)) + data
        size = os.fstat(fd).st_size
        try:
            n = os.write(fd, rec)
            if n != len(rec):  # a short write: the device is full
                raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} (wrote {n} of {len(rec)} bytes)")
        except OSError:
            try:  # no partial record: the log stays readable to its last whole record
                os.ftruncate(fd, size)
            except OSError:
                pass  # the reader drops a cut-short last record (and says so)
            raise
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


def read_spill(path: Path, include_late: bool = True, keep: Callable[[str], bool] | None = None,
               skipped: dict[str, int] | None = None) -> tuple[dict[str, RawTopic], dict[str, str], str, list[str]]:
    """``(raw, custom_data, session_id, warnings)`` of a spill directory (see module docstring);
    the late messages of ``<path>/late/`` merged into their topics in stamp order (unless
    ``include_late`` is False: transfer_align_node's own products are made without them).
    ``keep``: read only the topics it accepts (the others' files are not opened).  ``skipped``:
    filled with the corrupt bytes skipped per log (``topic``, ``late/topic``; only logs with some),
    what :class:`LogBlocks` counts in :attr:`LogBlocks.skipped` (status.json ``data_lost``)."""
    path = Path(path)
    raw, custom, sid, warnings = _read_one(path, keep, skipped)
    late_dir = path / LATE_DIR
    if include_late and is_spill(late_dir):
        late_skipped: dict[str, int] = {}
        late, _, _, late_warnings = _read_one(late_dir, keep, late_skipped)
        if skipped is not None:
            skipped.update({f"{LATE_DIR}/{t}": n for t, n in late_skipped.items()})
        warnings += [f"{LATE_DIR}/{w}" for w in late_warnings]
        for topic, (msgtype, times, blobs) in late.items():
            if not times:
                continue
            warnings.append(late_note(topic, len(times)))
            if topic not in raw:
                raw[topic] = RawTopic(msgtype, times, blobs)
                continue
            t_all = np.array(raw[topic].times + times, dtype=np.int64)
            order = np.argsort(t_all, kind="stable")
            raw[topic] = RawTopic(msgtype, t_all[order].tolist(), Messages.concat([raw[topic].blobs, blobs]).take(order))
    return raw, custom, sid, warnings


def late_note(topic: str, n: int) -> str:
    """The warning of :func:`read_spill` about ``n`` late messages of ``topic`` merged in."""
    return f"{topic}: {n} message(s) arrived after the session was closed (late); included from {LATE_DIR}/"


#: the largest record a reader believes (a message of transfer_align_node's topics is far smaller)
MAX_RECORD_BYTES = 2**26


def _cdr(raw: bytes | NDArray[np.uint8], o: int) -> bool:
    """Whether the 4 bytes at ``o`` are a serialized ROS message's CDR encapsulation header
    (representation 0x0000-0x0003: CDR or PL_CDR, big or little endian; options 0, or padding 1-3)."""
    return bool(raw[o] == 0 and raw[o + 1] < 4 and raw[o + 2] == 0 and raw[o + 3] < 4)


def _plausible(raw: bytes, o: int, final: bool, cdr: bool = True) -> bool | None:
    """Whether a record can start at ``o`` of ``raw``: its size within :data:`MAX_RECORD_BYTES` and the
    buffer, its data a serialized message (:func:`_cdr`), and the data of the record after it too
    (or the end of a ``final`` buffer right after it).  None: cannot tell yet (the buffer ends first, not
    ``final``).  (A record's stamp is what its message said: any value.)  ``cdr`` False: a log whose
    first record is not a serialized message (sizes alone are checked)."""
    h = _HEAD.size
    if o + h + 4 > len(raw):
        return False if final else None
    n_i = _HEAD.unpack_from(raw, o)[1]
    if not (4 if cdr else 0) <= n_i <= MAX_RECORD_BYTES or (cdr and not _cdr(raw, o + h)):
        return False
    nxt = o + h + n_i
    if nxt + h + 4 > len(raw):
        if nxt == len(raw):
            return True if final else None
        return False if final else None
    return not cdr or _cdr(raw, nxt + h)  # (the next one's size is checked in its turn)


def _chain(raw: bytes, o: int, final: bool, cdr: bool, k: int = 3) -> bool | None:
    """:func:`_plausible` for ``k`` records in a row from ``o`` (fewer when the ``final`` buffer
    ends right after them; None when a buffer that is not ``final`` ends first)."""
    h = _HEAD.size
    for _ in range(k):
        ok = _plausible(raw, o, final, cdr)
        if ok is not True:
            return ok
        o += h + _HEAD.unpack_from(raw, o)[1]
        if o == len(raw):
            return True if final else None
    return True


def _records(buf: NDArray[np.uint8], final: bool = True, skipped: list[tuple[int, int]] | None = None,
             cdr: bool | None = None) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], int]:
    """Records ``int64 t_ns | uint32 size | data`` back to back in ``buf``: ``(t_ns, data offset,
    data size, end of the last whole record)``, each (N,).  One vectorized pass when every record
    has the size of the first (the usual case: fixed frame names), else a loop over the records.
    A record whose size does not lead to another plausible record (:func:`_plausible`: a corrupt
    size; a log whose first record is a serialized message has every record's data checked to
    begin as one) is skipped: the reading resynchronizes on the next offset where two plausible records
    follow each other, and ``(offset, bytes skipped)`` is appended to ``skipped``.  ``final``: the
    buffer ends where the file does (else a record it cuts is left for the next buffer); ``cdr``:
    whether the log holds serialized messages (None: :func:`is_cdr_log` of ``buf``, the file's start)."""
    h = _HEAD.size
    if buf.size < h:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), 0
    if cdr is None:
        cdr = is_cdr_log(buf)
    size0 = int(buf[8:12].view("<u4")[0])
    step = h + size0
    n = buf.size // step
    if n and size0 <= MAX_RECORD_BYTES:
        heads = buf[: n * step].reshape(n, step)[:, :h]
        sizes = np.ascontiguousarray(heads[:, 8:12]).view("<u4")[:, 0]
        t = np.ascontiguousarray(heads[:, :8]).view("<i8")[:, 0].astype(np.int64)
        rest = buf[n * step :]
        e = buf[: n * step].reshape(n, step)[:, h : h + 4] if cdr and size0 >= 4 else np.zeros((n, 4), dtype=np.uint8)
        if np.all(sizes == size0) and np.all((e[:, 0] == 0) & (e[:, 1] < 4) & (e[:, 2] == 0) & (e[:, 3] < 4)):
            starts = np.arange(n, dtype=np.int64) * step + h
            leads = not (cdr and rest.size >= h + 4 and not _cdr(rest, h))  # (else the loop below finds the bad size)
            if cdr and 0 < rest.size < h + 4 and not final:
                n -= 1  # (the next buffer shows where the last one leads)
                t, starts = t[:n], starts[:n]
            if leads and (rest.size < h or h + int(rest[8:12].view("<u4")[0]) > rest.size):  # nothing whole after them
                if rest.size < h or int(rest[8:12].view("<u4")[0]) <= MAX_RECORD_BYTES or not final:
                    return t, starts, np.full(n, size0, dtype=np.int64), n * step
    times: list[int] = []
    starts_l: list[int] = []
    sizes_l: list[int] = []
    raw = buf.tobytes()
    o = 0
    while o + h <= len(raw):
        ok = _plausible(raw, o, final, cdr)
        if ok is None:
            break  # the next buffer tells
        if not ok:
            if not cdr:
                break  # (no check to resynchronize on: what follows is reported cut short)
            if final and o + h <= len(raw) and _HEAD.unpack_from(raw, o)[1] <= MAX_RECORD_BYTES \
                    and o + h + _HEAD.unpack_from(raw, o)[1] > len(raw) and not _resync_after(raw, o, cdr):
                break  # the last record cut short (a crash while writing): dropped by the caller
            p = _resync(buf, raw, o, final, cdr, sizes_l[-1] if sizes_l else None)
            if p + h > len(raw) or _chain(raw, p, final, cdr) is None:
                if not final:
                    break
                if skipped is not None:
                    skipped.append((o, len(raw) - o))
                return (np.array(times, dtype=np.int64), np.array(starts_l, dtype=np.int64),
                        np.array(sizes_l, dtype=np.int64), len(raw))
            if skipped is not None:
                skipped.append((o, p - o))
            o = p
            continue
        t_i, n_i = _HEAD.unpack_from(raw, o)
        times.append(t_i)
        starts_l.append(o + h)
        sizes_l.append(n_i)
        o += h + n_i
    return np.array(times, dtype=np.int64), np.array(starts_l, dtype=np.int64), np.array(sizes_l, dtype=np.int64), o


def is_cdr_log(buf: NDArray[np.uint8]) -> bool:
    """Whether the log starting with ``buf`` holds serialized messages (its first two records' data
    begin as one does: every log the node writes), so that a corrupt size can be resynchronized on."""
    h = _HEAD.size
    if buf.size < h:
        return False
    n0 = int(buf[8:12].view("<u4")[0])
    return bool(_plausible(buf[: h + n0 + h + 4].tobytes(), 0, True))


def _resync(buf: NDArray[np.uint8], raw: bytes, o: int, final: bool, cdr: bool, usual: int | None = None) -> int:
    """Where the reading goes on after a corrupt record at ``o`` (``len(raw)``: nowhere): the record
    after it if it had the ``usual`` size and 4 plausible records follow from there (:func:`_chain`:
    a size field alone was damaged), else the first offset after ``o`` with 4 (the candidates: a
    serialized message's first bytes 12 bytes on, found at once)."""
    h = _HEAD.size
    if usual is not None and cdr and _chain(raw, o + h + usual, final, cdr, 4) is not False:
        return o + h + usual
    if cdr:
        d = buf[o + 1 + h :]
        m = d.size - 3
        cand = np.nonzero((d[:m] == 0) & (d[1 : m + 1] < 4) & (d[2 : m + 2] == 0) & (d[3 : m + 3] < 4))[0] + o + 1 if m > 0 \
            else np.zeros(0, dtype=np.int64)
    else:  # (sizes alone: not enough to resynchronize on)
        return len(raw)
    for p in cand.tolist():
        if _chain(raw, p, final, cdr, 4) is not False:
            return int(p)
    return len(raw)


def _resync_after(raw: bytes, o: int, cdr: bool) -> bool:
    """Whether a plausible pair of records follows offset ``o`` (then the record at ``o`` is corrupt, not cut short)."""
    return _resync(np.frombuffer(raw, dtype=np.uint8), raw, o, True, cdr) < len(raw)


def skipped_warning(topic: str, file: Path, skipped: list[tuple[int, int]]) -> str:
    """The warning about corrupt bytes of ``file`` skipped (``(offset, bytes)`` each) while reading."""
    where = ", ".join(f"{n} at byte {o}" for o, n in skipped[:5]) + (" ..." if len(skipped) > 5 else "")
    return (f"{topic}: {sum(n for _, n in skipped)} corrupt byte(s) of {file.name} skipped ({where}: a record size that leads "
            f"to no valid record); the reading resynchronized on the next valid record, the others are kept")


def spill_meta(path: Path) -> tuple[dict[str, tuple[str, Path]], dict[str, str], str]:
    """``({topic: (msgtype, log file)}, custom_data, session_id)`` of the spill directory ``path``
    (its ``spill.json``, topics in the order they appeared); ValueError when it is not a spill of
    this format and version, OSError when it cannot be read."""
    path = Path(path)
    try:
        meta = json.loads((path / "spill.json").read_text())
    except UnicodeDecodeError as e:
        raise ValueError(f"{path / 'spill.json'}: not text ({e.reason})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise ValueError(f"{path}: not a {FORMAT} v{VERSION} directory")
    where = path / "spill.json"
    entries = meta.get("topics")
    if not isinstance(entries, dict):
        raise ValueError(f"{where}: 'topics' is missing or not a mapping")
    custom = meta.get("custom_data") or {}
    if not isinstance(custom, dict):
        raise ValueError(f"{where}: 'custom_data' is not a mapping")
    topics = {}
    for topic, info in entries.items():
        if not isinstance(info, dict) or not isinstance(info.get("msgtype"), str) or not isinstance(info.get("file"), str):
            raise ValueError(f"{where}: topic {topic!r} needs a 'msgtype' and a 'file' (strings)")
        topics[str(topic)] = (info["msgtype"], _log_file(path, info["file"]))
    return topics, {str(k): str(v) for k, v in custom.items()}, str(meta.get("session_id", path.name))


def _log_file(spill_dir: Path, name: str) -> Path:
    """``spill_dir/name`` for the ``file`` of a topic in spill.json: a plain file name (no separator,
    not hidden) whose resolved path is directly in the spill (no symbolic link out of it);
    ValueError otherwise: a spill.json never makes a reader open a file outside its spill."""
    f = spill_dir / name
    if not name or Path(name).name != name or name.startswith(".") or "\\" in name or "\0" in name:
        raise ValueError(f"{spill_dir / 'spill.json'}: topic log file {name!r} is not a file name in the spill")
    if f.resolve().parent != spill_dir.resolve():
        raise ValueError(f"{spill_dir / 'spill.json'}: topic log file {name!r} resolves outside the spill ({f.resolve()})")
    return f


def cut_short_warning(topic: str, file: Path, n_bytes: int) -> str:
    """The warning about a last record of ``file`` cut short by ``n_bytes`` (a crash while writing)."""
    return f"{topic}: the last record of {file.name} is cut short ({n_bytes} bytes, a crash while writing); dropped"


class _Offset(list[tuple[int, int]]):
    """A list whose appended ``(offset, n)`` go to ``target`` with ``base`` added to the offset."""

    def __init__(self, target: list[tuple[int, int]], base: int) -> None:
        super().__init__()
        self.target, self.base = target, base

    def append(self, item: tuple[int, int]) -> None:
        self.target.append((item[0] + self.base, item[1]))


class LogBlocks:
    """The records of one topic's ``<n>.log`` read a block of about ``block_bytes`` at a time
    (a long session's log is never held whole): iterating gives ``(t_ns (N,), Messages)``
    per block, the records in file order, exactly those :func:`read_spill` reads.  A record longer
    than a block is read whole (the block grows).  After the iteration :attr:`cut_short` is the
    size of a last record cut short (a crash while writing: dropped, 0 when none),
    :attr:`skipped` the corrupt bytes skipped (:func:`_records`) and :attr:`count` the records read.  A missing file has no record."""

    def __init__(self, file: Path, block_bytes: int = 2**24) -> None:
        if block_bytes < 1:
            raise ValueError(f"block_bytes must be >= 1, got {block_bytes}")
        self.file = Path(file)
        self.block_bytes = int(block_bytes)
        self.cut_short = 0
        self.count = 0
        self.skipped: list[tuple[int, int]] = []  # (file offset, bytes) of corrupt bytes skipped

    def skipped_at(self, base: int) -> _Offset:
        """A list that appends to :attr:`skipped` with ``base`` added to each offset."""
        return _Offset(self.skipped, base)

    def __iter__(self) -> Iterator[tuple[NDArray[np.int64], Messages]]:
        self.cut_short = self.count = 0
        self.skipped = []
        o_file = 0  # the file offset of ``buf``'s start
        cdr: bool | None = None
        if not self.file.is_file():
            return
        tail = np.zeros(0, dtype=np.uint8)
        want = self.block_bytes
        with self.file.open("rb") as f:
            while True:
                data = np.frombuffer(f.read(want), dtype=np.uint8)
                eof = data.size < want  # (a regular file reads short at its end only)
                buf = np.concatenate([tail, data]) if tail.size else data
                if cdr is None and (eof or buf.size >= _HEAD.size and buf.size >= 2 * (_HEAD.size + 4) + int(buf[8:12].view("<u4")[0])):
                    cdr = is_cdr_log(buf)  # (from the file's start, once it holds the first record and the next one's head)
                t, starts, sizes, o = _records(buf, eof, self.skipped_at(o_file), bool(cdr))
                o_file += o
                tail = buf[o:]
                if t.size:
                    self.count += t.size
                    yield t, Messages.pack(buf, starts, sizes)
                if eof:
                    break
                want = self.block_bytes if t.size else 2 * want  # no whole record yet: one longer than a block
        self.cut_short = int(tail.size)


def _read_one(path: Path, keep: Callable[[str], bool] | None = None, skipped_bytes: dict[str, int] | None = None,
              ) -> tuple[dict[str, RawTopic], dict[str, str], str, list[str]]:
    topics, custom, sid = spill_meta(path)
    raw: dict[str, RawTopic] = {}
    warnings: list[str] = []
    for topic, (msgtype, f) in topics.items():
        if keep is not None and not keep(topic):
            continue
        buf = np.fromfile(f, dtype=np.uint8) if f.is_file() else np.zeros(0, dtype=np.uint8)
        skipped: list[tuple[int, int]] = []
        t, starts, sizes, o = _records(buf, True, skipped)
        if skipped:
            warnings.append(skipped_warning(topic, f, skipped))
            if skipped_bytes is not None:
                skipped_bytes[topic] = sum(n for _, n in skipped)
        if o != buf.size:
            warnings.append(cut_short_warning(topic, f, buf.size - o))
        raw[topic] = RawTopic(msgtype, t.tolist(), Messages.pack(buf, starts, sizes))
    return raw, custom, sid, warnings


class BufferedSpill:
    """A :class:`SpillWriter` that survives disk faults (module docstring, "Disk faults").

    ``make_writer`` creates the writer (the spill directory) when the first record is written,
    and again while the disk refuses it.  :meth:`write` first writes out what is held in memory,
    then the new record; a record the disk refuses (``OSError``) is held in memory in arrival
    order, up to ``max_bytes`` of message data.  Past that bound a record is lost: counted in
    :attr:`lost` (never silently).  While anything is held, the disk is tried again at most every
    ``retry_s``.  :attr:`error` is the last disk error while anything is held (None once
    everything is on disk).
    """

    def __init__(self, make_writer: Callable[[], SpillWriter], max_bytes: int, retry_s: float = 1.0) -> None:
        self._make_writer = make_writer
        self.writer: SpillWriter | None = None
        self.max_bytes = int(max_bytes)
        self.retry_s = float(retry_s)
        self._next_try = 0.0
        self._held: deque[tuple[str, str, int, bytes]] = deque()
        self.held_bytes = 0
        self.lost = 0
        self.error: OSError | None = None
        self.disk_errors = 0  # writes the disk refused (each retry counts)

    @property
    def held(self) -> int:
        """Records held in memory, waiting for the disk."""
        return len(self._held)

    def _write(self, topic: str, msgtype: str, t_ns: int, data: bytes) -> None:
        if self.writer is None:
            self.writer = self._make_writer()
        self.writer.write(topic, msgtype, t_ns, data)

    def _refused(self, e: OSError) -> None:
        self.error = e
        self.disk_errors += 1
        self._next_try = time.monotonic() + self.retry_s

    def flush(self) -> bool:
        """Write out what is held; True when nothing is held any more."""
        while self._held:
            try:
                self._write(*self._held[0])
            except OSError as e:
                self._refused(e)
                return False
            _, _, _, data = self._held.popleft()
            self.held_bytes -= len(data)
        self.error = None
        return True

    def write(self, topic: str, msgtype: str, t_ns: int, data: bytes) -> None:
        if (not self._held or time.monotonic() >= self._next_try) and self.flush():
            try:
                self._write(topic, msgtype, t_ns, data)
                return
            except OSError as e:
                self._refused(e)
        if self.held_bytes + len(data) > self.max_bytes:
            self.lost += 1
            return
        self._held.append((topic, msgtype, int(t_ns), bytes(data)))
        self.held_bytes += len(data)

    def close(self) -> None:
        """Close the writer (what is still held stays held: call :meth:`flush` first)."""
        if self.writer is not None:
            self.writer.close()
