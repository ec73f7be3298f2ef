"""Private recovery scan of :mod:`dpos_ros.io.bag`: every readable record of an MCAP file read from
its start, without its summary (:func:`scan`), for a recording cut short or whose summary cannot
be trusted (:func:`dpos_ros.io._mcap.damage`).  A chunk is decoded as the indexed reader decodes
it (:func:`dpos_ros.io._mcap._chunk_data`); what cannot be read is skipped and said."""

from __future__ import annotations

import mmap
import struct
from dataclasses import dataclass
from pathlib import Path

from dpos_ros.io import _bag_kernel as K
from dpos_ros.io._mcap import (
    _FOOTER,
    MAGIC,
    MAX_CHUNK_BYTES,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_SCHEMA,
    _Buffers,
    _chunk_data,
    _ChunkIndex,
    _Cursor,
    _records,
    _skipped,
)


@dataclass
class Scanned:
    """What :func:`scan` read: schemas ``{id: (name, encoding, data)}``, channels ``{id: (topic,
    schema id)}``, the messages ``(channel id, log time [ns], data)`` in file order, the messages
    known lost in skipped chunks, and the warnings (:attr:`notes`, the last one where the reading
    stopped)."""

    schemas: dict[int, tuple[str, str, bytes]]
    channels: dict[int, tuple[str, int]]
    messages: list[tuple[int, int, bytes]]
    lost: int
    notes: list[str]


#: a chunk record's compression field "zstd", 37 bytes after its start: where :func:`scan` resynchronizes
_ZSTD_FIELD = b"\x04\x00\x00\x00zstd"


def _records_in(buf: memoryview | bytes, out: Scanned, top: bool) -> int:
    """Read the schema, channel and message records back to back in ``buf`` into ``out``; returns
    where the records stop (``len(buf)`` when all are whole).  ``top``: the file's own records
    (stop at the end of the data)."""
    o, n = 0, len(buf)
    while o + 9 <= n:
        op, length = struct.unpack_from("<BQ", buf, o)
        if length > n - o - 9:
            return o
        body = o + 9
        if op == OP_MESSAGE:
            if length < K.MESSAGE_HEAD - 9:
                return o
            cid, = struct.unpack_from("<H", buf, body)
            t, = struct.unpack_from("<Q", buf, body + 6)
            out.messages.append((cid, t, bytes(buf[body + K.MESSAGE_HEAD - 9 : body + length])))
        elif op == OP_SCHEMA:
            c = _Cursor(buf, body)
            sid, name, enc = c.u16(), c.str(), c.str()
            out.schemas[sid] = (name, enc, c.raw(c.u32()))
        elif op == OP_CHANNEL:
            c = _Cursor(buf, body)
            cid, sid = c.u16(), c.u16()
            out.channels[cid] = (c.str(), sid)
        o = body + length
    return o


def scan(file: Path) -> Scanned:
    """Every readable record of the MCAP ``file`` read from its start, without its summary (a
    recording cut short, or whose summary cannot be trusted: :func:`damage`).  A chunk that is
    corrupt (see :func:`read`) is skipped, its lost messages counted from the message indexes that
    follow it, and said; a record whose declared length runs past the end of the file is either
    the end (a file cut short: what it held is lost, said) or, when a whole chunk follows it,
    damage skipped up to that chunk.  No allocation is larger than a chunk (at most
    :data:`MAX_CHUNK_BYTES`): the file is mapped, not read."""
    out = Scanned({}, {}, [], 0, [])
    size = file.stat().st_size
    reuse = _Buffers()
    with file.open("rb") as f:
        if size < len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{file}: not an MCAP file (no magic)")
        if size <= len(MAGIC) + 9:
            out.notes.append(f"{file}: no record after the magic")
            return out
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            buf = memoryview(mm)
            try:
                _scan(file, mm, buf, size, out, reuse)
                _summary_channels(buf, size, out)
            finally:
                buf.release()
    return out


