"""Private fast path of :mod:`dpos_ros.io.bag`: reading and writing rosbag2 MCAP files chunk by
chunk, with no Python object per message.

Reading (:func:`read`) takes the chunk indexes from the file's summary, decompresses each chunk
that holds a wanted channel, finds its Message records with a numba scan
(:func:`dpos_ros.io._bag_kernel.scan_messages`) and gathers each topic's payloads into one
buffer (:class:`dpos_ros.io.messages.Messages`, sized from the summary's statistics; the chunk
and its decompressed records go through buffers reused from chunk to chunk, as fresh memory is
paid a page fault per page).  Per topic, messages come out in the order of
rosbags' ``AnyReader.messages``: by log time, ties in file order.  A file this path does not
handle (no summary or chunk index, an unknown compression, one topic on several channels)
gives None, and the caller falls back to rosbags.  A file whose summary cannot be trusted
(:func:`damage`) is read record by record by :mod:`dpos_ros.io._mcap_recover`, which decodes a
chunk as this reader does (:func:`_chunk_data`).

Writing (:func:`write`) lays out the file as rosbags' MCAP writer does (rosbag2 ``version`` 9,
profile ``ros2``): the schema and channel records at the start of the first chunk, chunks closed
after the record that takes their uncompressed size over 1 MiB, zstd chunk compression, a
message index per channel after each chunk, the ``rosbag2`` metadata record, and a summary with
schemas, channels, chunk indexes, the metadata index, statistics and summary offsets; then
``metadata.yaml`` with the same fields.  Message records are filled by a numba kernel
(:func:`dpos_ros.io._bag_kernel.fill_messages`); chunks are compressed on COMPRESS_THREADS threads
while the next ones are built, and written in order.
"""

from __future__ import annotations

import struct
import threading
import zlib
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from io import BufferedReader, StringIO
from pathlib import Path
from typing import BinaryIO

import numpy as np
import zstandard
from lz4.frame import LZ4FrameDecompressor  # type: ignore[import-untyped]  # (rosbags' dependency)
from numpy.typing import NDArray
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from dpos_core.errors import BagDamaged as Damaged  # (the file's layout cannot be trusted: read it with scan)
from dpos_ros.io import _bag_kernel as K
from dpos_ros.io.messages import Messages, RawTopic

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX = 0x07, 0x08, 0x0B, 0x0C, 0x0D
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F
#: a chunk is closed after the record that takes its uncompressed size over this (rosbags' MCAP writer)
CHUNK_SIZE = 2**20
#: zstd level of the chunks.  rosbags' ``zstd.compress`` takes 3; the fast level -1 compresses
#: these messages 1.4-1.6x faster than level 1 and 2x faster than 3, for 1.5 % and 3.5 % more
#: bytes (CPU of one process on paper_wing's
#: chunks: antenna poses 495-565 MB/s at -1, 333-353 at 1, 234-271 at 3, ratio 2.85 / 2.89 / 2.95;
#: the recording's IMU messages 918-1182 MB/s at -1, 646-879 at 1, ratio 6.28 / 6.38), and any
#: level decodes the same
ZSTD_LEVEL = -1
#: threads compressing chunks while the next ones are built (at most twice as many chunks in flight)
COMPRESS_THREADS = 2
_FOOTER = 1 + 8 + 20


class _Cursor:
    """Little-endian fields of one record's body."""

    def __init__(self, buf: bytes | memoryview, o: int = 0) -> None:
        self.buf, self.o = buf, o

    def u16(self) -> int:
        v: int = struct.unpack_from("<H", self.buf, self.o)[0]
        self.o += 2
        return v

    def u32(self) -> int:
        v: int = struct.unpack_from("<I", self.buf, self.o)[0]
        self.o += 4
        return v

    def u64(self) -> int:
        v: int = struct.unpack_from("<Q", self.buf, self.o)[0]
        self.o += 8
        return v

    def raw(self, n: int) -> bytes:
        if self.o + n > len(self.buf):
            raise ValueError("field beyond its record")
        v = bytes(self.buf[self.o : self.o + n])
        self.o += n
        return v

    def str(self) -> str:
        return self.raw(self.u32()).decode("utf-8")


#: the largest chunk (compressed or not) a reader allocates for: a header declaring more is damage
#: (dpos and rosbag2 write chunks of about 1 MiB; rosbag2's ``chunk_size`` setting is far below this)
MAX_CHUNK_BYTES = 2**28


class Notes(list[str]):
    """Warnings about skipped chunks, with :attr:`lost_messages` the messages they held (counted
    from their message indexes); a chunk is said and counted once however often it is read."""

    def __init__(self) -> None:
        super().__init__()
        self.lost_messages = 0
        self.seen: set[tuple[str, int]] = set()  # (file, chunk start) said


@dataclass(frozen=True)
class _ChunkIndex:
    start: int  # chunk record's offset in the file
    length: int
    channels: frozenset[int]  # channels with a message index (empty: not indexed, read the chunk)
    compression: str
    compressed_size: int
    uncompressed_size: int
    t0: int = 0  # log time range of its messages [ns]
    t1: int = 0
    index_offsets: tuple[tuple[int, int], ...] = ()  # (channel, offset of its message index record)


