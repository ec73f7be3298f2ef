"""Private numba kernels of the MCAP fast path (:mod:`dpos_ros.io._mcap`) and of
:class:`dpos_ros.io.messages.Messages`: scanning a decompressed chunk's records, and copying
message bytes in and out of contiguous buffers, one loop over the messages instead of one Python
object per message.

MCAP records (little endian): opcode u8, length u64, then ``length`` bytes; a Message record
(opcode 0x05) is channel_id u16, sequence u32, log_time u64, publish_time u64, then the data.
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: opcode of an MCAP Message record, and the bytes of a Message record before its data
OP_MESSAGE = 0x05
MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8


@nb.njit(cache=True, nogil=True)
def _u64(buf: np.ndarray, o: int) -> int:
    v = 0
    for k in range(7, -1, -1):
        v = (v << 8) | int(buf[o + k])
    return v


@nb.njit(cache=True, nogil=True)
def scan_messages(buf: np.ndarray, wanted: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Message records of the channels with ``wanted[channel_id]`` (65536,) bool in the records
    ``buf`` (M,) uint8: ``(end, record offset, channel id, log time [ns], data offset, data size)``,
    each (K,) int64 in file order.  ``end`` is where the scan stopped: ``len(buf)`` when every
    record is whole, else the offset of the first record that does not fit (or of a Message record
    shorter than its header)."""
    n = buf.shape[0]
    cap = n // MESSAGE_HEAD + 1
    rec = np.empty(cap, dtype=np.int64)
    ch = np.empty(cap, dtype=np.int64)
    t = np.empty(cap, dtype=np.int64)
    d0 = np.empty(cap, dtype=np.int64)
    ds = np.empty(cap, dtype=np.int64)
    k = 0
    o = 0
    while o + 9 <= n:
        op = buf[o]
        length = _u64(buf, o + 1)
        if length < 0 or length > n - o - 9:
            break
        if op == OP_MESSAGE:
            if length < MESSAGE_HEAD - 9:
                break
            c = np.int64(buf[o + 9]) | (np.int64(buf[o + 10]) << 8)
            if wanted[c]:
                rec[k] = o
                ch[k] = c
                t[k] = _u64(buf, o + 15)
                d0[k] = o + MESSAGE_HEAD
                ds[k] = length - (MESSAGE_HEAD - 9)
                k += 1
        o += 9 + length
    return o, rec[:k].copy(), ch[:k].copy(), t[:k].copy(), d0[:k].copy(), ds[:k].copy()


@nb.njit(cache=True, nogil=True)
def gather(src: np.ndarray, start: np.ndarray, size: np.ndarray, out: np.ndarray, off: np.ndarray) -> None:
    """``out[off[i]:off[i] + size[i]] = src[start[i]:start[i] + size[i]]`` for each i of (K,)."""
    for i in range(start.shape[0]):
        a = start[i]
        b = off[i]
        out[b : b + size[i]] = src[a : a + size[i]]  # (a slice copies twice as fast as a byte loop)


@nb.njit(cache=True, nogil=True)
def fill_messages(out: np.ndarray, rec: np.ndarray, channel: np.ndarray, t: np.ndarray,
                  src: np.ndarray, start: np.ndarray, size: np.ndarray) -> None:
    """Write K Message records into ``out`` (M,) uint8: record i at ``rec[i]``, channel id
    ``channel[i]``, sequence 0, log and publish time ``t[i]`` [ns], its data the ``size[i]`` bytes
    of ``src`` at ``start[i]`` (all (K,) int64)."""
    for i in range(rec.shape[0]):
        o = rec[i]
        out[o] = OP_MESSAGE
        length = size[i] + (MESSAGE_HEAD - 9)
        for k in range(8):
            out[o + 1 + k] = (length >> (8 * k)) & 0xFF
        c = channel[i]
        out[o + 9] = c & 0xFF
        out[o + 10] = (c >> 8) & 0xFF
        for k in range(4):
            out[o + 11 + k] = 0
        ti = t[i]
        for k in range(8):
            b = (ti >> (8 * k)) & 0xFF
            out[o + 15 + k] = b
            out[o + 23 + k] = b
        a = start[i]
        d = o + MESSAGE_HEAD
        out[d : d + size[i]] = src[a : a + size[i]]