def _summary_channels(buf: memoryview, size: int, out: Scanned) -> None:
    """Add to ``out`` the schemas and channels of the file's summary that the records did not give
    (those of a skipped chunk), when the footer and the summary are whole."""
    if size < 2 * len(MAGIC) + _FOOTER:
        return
    op, n, start, offsets, _ = struct.unpack_from("<BQQQI", buf, size - len(MAGIC) - _FOOTER)
    end = offsets or size - len(MAGIC) - _FOOTER
    if op != OP_FOOTER or n != 20 or bytes(buf[size - len(MAGIC):]) != MAGIC or not 0 < start <= end <= size:
        return
    found = Scanned({}, {}, [], 0, [])
    try:
        for op, c, _ in _records(buf[start:end]):
            if op in (OP_SCHEMA, OP_CHANNEL):
                _records_in(buf[start + c.o - 9 : start + c.o - 9 + 9 + struct.unpack_from("<Q", buf, start + c.o - 8)[0]],
                            found, True)
    except (ValueError, struct.error, UnicodeDecodeError):
        return
    for k, v in found.schemas.items():
        out.schemas.setdefault(k, v)
    for k, ch in found.channels.items():
        out.channels.setdefault(k, ch)


def _scan(file: Path, mm: mmap.mmap, buf: memoryview, size: int, out: Scanned, reuse: _Buffers) -> None:
    o = len(MAGIC)
    bad: list[str] | None = None  # the skipped chunk's warning, waiting for its message indexes
    bad_n: list[int] = [0]

    def close_bad() -> None:
        nonlocal bad
        if bad is not None:
            out.lost += bad_n[0]
            out.notes.append(bad[0].replace("{lost}", f"{bad_n[0]} message(s)" if bad_n[0] else "its messages (not indexed)"))
            bad = None

    while True:
        if o + 9 > size:
            close_bad()
            if o < size:
                out.notes.append(f"the file ends in an incomplete record at byte {o} of {size}; what was not in a complete chunk is lost")
            else:
                out.notes.append("read to the end")
            return
        op, length = struct.unpack_from("<BQ", buf, o)
        if op == OP_MESSAGE_INDEX and bad is not None and length >= 6 and o + 15 <= size:
            bad_n[0] += struct.unpack_from("<I", buf, o + 11)[0] // 16
            o += 9 + length
            continue
        close_bad()
        if op in (OP_DATA_END, OP_FOOTER):
            out.notes.append("read to the end")
            return
        if length > size - o - 9:
            nxt = mm.find(_ZSTD_FIELD, o + 9 + 37)
            if nxt < 0 or buf[nxt - 37] != OP_CHUNK:
                out.notes.append(f"the file ends in an incomplete record at byte {o} of {size} (one of {length} bytes "
                                 f"declared); what was not in a complete chunk is lost")
                return
            out.notes.append(f"{file}: {nxt - 37 - o} bytes skipped at byte {o} (a record declaring {length} bytes, "
                             f"past the end of the file: damage); reading on from the chunk at byte {nxt - 37}")
            o = nxt - 37
            continue
        if op == OP_CHUNK:
            why = _scan_chunk(buf[o : o + 9 + length], out, reuse)
            if why is not None:
                t0, t1 = struct.unpack_from("<QQ", buf, o + 9) if length >= 16 else (0, 0)
                ch = _ChunkIndex(o, 9 + length, frozenset(), "", 0, 0, t0, t1)
                bad = [_skipped(file, ch, why, "{lost}")]
                bad_n[0] = 0
        elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE):
            try:
                _records_in(buf[o : o + 9 + length], out, True)
            except (ValueError, struct.error, UnicodeDecodeError) as e:
                out.notes.append(f"{file}: the record at byte {o} is skipped ({e})")
        o += 9 + length


def _scan_chunk(rec: memoryview, out: Scanned, reuse: _Buffers) -> str | None:
    """Read one chunk record into ``out`` (all or nothing); why it is skipped, or None."""
    try:
        if len(rec) > MAX_CHUNK_BYTES + 256:
            raise ValueError(f"it declares {len(rec)} bytes, more than the {MAX_CHUNK_BYTES} a chunk may have")
        data = _chunk_data(rec, reuse)
        part = Scanned({}, {}, [], 0, [])
        if _records_in(data, part, False) != len(data):
            raise ValueError("its records end in an incomplete record")
    except (ValueError, struct.error, UnicodeDecodeError) as e:
        return str(e)
    out.schemas.update(part.schemas)
    out.channels.update(part.channels)
    out.messages.extend(part.messages)
    return None