def _records(buf: bytes | memoryview) -> list[tuple[int, _Cursor, int]]:
    """(opcode, cursor at its body, end of body) of the records back to back in ``buf``."""
    out = []
    o = 0
    while o < len(buf):
        if o + 9 > len(buf):
            raise ValueError("summary record cut short")
        op, n = struct.unpack_from("<BQ", buf, o)
        if o + 9 + n > len(buf):
            raise ValueError("summary record cut short")
        out.append((op, _Cursor(buf, o + 9), o + 9 + n))
        o += 9 + n
    return out


class _Buffers:
    """Buffers reused from chunk to chunk (the file's chunk record, its decompressed records):
    fresh memory costs a page fault per page, which on some machines is most of the reading."""

    def __init__(self) -> None:
        self.rec = bytearray()
        self.out = bytearray()
        self._dctx: object | None = None

    def read(self, f: BufferedReader, start: int, length: int) -> memoryview:
        """The ``length`` bytes of ``f`` at ``start`` (fewer at the end of the file)."""
        if len(self.rec) < length:
            self.rec = bytearray(length)
        f.seek(start)
        view = memoryview(self.rec)[:length]
        got = f.readinto(view)
        return view[: got or 0]

    def decompress(self, data: memoryview, compression: str, size: int) -> memoryview:
        """``data`` decompressed (at most ``size`` bytes read: a longer result shows as ``size + 1``)."""
        if compression == "":
            return data
        if compression == "lz4":
            return memoryview(LZ4FrameDecompressor().decompress(bytes(data), max_length=size + 1))
        if compression != "zstd":
            raise ValueError(f"unsupported chunk compression {compression!r}")

        if self._dctx is None:
            self._dctx = zstandard.ZstdDecompressor()
        assert isinstance(self._dctx, zstandard.ZstdDecompressor)
        if len(self.out) < size + 1:
            self.out = bytearray(size + 1)
        view = memoryview(self.out)[: size + 1]
        total = 0
        with self._dctx.stream_reader(data, read_across_frames=True) as r:
            while total <= size:
                k = r.readinto(view[total:])
                if not k:
                    break
                total += k
        return view[:total]


def _summary(f: BufferedReader, size: int, wanted: Callable[[str], bool] | None,
             ) -> tuple[dict[int, tuple[str, str]], list[_ChunkIndex], dict[int, int], dict[int, str]] | None:
    """The wanted channels ``{id: (topic, type)}``, the chunk indexes, the messages per channel
    and every channel's topic from the file's summary, or None when this path does not read the
    file (module docstring).  :class:`Damaged` when the footer is missing (a file cut short) or
    the summary or a chunk index points past the end of the data: nothing in the summary is
    trusted then."""
    if size < len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
        return None
    if size < 2 * len(MAGIC) + _FOOTER:
        raise Damaged(f"the file ends after {size} bytes, before any footer")
    f.seek(size - len(MAGIC) - _FOOTER)
    foot = f.read(_FOOTER + len(MAGIC))
    op, n, summary_start, summary_offset_start, _crc = struct.unpack_from("<BQQQI", foot)
    if op != OP_FOOTER or n != 20 or foot[_FOOTER:] != MAGIC:
        raise Damaged("no footer at its end (a file cut short)")
    if summary_start == 0:
        return None  # no summary: rosbags reads it
    end = summary_offset_start or size - len(MAGIC) - _FOOTER
    if not 0 < summary_start <= end <= size:
        raise Damaged(f"its footer points past the end of the file (summary at byte {summary_start} of {size})")
    f.seek(summary_start)
    try:
        summary = _records(f.read(end - summary_start))
    except ValueError as e:
        raise Damaged(f"its summary is damaged ({e})") from None
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    chunks: list[_ChunkIndex] = []
    counts: dict[int, int] = {}  # messages per channel (the statistics record), to size the buffers
    try:
        _parse_summary(summary, summary_start, schemas, channels, chunks, counts)
    except (ValueError, struct.error, UnicodeDecodeError) as e:
        if isinstance(e, Damaged):
            raise
        raise Damaged(f"its summary is damaged ({e})") from None
    if not chunks or any(ch.compression not in ("", "zstd", "lz4") for ch in chunks):
        return None  # unchunked (or an unknown compression): rosbags reads it, or says why not
    names = {cid: topic for cid, (topic, _) in channels.items()}
    sel = {cid: (topic, schemas[sid]) for cid, (topic, sid) in channels.items()
           if sid in schemas and (wanted is None or wanted(topic))}
    if len({t for t, _ in sel.values()}) != len(sel):
        return None  # a topic on several channels
    return sel, sorted(chunks, key=lambda x: x.start), counts, names


