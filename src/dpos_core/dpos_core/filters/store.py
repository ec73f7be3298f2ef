"""Per-epoch arrays of a filter's forward pass kept for its backward pass: in memory, or in a file
when they are large (the UPF's particle track is ~50 kB an epoch; four hours at 1 Hz
are 0.7 GB per sub-IMU).

A file-backed :class:`EpochArray` is written and read with ``pwrite`` / ``pread`` (no memory
map: pages of a mapped file would count in the process's resident memory), so memory holds the
records being read or written, and the page cache the rest.  Records written one epoch after the
other are gathered in a small buffer (:data:`WRITE_BUFFER_BYTES`) and written together (a forward
filter writes a dozen records an epoch: one system call each cost ~10 % of the UPS's time).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dpos_core.units import FloatArray

#: an on-disk :class:`EpochArray` gathers the records written one epoch after the other up to this many
#: bytes (and at most 64 epochs) before writing them to its file
WRITE_BUFFER_BYTES = 2**18


class EpochArray:
    """A float64 array (K, ...) indexed by epoch: ``a[k] = v``, ``a[k0:k1] = block`` and ``a[k]``,
    ``a[k0:k1]`` (step 1) and ``a[-1]``; ``shape``.  In memory (``path`` None) or in the file
    ``path`` (created, removed by :meth:`close`)."""

    def __init__(self, n_epochs: int, shape: tuple[int, ...], path: Path | None = None) -> None:
        self.shape = (int(n_epochs), *(int(s) for s in shape))
        self._rec = tuple(self.shape[1:])
        self._rec_bytes = int(np.prod(self._rec, dtype=np.int64)) * 8
        self.path = path
        self._mem: FloatArray | None = None
        self._fd: int | None = None
        self._buf: FloatArray | None = None  # records of epochs _buf_k0 .. _buf_k0 + _buf_n - 1 not written yet
        self._buf_k0 = self._buf_n = 0
        if path is None:
            self._mem = np.empty(self.shape)
        else:
            self._fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
            self._buf = np.empty((max(1, min(64, WRITE_BUFFER_BYTES // max(self._rec_bytes, 1))), *self._rec))

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def on_disk(self) -> bool:
        return self._fd is not None

    def _index(self, k: int) -> int:
        k = int(k)
        if k < 0:
            k += self.shape[0]
        if not 0 <= k < self.shape[0]:
            raise IndexError(f"epoch {k} of {self.shape[0]}")
        return k

    def _flush(self) -> None:
        """Write the buffered records."""
        if self._buf_n and self._buf is not None:
            self._write(self._buf_k0, self._buf[:self._buf_n])
            self._buf_n = 0

    def _write(self, k: int, rec: FloatArray) -> None:
        size = rec.size * 8
        assert self._fd is not None
        if size and os.pwrite(self._fd, rec.data.cast("B"), k * self._rec_bytes) != size:
            raise OSError(f"short write to {self.path}")

    def __setitem__(self, k: int | slice, value) -> None:
        if self._mem is not None:
            self._mem[k] = value
            return
        assert self._fd is not None and self._buf is not None
        if not isinstance(k, slice):  # one epoch: into the buffer when it follows the buffered ones
            k = self._index(k)
            if self._buf_n and k != self._buf_k0 + self._buf_n:
                self._flush()
            if not self._buf_n:
                self._buf_k0 = k
            self._buf[self._buf_n] = value
            self._buf_n += 1
            if self._buf_n == len(self._buf):
                self._flush()
            return
        self._flush()
        a, b, step = k.indices(self.shape[0])
        if step != 1:
            raise IndexError("only slices of step 1")
        self._write(a, np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=float), (max(b - a, 0), *self._rec))))

    def __getitem__(self, k: int | slice) -> FloatArray:
        if self._mem is not None:
            return self._mem[k]
        assert self._fd is not None
        self._flush()
        if isinstance(k, slice):
            a, b, step = k.indices(self.shape[0])
            if step != 1:
                raise IndexError("only slices of step 1")
            n = max(b - a, 0)
            data = os.pread(self._fd, n * self._rec_bytes, a * self._rec_bytes)
            return np.frombuffer(data, dtype=float).reshape((n, *self._rec)).copy()
        i = self._index(k)
        data = os.pread(self._fd, self._rec_bytes, i * self._rec_bytes)
        if len(data) != self._rec_bytes:
            raise OSError(f"short read from {self.path} (epoch {i} not written?)")
        return np.frombuffer(data, dtype=float).reshape(self._rec).copy()

    def __array__(self, dtype=None, copy=None) -> FloatArray:
        """The whole array (read into memory when in a file)."""
        out = self[0:self.shape[0]] if self._mem is None else self._mem
        return out if dtype is None else out.astype(dtype)

    def close(self) -> None:
        """Remove the file (an in-memory array is kept)."""
        if self._fd is not None:
            self._buf, self._buf_n = None, 0
            os.close(self._fd)
            self._fd = None
            if self.path is not None:
                self.path.unlink(missing_ok=True)
            self._mem = np.empty((0, *self._rec))
            self.shape = (0, *self._rec)


#: what :meth:`EpochStore.array` makes: an array in memory, or one in a file
PerEpoch = FloatArray | EpochArray


class EpochStore:
    """Where a filter or smoother keeps its per-epoch arrays: ``directory`` None keeps
    them in memory (``numpy`` arrays, the default of every runner), else each array is an
    :class:`EpochArray` file in ``directory`` (the same numbers; memory then holds the records being
    read or written).  :meth:`close` removes the files of the arrays it made."""

    def __init__(self, directory: Path | None = None) -> None:
        self.directory = None if directory is None else Path(directory)
        self._made: list[EpochArray] = []
        self._names: set[str] = set()

    @property
    def on_disk(self) -> bool:
        return self.directory is not None

    def array(self, name: str, n_epochs: int, shape: tuple[int, ...], fill: float | None = None) -> PerEpoch:
        """A float64 array (n_epochs, *shape) named ``name`` (unique in the store), uninitialized, or
        every record ``fill``."""
        if self.directory is None:
            return np.empty((n_epochs, *shape)) if fill is None else np.full((n_epochs, *shape), fill)
        if name in self._names:
            raise ValueError(f"the store already has an array {name!r}")
        self._names.add(name)
        a = EpochArray(n_epochs, shape, self.directory / f"{name}.f64")
        self._made.append(a)
        if fill is not None:
            blk = max(1, 2**20 // max(a._rec_bytes, 1))
            for k0 in range(0, n_epochs, blk):
                a[k0:min(k0 + blk, n_epochs)] = fill
        return a

    def close(self) -> None:
        """Remove the files of the arrays made (those in memory are left to the caller)."""
        for a in self._made:
            a.close()
        self._made.clear()


def in_memory(a: PerEpoch) -> FloatArray:
    """The whole array in memory (read from its file when an :class:`EpochArray`)."""
    return np.asarray(a) if isinstance(a, EpochArray) else a


def blocks(n: int, block: int, reverse: bool = False):
    """The ranges ``(k0, k1)`` covering ``0 .. n`` in steps of ``block`` (last to first with ``reverse``)."""
    starts = range(0, n, block)
    for k0 in (reversed(starts) if reverse else starts):
        yield k0, min(k0 + block, n)
