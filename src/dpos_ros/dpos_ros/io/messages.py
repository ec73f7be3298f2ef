"""Many serialized messages in one buffer: what the bag and spill readers return per topic.

A :class:`Messages` is a sequence of ``bytes`` (index, slice, iterate, compare with a list) held
as one contiguous ``uint8`` buffer and the messages' start offsets, so that reading a bag of a
million messages creates no Python object per message; :meth:`Messages.rows` gives fixed-size
messages as the (N, size) array the vectorized decoder (:mod:`dpos_ros.contract.cdr`) takes,
without a copy when the messages are contiguous.  :class:`RawTopic` is one topic as
``(msgtype, log times [ns], messages)``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import NamedTuple, overload

import numpy as np
from numpy.typing import NDArray

from dpos_ros.io import _bag_kernel


class Messages(Sequence[bytes]):
    """N messages: ``data`` (M,) uint8 holding them back to back, ``offsets`` (N + 1,) int64 where
    message i is ``data[offsets[i]:offsets[i + 1]]``."""

    __slots__ = ("data", "offsets")

    def __init__(self, data: NDArray[np.uint8], offsets: NDArray[np.int64]) -> None:
        self.data = data
        self.offsets = offsets

    @classmethod
    def from_list(cls, blobs: Sequence[bytes]) -> Messages:
        """From a sequence of ``bytes`` (one copy)."""
        if isinstance(blobs, Messages):
            return blobs
        sizes = np.fromiter((len(b) for b in blobs), dtype=np.int64, count=len(blobs))
        off = np.zeros(len(blobs) + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        return cls(np.frombuffer(b"".join(blobs), dtype=np.uint8), off)

    @classmethod
    def from_rows(cls, rows: NDArray[np.uint8]) -> Messages:
        """From fixed-size messages (N, size) uint8 (no copy when ``rows`` is C-contiguous)."""
        r = np.ascontiguousarray(rows, dtype=np.uint8)
        n, size = r.shape
        return cls(r.reshape(-1), np.arange(n + 1, dtype=np.int64) * size)

    @classmethod
    def pack(cls, src: NDArray[np.uint8], start: NDArray[np.int64], sizes: NDArray[np.int64]) -> Messages:
        """The ``sizes[i]`` bytes of ``src`` at ``start[i]`` for i of (N,), packed into one buffer."""
        off = np.zeros(len(start) + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        return cls(_gather(src, np.asarray(start, dtype=np.int64), np.asarray(sizes, dtype=np.int64), off), off)

    @classmethod
    def concat(cls, parts: Sequence[Messages]) -> Messages:
        """The messages of ``parts`` one after the other (one copy)."""
        if len(parts) == 1:
            return parts[0]
        datas = [p.data[p.offsets[0]:p.offsets[-1]] for p in parts]
        sizes = [np.diff(p.offsets) for p in parts]
        off = np.zeros(sum(len(s) for s in sizes) + 1, dtype=np.int64)
        if len(off) > 1:
            np.cumsum(np.concatenate(sizes), out=off[1:])
        return cls(np.concatenate(datas) if datas else np.zeros(0, dtype=np.uint8), off)

    @property
    def sizes(self) -> NDArray[np.int64]:
        """(N,) bytes per message."""
        return np.diff(self.offsets)

    def __len__(self) -> int:
        return int(self.offsets.shape[0]) - 1

    @overload
    def __getitem__(self, i: int) -> bytes: ...

    @overload
    def __getitem__(self, i: slice) -> Messages: ...

    def __getitem__(self, i: int | slice) -> bytes | Messages:
        if isinstance(i, slice):
            start, stop, step = i.indices(len(self))
            if step != 1:
                return self.take(np.arange(start, stop, step))
            return Messages(self.data, self.offsets[start : max(start, stop) + 1])
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"message {i} of {n}")
        return self.data[self.offsets[i] : self.offsets[i + 1]].tobytes()

    def __iter__(self) -> Iterator[bytes]:
        data, off = self.data, self.offsets.tolist()
        for a, b in zip(off[:-1], off[1:]):
            yield data[a:b].tobytes()

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Messages):
            return (len(self) == len(other) and bool(np.array_equal(self.sizes, other.sizes))
                    and bool(np.array_equal(self.data[self.offsets[0]:self.offsets[-1]],
                                            other.data[other.offsets[0]:other.offsets[-1]])))
        if isinstance(other, Sequence) and not isinstance(other, str | bytes):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable buffer

    def __add__(self, other: Sequence[bytes]) -> Messages | list[bytes]:
        """Concatenation, as of lists: a Messages with a Messages, else a list."""
        if isinstance(other, Messages):
            return Messages.concat([self, other])
        if isinstance(other, Sequence):
            return list(self) + list(other)
        return NotImplemented

    def __radd__(self, other: Sequence[bytes]) -> list[bytes]:
        if isinstance(other, Sequence):
            return list(other) + list(self)
        return NotImplemented

    def __repr__(self) -> str:
        return f"Messages({len(self)} messages, {int(self.offsets[-1] - self.offsets[0])} bytes)"

    def take(self, idx: NDArray[np.intp]) -> Messages:
        """The messages ``idx`` (K,), in that order (one copy)."""
        idx = np.asarray(idx, dtype=np.int64)
        sizes = self.sizes[idx]
        off = np.zeros(idx.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        return Messages(_gather(self.data, self.offsets[idx], sizes, off), off)

    def _fixed_rows(self, idx: NDArray[np.int64], size: int) -> NDArray[np.uint8]:
        start = self.offsets[idx]
        if idx.size and np.all(np.diff(start) == size):  # back to back: a view
            return self.data[start[0] : start[0] + idx.size * size].reshape(idx.size, size)
        off = np.arange(idx.size + 1, dtype=np.int64) * size
        return _gather(self.data, start, np.full(idx.size, size, dtype=np.int64), off).reshape(idx.size, size)

    def rows(self, idx: NDArray[np.intp] | None = None) -> NDArray[np.uint8]:
        """Fixed-size messages (all, or those of ``idx`` (K,)) as a (K, size) uint8 array; a view when
        they lie back to back.  Raises :class:`ValueError` when their sizes differ."""
        sel = np.arange(len(self), dtype=np.int64) if idx is None else np.asarray(idx, dtype=np.int64)
        if sel.size == 0:
            return np.zeros((0, 0), dtype=np.uint8)
        sizes = self.sizes[sel]
        if np.any(sizes != sizes[0]):
            raise ValueError("messages of different sizes: frame names change within the topic")
        return self._fixed_rows(sel, int(sizes[0]))


def _gather(data: NDArray[np.uint8], start: NDArray[np.int64], sizes: NDArray[np.int64], off: NDArray[np.int64]) -> NDArray[np.uint8]:
    """``data[start[i]:start[i] + sizes[i]]`` for i = 0..K-1 back to back (message i at ``off[i]``)."""
    out = np.empty(int(off[-1]), dtype=np.uint8)
    _bag_kernel.gather(data, start, sizes, out, off)
    return out


class RawTopic(NamedTuple):
    """One topic of a bag or spill: its message type, log times [ns] (a list of N ints, in order)
    and its N serialized messages."""

    msgtype: str
    times: list[int]
    blobs: Messages