def _parse_summary(summary: list[tuple[int, _Cursor, int]], summary_start: int, schemas: dict[int, str],
                   channels: dict[int, tuple[str, int]], chunks: list[_ChunkIndex], counts: dict[int, int]) -> None:
    """Fill the schemas, channels, chunk indexes and counts of :func:`_summary` from its records."""
    for op, c, _ in summary:
        if op == OP_SCHEMA:
            sid = c.u16()
            schemas[sid] = c.str()
        elif op == OP_CHANNEL:
            cid, sid = c.u16(), c.u16()
            channels[cid] = (c.str(), sid)
        elif op == OP_CHUNK_INDEX:
            t0, t1 = c.u64(), c.u64()
            start, length = c.u64(), c.u64()
            m, offs = c.u32(), []
            stop = c.o + m
            while c.o < stop:
                offs.append((c.u16(), c.u64()))
            c.u64()
            ch = _ChunkIndex(start, length, frozenset(k for k, _ in offs), c.str(), c.u64(), c.u64(), t0, t1, tuple(offs))
            if not (0 < start and start + length <= summary_start):
                raise Damaged(f"the chunk index points past the data (a chunk at byte {start} of {length} bytes, "
                              f"the data end at byte {summary_start})")
            chunks.append(ch)
        elif op == OP_STATISTICS:
            c.raw(8 + 2 + 4 + 4 + 4 + 4 + 8 + 8)
            stop = c.u32() + c.o
            while c.o < stop:
                cid = c.u16()
                counts[cid] = c.u64()


def _results(sel: dict[int, tuple[str, str]], bufs: dict[int, _Growing]) -> dict[str, RawTopic]:
    out: dict[str, RawTopic] = {}
    for cid, (topic, msgtype) in sorted(sel.items(), key=lambda kv: kv[0]):
        t, msgs = bufs.pop(cid).result()
        if t.size > 1 and np.any(np.diff(t) < 0):  # rosbags: by log time, ties in file order
            order = np.argsort(t, kind="stable")
            t, msgs = t[order], msgs.take(order)
        out[topic] = RawTopic(msgtype, t.tolist(), msgs)
    return out


def damage(file: Path) -> str | None:
    """Why the MCAP ``file``'s layout cannot be trusted (no footer: a file cut short; a summary or
    chunk index pointing past the end of its data), or None when it is intact or not one this
    path reads.  Reads the footer and the summary only."""
    try:
        with file.open("rb") as f:
            _summary(f, file.stat().st_size, None)
    except Damaged as e:
        return str(e)
    return None


def _lost(f: BufferedReader, size: int, ch: _ChunkIndex, names: dict[int, str]) -> tuple[int, str]:
    """(messages, what they are) in the chunk ``ch``, from its message index records (each read only
    when it lies within the file)."""
    per: list[tuple[str, int]] = []
    for cid, off in ch.index_offsets:
        if not 0 < off <= size - 15:
            continue
        f.seek(off)
        head = f.read(15)
        op, _n, c, m = struct.unpack_from("<BQHI", head)
        if op == OP_MESSAGE_INDEX and c == cid:
            per.append((names.get(cid, f"channel {cid}"), m // 16))
    n = sum(k for _, k in per)
    what = ", ".join(f"{t} {k}" for t, k in per) if per else "not indexed"
    return n, f"{n} message(s) ({what})"


def _skipped(file: Path, ch: _ChunkIndex, why: str, lost: str) -> str:
    """The warning about the chunk ``ch`` skipped because ``why``."""
    span = f"log time {ch.t0 * 1e-9:.3f} to {ch.t1 * 1e-9:.3f} s" if ch.t1 >= ch.t0 > 0 else "log time unknown"
    return f"{file}: the chunk at byte {ch.start} ({span}) is skipped: {why}; lost {lost}; the other chunks are read"


class _Reading:
    """The chunks of one file read into per-channel buffers; a bad chunk is skipped, said in
    :attr:`notes` and counted in :attr:`lost` (messages)."""

    def __init__(self, file: Path, f: BufferedReader, size: int, names: dict[int, str], notes: list[str] | None) -> None:
        self.file, self.f, self.size, self.names = file, f, size, names
        self.notes = notes if notes is not None else []
        self.lost = 0
        self.reuse = _Buffers()

    def chunk(self, ch: _ChunkIndex, mask: NDArray[np.bool_], bufs: dict[int, _Growing]) -> None:
        try:
            if ch.uncompressed_size > MAX_CHUNK_BYTES or ch.length > MAX_CHUNK_BYTES + 256:
                raise ValueError(f"it declares {max(ch.uncompressed_size, ch.length)} bytes, more than the "
                                 f"{MAX_CHUNK_BYTES} a chunk may have (nothing allocated)")
            _chunk_messages(ch, self.reuse.read(self.f, ch.start, ch.length), mask, bufs, self.reuse)
        except ValueError as e:
            why = str(e)
            n, lost = _lost(self.f, self.size, ch, self.names)
            self.lost += n
            if isinstance(self.notes, Notes):
                if (str(self.file), ch.start) in self.notes.seen:
                    return
                self.notes.seen.add((str(self.file), ch.start))
                self.notes.lost_messages += n
            self.notes.append(_skipped(self.file, ch, why, lost))


def read(file: Path, wanted: Callable[[str], bool] | None, notes: list[str] | None = None) -> dict[str, RawTopic] | None:
    """``{topic: RawTopic}`` of the channels whose topic ``wanted`` accepts (all when None), or None
    when the file is not one this path reads (see module docstring).  A chunk that is corrupt (cut
    short, not decompressible, a CRC mismatch, records that do not fill it, a size past
    :data:`MAX_CHUNK_BYTES`) is skipped: a warning naming it, its log time range and the messages
    lost is appended to ``notes``, the other chunks are read.  :class:`Damaged` when the file's
    layout cannot be trusted (:func:`damage`)."""
    size = file.stat().st_size
    with file.open("rb") as f:
        found = _summary(f, size, wanted)
        if found is None:
            return None
        sel, chunks, counts, names = found
        mask = np.zeros(65536, dtype=np.bool_)
        mask[list(sel)] = True
        bufs = {cid: _Growing(counts.get(cid, 0), 64 * size) for cid in sel}
        reading = _Reading(file, f, size, names, notes)
        for ch in chunks:
            if ch.channels and not any(mask[c] for c in ch.channels):
                continue
            reading.chunk(ch, mask, bufs)
    return _results(sel, bufs)


def read_batches(file: Path, wanted: Callable[[str], bool] | None, batch_bytes: int = 2**26,
                 notes: list[str] | None = None) -> Iterator[dict[str, RawTopic]] | None:
    """:func:`read` a part at a time: ``{topic: RawTopic}`` of the wanted messages of consecutive
    chunks (in file order, each part sorted by log time), a part once it holds about
    ``batch_bytes`` of messages; every wanted topic in each part.  None when :func:`read` would
    return None; a corrupt chunk is skipped and said in ``notes`` as :func:`read` does.  Memory
    holds one part."""
    size = file.stat().st_size
    with file.open("rb") as f:
        found = _summary(f, size, wanted)
    if found is None:
        return None
    sel, chunks, _, names = found

    def parts() -> Iterator[dict[str, RawTopic]]:
        mask = np.zeros(65536, dtype=np.bool_)
        mask[list(sel)] = True
        with file.open("rb") as f:
            reading = _Reading(file, f, size, names, notes)
            bufs = {cid: _Growing(0) for cid in sel}
            for ch in chunks:
                if ch.channels and not any(mask[c] for c in ch.channels):
                    continue
                reading.chunk(ch, mask, bufs)
                if sum(b.used for b in bufs.values()) >= batch_bytes:
                    yield _results(sel, bufs)
                    bufs = {cid: _Growing(0) for cid in sel}
            yield _results(sel, bufs)

    return parts()


class _Growing:
    """One channel's messages as they are read: a buffer grown by doubling (first sized for
    ``expected`` messages of the size of the first), the messages' offsets and log times."""

    def __init__(self, expected: int, limit: int = 0) -> None:
        self.expected = expected
        self.limit = limit  # most bytes ``expected`` may ask for at once (a count in the file is not trusted)
        self.data = np.zeros(0, dtype=np.uint8)
        self.used = 0
        self.sizes: list[NDArray[np.int64]] = []
        self.times: list[NDArray[np.int64]] = []

    def add(self, src: NDArray[np.uint8], start: NDArray[np.int64], sizes: NDArray[np.int64], t: NDArray[np.int64]) -> None:
        """Append the messages ``src[start[i]:start[i] + sizes[i]]`` (K,) with log times ``t`` (K,)."""
        need = self.used + int(sizes.sum())
        if need > self.data.size:
            cap = max(need, 2 * self.data.size, min(self.expected * int(sizes[0]), self.limit) if not self.sizes else 0)
            grown = np.empty(cap, dtype=np.uint8)
            grown[: self.used] = self.data[: self.used]
            self.data = grown
        off = np.empty(sizes.size + 1, dtype=np.int64)
        off[0] = self.used
        np.cumsum(sizes, out=off[1:])
        off[1:] += self.used
        K.gather(src, start, sizes, self.data, off)
        self.used = need
        self.sizes.append(sizes)
        self.times.append(t)

    def result(self) -> tuple[NDArray[np.int64], Messages]:
        """``(log times (N,), messages)`` in the order they were added."""
        sizes = np.concatenate(self.sizes) if self.sizes else np.zeros(0, dtype=np.int64)
        off = np.zeros(sizes.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        t = np.concatenate(self.times) if self.times else np.zeros(0, dtype=np.int64)
        return t, Messages(self.data[: self.used], off)


def _chunk_data(rec: memoryview, reuse: _Buffers) -> memoryview:
    """The records of the chunk record ``rec`` (from its opcode on) decompressed (into ``reuse``'s
    buffer) and checked against the chunk's declared size and CRC; ValueError saying why they
    cannot be read (the reader and the recovery scan, :mod:`dpos_ros.io._mcap_recover`, skip the chunk)."""
    c = _Cursor(rec, 9)
    c.u64(), c.u64()  # (its messages' log time range)
    usize, crc = c.u64(), c.u32()
    comp = c.str()
    n = c.u64()
    if usize > MAX_CHUNK_BYTES:
        raise ValueError(f"it declares {usize} bytes of records, more than the {MAX_CHUNK_BYTES} a chunk may have (nothing allocated)")
    if c.o + n > len(rec):
        raise ValueError(f"is cut short ({len(rec) - c.o} of {n} bytes of records)")
    try:
        data = reuse.decompress(rec[c.o : c.o + n], comp, usize)
    except Exception as e:  # noqa: BLE001 - zstandard / lz4 raise their own errors
        raise ValueError(f"cannot be decompressed ({comp}: {type(e).__name__}: {e})") from None
    if len(data) != usize:
        raise ValueError(f"decompresses to {'more than ' if len(data) > usize else ''}{len(data)} bytes, not {usize}")
    if crc and zlib.crc32(data) != crc:
        raise ValueError("CRC mismatch of its records")
    return data


def _chunk_messages(ch: _ChunkIndex, rec: memoryview, mask: NDArray[np.bool_], bufs: dict[int, _Growing], reuse: _Buffers) -> None:
    """Append the wanted messages of one chunk record ``rec`` (indexed as ``ch``) to their channels'
    ``bufs``; ValueError saying why the chunk cannot be read."""
    if len(rec) != ch.length or len(rec) < 9 + 28 or rec[0] != OP_CHUNK:
        raise ValueError(f"is cut short or not a chunk ({len(rec)} of {ch.length} bytes)")
    buf = np.frombuffer(_chunk_data(rec, reuse), dtype=np.uint8)
    stop, _, cid, t, d0, ds = K.scan_messages(buf, mask)
    if stop != buf.size:
        raise ValueError(f"its records end in an incomplete record at byte {stop} of {buf.size}")
    for c_ in np.unique(cid):
        i = np.nonzero(cid == c_)[0]
        bufs[int(c_)].add(buf, d0[i], ds[i], t[i])


# ---------------------------------------------------------------------------------------------
# writing


def _u16(v: int) -> bytes:
    return v.to_bytes(2, "little")


def _u32(v: int) -> bytes:
    return v.to_bytes(4, "little")


def _u64(v: int) -> bytes:
    return v.to_bytes(8, "little")


def _s(v: str) -> bytes:
    b = v.encode()
    return _u32(len(b)) + b


def _rec(op: int, body: bytes) -> bytes:
    return bytes([op]) + _u64(len(body)) + body


def _buffer(data: bytes | NDArray[np.uint8]) -> bytes | memoryview:
    """``data`` as zstd takes it, without a copy."""
    return data.data if isinstance(data, np.ndarray) else data


@dataclass(frozen=True)
class _Chunk:
    """A chunk to write: its records ``data``, log time range [ns], the index of the message after
    its last, and its message indexes ``[(channel id, (log time, offset) pairs as u64 bytes)]``."""

    data: bytes | NDArray[np.uint8]  # (a built chunk's buffer is compressed as it is: no copy to bytes)
    t0: int
    t1: int
    end: int
    index: list[tuple[int, bytes]]
    crc: int = 0  # CRC-32 of the records (set once ``data`` is dropped: a chunk encoded elsewhere)


@dataclass(frozen=True)
class Topic:
    """One channel to write: ``msgs`` in the order of ``t_ns`` (N,) [ns] (the log times)."""

    topic: str
    msgtype: str
    t_ns: NDArray[np.int64]
    msgs: Messages


def _yaml(obj: object) -> str:
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    s = StringIO()
    yaml.dump(obj, s)
    return s.getvalue()


def write(path: Path, topics: Sequence[Topic], order: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]],
          custom_data: dict[str, str], version: int, library: str,
          progress: Callable[[int, int], None] | None = None, qos: Sequence[Sequence[Qos]] | None = None) -> int:
    """Write a new rosbag2 directory ``path`` with one MCAP file, messages in ``order`` =
    ``(t_ns, topic index, message index)`` (each (N,), from :func:`dpos_ros.io.streams.merged_order`);
    returns N.  The layout is that of rosbags' writer (module docstring); ``qos``: the offered QoS
    profiles of each topic (as :class:`Writer`)."""
    n = int(np.asarray(order[0]).size)
    with Writer(path, [(tp.topic, tp.msgtype) for tp in topics], custom_data, version, library,
                None if progress is None else (lambda done: progress(done, n)), qos) as w:
        w.add(topics, order)
    return n


def _chunks(topics: Sequence[Topic], order: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]],
            prefix: bytes) -> Iterator[_Chunk]:
    """The uncompressed chunks of one batch (``order`` as :func:`write`'s), laid out as rosbags'
    writer does (module docstring): ``prefix`` (records) opens the first, a chunk ends after the
    record that takes it over :data:`CHUNK_SIZE`, the batch's last chunk is closed with it."""
    t_all, si, mi = (np.asarray(a, dtype=np.int64) for a in order)
    n = int(t_all.size)
    # every message's channel, size and where its bytes are
    size = np.zeros(n, dtype=np.int64)
    start = np.zeros(n, dtype=np.int64)
    for k, tp in enumerate(topics):
        sel = si == k
        size[sel] = tp.msgs.sizes[mi[sel]]
        start[sel] = tp.msgs.offsets[mi[sel]]
    rec_len = size + K.MESSAGE_HEAD
    cum = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(rec_len, out=cum[1:])

    def build(a: int, b: int, prefix: bytes) -> _Chunk:
        """The uncompressed chunk of messages a..b-1 after the records ``prefix``."""
        usize = len(prefix) + int(cum[b] - cum[a])
        buf = np.empty(usize, dtype=np.uint8)
        if prefix:
            buf[: len(prefix)] = np.frombuffer(prefix, dtype=np.uint8)
        rec_off = len(prefix) + cum[a:b] - cum[a]
        s_c, t_c = si[a:b], t_all[a:b]
        for k, tp in enumerate(topics):
            j = np.nonzero(s_c == k)[0]
            if j.size:
                K.fill_messages(buf, rec_off[j], np.full(j.size, k + 1, dtype=np.int64), t_c[j],
                                tp.msgs.data, start[a:b][j], size[a:b][j])
        index = []  # message indexes, channels in the order of their first message in the chunk
        _, first_pos = np.unique(s_c, return_index=True)
        for k in s_c[np.sort(first_pos)]:
            j = np.nonzero(s_c == k)[0]
            pairs = np.empty((j.size, 2), dtype="<u8")
            pairs[:, 0] = t_c[j]
            pairs[:, 1] = rec_off[j]
            index.append((int(k) + 1, pairs.tobytes()))
        t0, t1 = (int(t_c.min()), int(t_c.max())) if b > a else (2**63 - 1, 0)
        return _Chunk(buf, t0, t1, b, index)

    a = 0
    while a < n or prefix:
        if a >= n:
            b = n
        elif len(prefix) > CHUNK_SIZE:  # rosbags closes a chunk only after a message
            b = a + 1
        else:  # the chunk ends after the first record that takes it over CHUNK_SIZE
            b = min(n, int(np.searchsorted(cum, cum[a] + CHUNK_SIZE - len(prefix), side="right")))
        yield build(a, b, prefix)
        prefix = b""
        a = b


def _batch_stats(n_topics: int, order: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]) -> tuple[int, NDArray[np.int64], int, int]:
    """(message count, count per channel, first and last log time) of a batch."""
    t_all, si = np.asarray(order[0], dtype=np.int64), np.asarray(order[1], dtype=np.int64)
    if not t_all.size:
        return 0, np.zeros(n_topics, dtype=np.int64), 2**63 - 1, 0
    return int(t_all.size), np.bincount(si, minlength=n_topics).astype(np.int64), int(t_all.min()), int(t_all.max())


@dataclass(frozen=True)
class EncodedBatch:
    """One batch laid out in compressed chunks (:func:`encode_batch`) for :meth:`Writer.add_encoded`;
    picklable.  ``chunks``: (chunk without its records, uncompressed size, compressed records)."""

    channels: list[tuple[str, str]]
    chunks: list[tuple[_Chunk, int, bytes]]
    stats: tuple[int, NDArray[np.int64], int, int]
    prefixed: bool


def encode_batch(topics: Sequence[Topic], order: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]],
                 prefix: bytes = b"") -> EncodedBatch:
    """:meth:`Writer.add`'s chunks of one batch, compressed in this thread (a pool's task: the
    writing process then only appends them, :meth:`Writer.add_encoded`); ``prefix``: the writer's
    :attr:`Writer.prefix` for the file's first batch, else empty."""
    cctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    chunks = []
    for ch in _chunks(topics, order, prefix):
        chunks.append((_Chunk(b"", ch.t0, ch.t1, ch.end, ch.index, zlib.crc32(_buffer(ch.data))), len(ch.data),
                       cctx.compress(_buffer(ch.data))))
    return EncodedBatch([(tp.topic, tp.msgtype) for tp in topics], chunks, _batch_stats(len(topics), order), bool(prefix))


class Writer:
    """A rosbag2 MCAP file written batch by batch (:meth:`add`; the whole file in one batch is
    :func:`write`): the channels are fixed at the start, each batch's messages go into chunks as
    :func:`write` lays them out (the last chunk of a batch is closed with it), the summary and
    ``metadata.yaml`` are written by :meth:`close`.  Memory holds one batch.

    ``library``: the MCAP header's writer name; ``qos``: per channel, the QoS profiles its
    publishers offered (rosbag2's ``offered_qos_profiles``, in the channel record and in
    ``metadata.yaml``: ``ros2 bag play`` publishes a topic TRANSIENT_LOCAL when they all were);
    none given: an empty list per channel."""

    def __init__(self, path: Path, channels: Sequence[tuple[str, str]], custom_data: dict[str, str], version: int,
                 library: str, progress: Callable[[int], None] | None = None,
                 qos: Sequence[Sequence[Qos]] | None = None) -> None:
        ts = get_typestore(Stores.ROS2_JAZZY)
        self.path, self.channels, self.custom_data = path, list(channels), dict(custom_data)
        self.version, self.progress = version, progress
        if qos is not None and len(qos) != len(self.channels):
            raise ValueError(f"{len(qos)} QoS lists for {len(self.channels)} channels")
        self.qos = [dump_qos_v9(list(q)) for q in qos] if qos is not None else [dump_qos_v9([]) for _ in self.channels]
        path.mkdir(mode=0o755, parents=True)
        self.file = path / f"{path.name}.mcap"
        # schemas and channels (ids from 1, a schema per message type, in the order of the topics)
        schema_ids: dict[str, int] = {}
        self.schema_recs: list[bytes] = []
        self.channel_recs: list[bytes] = []
        head = bytearray()  # the first chunk's schema and channel records
        self.digests: list[str] = []
        for k, (topic, msgtype) in enumerate(self.channels):
            if msgtype not in schema_ids:
                msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
                fmt = "ros2idl" if msgdef.startswith("=" * 80 + "\nIDL: ") else "ros2msg"
                schema_ids[msgtype] = len(schema_ids) + 1
                self.schema_recs.append(_rec(OP_SCHEMA, _u16(schema_ids[msgtype]) + _s(msgtype) + _s(fmt) + _s(msgdef)))
                head += self.schema_recs[-1]
            self.digests.append(ts.hash_rihs01(msgtype))
            qos_k = self.qos[k]
            meta = _s("offered_qos_profiles") + _s(qos_k if isinstance(qos_k, str) else _yaml(qos_k).strip())
            self.channel_recs.append(_rec(OP_CHANNEL, _u16(k + 1) + _u16(schema_ids[msgtype]) + _s(topic) + _s("cdr")
                                          + _u32(len(meta)) + meta))
            head += self.channel_recs[-1]
        self.prefix = bytes(head)  # the schema and channel records open the first chunk
        self.chunk_index: list[bytes] = []
        self.counts = np.zeros(len(self.channels), dtype=np.int64)
        self.n = 0
        self.t_min, self.t_max = 2**63 - 1, 0
        self._local = threading.local()
        self._zstd = zstandard
        self.f: BinaryIO = self.file.open("xb")
        self.pool = ThreadPoolExecutor(COMPRESS_THREADS)
        self.f.write(MAGIC)
        self.f.write(_rec(OP_HEADER, _s("ros2") + _s(library)))

    def __enter__(self) -> Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.f.close()

    def _compress(self, data: bytes | NDArray[np.uint8]) -> tuple[int, bytes]:
        """(CRC-32 of ``data``, ``data`` compressed); zstandard and zlib release the GIL: chunks are
        compressed while the next are built."""
        if not hasattr(self._local, "cctx"):
            self._local.cctx = self._zstd.ZstdCompressor(level=ZSTD_LEVEL)
        out: bytes = self._local.cctx.compress(_buffer(data))
        return zlib.crc32(_buffer(data)), out

    def _write_chunk(self, ch: _Chunk, usize: int, comp: bytes, crc: int) -> None:
        """Chunk ``ch`` (``usize`` bytes uncompressed with CRC-32 ``crc``, checked by readers; ``comp``
        compressed), its message indexes, its chunk index entry."""
        f = self.f
        body = _u64(ch.t0) + _u64(ch.t1) + _u64(usize) + _u32(crc) + _s("zstd") + _u64(len(comp))
        chunk_start = f.tell()
        f.write(bytes([OP_CHUNK]) + _u64(len(body) + len(comp)) + body)
        f.write(comp)
        chunk_end = f.tell()
        offsets = []
        for cid, pairs in ch.index:
            offsets.append((cid, f.tell()))
            f.write(_rec(OP_MESSAGE_INDEX, _u16(cid) + _u32(len(pairs)) + pairs))
        idx_map = b"".join(_u16(c) + _u64(o) for c, o in offsets)
        self.chunk_index.append(_rec(OP_CHUNK_INDEX, _u64(ch.t0) + _u64(ch.t1) + _u64(chunk_start) + _u64(chunk_end - chunk_start)
                                     + _u32(len(idx_map)) + idx_map + _u64(f.tell() - chunk_end) + _s("zstd")
                                     + _u64(len(comp)) + _u64(usize)))
        if self.progress is not None:
            self.progress(self.n_before + ch.end)

    def add(self, topics: Sequence[Topic], order: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]) -> None:
        """Write one batch: ``topics`` one per channel of the writer (in its order), ``order`` as :func:`write`'s.
        The chunks are compressed on :data:`COMPRESS_THREADS` threads while the next ones are built."""
        if [(tp.topic, tp.msgtype) for tp in topics] != self.channels:
            raise ValueError("a batch must hold the writer's channels, in order")
        self.n_before = self.n
        pending: deque[tuple[_Chunk, Future[tuple[int, bytes]]]] = deque()
        for ch in _chunks(topics, order, self.prefix):
            pending.append((ch, self.pool.submit(self._compress, ch.data)))
            while len(pending) > 2 * COMPRESS_THREADS:
                done, fut = pending.popleft()
                crc, comp = fut.result()
                self._write_chunk(done, len(done.data), comp, crc)
        while pending:
            done, fut = pending.popleft()
            crc, comp = fut.result()
            self._write_chunk(done, len(done.data), comp, crc)
        self._account(_batch_stats(len(topics), order))

    def add_encoded(self, batch: EncodedBatch) -> None:
        """Write one batch encoded elsewhere (:func:`encode_batch`, e.g. on a process pool): the same
        file as :meth:`add` of the batch's topics.  Batches are added in the order of the file; the
        first one must carry the writer's schema and channel records (``encode_batch(prefix=...)``)."""
        if batch.channels != self.channels:
            raise ValueError("a batch must hold the writer's channels, in order")
        if batch.prefixed != bool(self.prefix):
            raise ValueError("the first batch (and only it) must be encoded with the writer's prefix (Writer.prefix)")
        self.n_before = self.n
        for ch, usize, comp in batch.chunks:
            self._write_chunk(ch, usize, comp, ch.crc)
        self._account(batch.stats)

    def _account(self, stats: tuple[int, NDArray[np.int64], int, int]) -> None:
        n, counts, t_min, t_max = stats
        self.prefix = b""
        self.n += n
        if n:
            self.counts += counts
            self.t_min, self.t_max = min(self.t_min, t_min), max(self.t_max, t_max)

    def close(self) -> None:
        """The summary, the footer and ``metadata.yaml``."""
        if self.prefix:  # no batch: the schemas and channels still open a chunk
            self.add([Topic(t, m, np.zeros(0, dtype=np.int64), Messages.from_list(())) for t, m in self.channels],
                     (np.zeros(0, dtype=np.int64),) * 3)
        self.pool.shutdown(wait=True)
        f, n, counts = self.f, self.n, self.counts
        t_min, t_max = self.t_min, self.t_max
        file = self.file
        info = {
            "version": self.version,
            "storage_identifier": "mcap",
            "relative_file_paths": [file.name],
            "duration": {"nanoseconds": max(0, t_max - t_min)},
            "starting_time": {"nanoseconds_since_epoch": t_min},
            "message_count": n,
            "topics_with_message_count": [
                {"topic_metadata": {"name": topic, "type": msgtype, "serialization_format": "cdr",
                                    "offered_qos_profiles": self.qos[k], "type_description_hash": self.digests[k]},
                 "message_count": int(counts[k])}
                for k, (topic, msgtype) in enumerate(self.channels)],
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": file.name, "starting_time": {"nanoseconds_since_epoch": t_min},
                       "duration": {"nanoseconds": max(0, t_max - t_min)}, "message_count": n}],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": "jazzy",
        }
        with f:
            serialized = _yaml(info).strip()
            metadata_start = f.tell()
            meta_map = _s("serialized_metadata") + _s(serialized)
            f.write(_rec(OP_METADATA, _s("rosbag2") + _u32(len(meta_map)) + meta_map))
            metadata_end = f.tell()
            f.write(_rec(OP_DATA_END, _u32(0)))
            schema_start = f.tell()
            f.write(b"".join(self.schema_recs))
            channel_start = f.tell()
            f.write(b"".join(self.channel_recs))
            chunk_idx_start = f.tell()
            f.write(b"".join(self.chunk_index))
            metadata_index_start = f.tell()
            f.write(_rec(OP_METADATA_INDEX, _u64(metadata_start) + _u64(metadata_end - metadata_start) + _s("rosbag2")))
            statistics_start = f.tell()
            stats = b"".join(_u16(k + 1) + _u64(int(counts[k])) for k in range(len(self.channels)))
            f.write(_rec(OP_STATISTICS, _u64(n) + _u16(len(self.schema_recs)) + _u32(len(self.channels)) + _u32(0) + _u32(1)
                         + _u32(len(self.chunk_index)) + _u64(t_min) + _u64(t_max) + _u32(len(stats)) + stats))
            summary_offset_start = f.tell()
            for op, a0, a1 in ((OP_SCHEMA, schema_start, channel_start), (OP_CHANNEL, channel_start, chunk_idx_start),
                               (OP_CHUNK_INDEX, chunk_idx_start, metadata_index_start)):
                if a1 != a0:
                    f.write(_rec(OP_SUMMARY_OFFSET, bytes([op]) + _u64(a0) + _u64(a1 - a0)))
            f.write(_rec(OP_SUMMARY_OFFSET, bytes([OP_METADATA_INDEX]) + _u64(metadata_index_start)
                         + _u64(statistics_start - metadata_index_start)))
            f.write(_rec(OP_SUMMARY_OFFSET, bytes([OP_STATISTICS]) + _u64(statistics_start)
                         + _u64(summary_offset_start - statistics_start)))
            f.write(_rec(OP_FOOTER, _u64(schema_start) + _u64(summary_offset_start) + _u32(0)))
            f.write(MAGIC)
        meta_path = self.path / "metadata.yaml"
        tmp = meta_path.with_suffix(".yaml.tmp")
        tmp.write_text(_yaml({"rosbag2_bagfile_information": info}), "utf8")
        tmp.replace(meta_path)
