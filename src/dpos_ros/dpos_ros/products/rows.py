"""Rows of the session products held a block at a time (docs/long_flights.md): a :class:`RowStore`
per antenna (appended as the transfer alignment hands the rows over, read back by row ranges; in
memory, or one file per column in a scratch directory for a long flight), :class:`StampCursor`
over its stamps, :class:`RowBlock` (a range of rows as arrays) and the helpers of the workers that
fill them (:func:`release_memory`, :func:`drained`, :func:`scratch_dir`)."""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import ctypes.util
import functools
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.series import NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.units import FloatArray

#: rows read or written at a time
ROW_BLOCK = 2**16


#: the columns of an antenna's (or a sub-IMU's) rows
ROW_COLUMNS: dict[str, tuple[tuple[int, ...], str]] = {
    "t_s": ((), "<f8"), "q_nb": ((4,), "<f8"), "vel_n_mps": ((3,), "<f8"), "llh": ((3,), "<f8"), "sigma": ((9,), "<f8"),
    "flags": ((), "<u4")}


@dataclass
class RowStore:
    """Rows appended column by column and read back by row ranges: in memory (``path`` None) or one
    file per column under ``path`` (created; the rows spilled to disk, a long flight's).  The same
    rows either way; picklable (a worker's store comes back to the caller; the files are opened
    per call).  The rows read are the reader's own (a copy, in memory as from the files)."""

    path: Path | None = None
    columns: dict[str, tuple[tuple[int, ...], str]] = field(default_factory=lambda: dict(ROW_COLUMNS))
    n: int = 0
    _mem: dict[str, list[NDArray]] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.path is None:
            if self._mem is None:
                self._mem = {name: [] for name in self.columns}
            return
        self.path = Path(self.path)
        self.path.mkdir(parents=True, exist_ok=True)

    def child(self, name: str, columns: dict[str, tuple[tuple[int, ...], str]] | None = None) -> RowStore:
        """A new store of ``columns`` (default :data:`ROW_COLUMNS`) kept as this one is: in memory, or
        in the directory ``name`` beside this one's files."""
        cols = dict(ROW_COLUMNS) if columns is None else columns
        return RowStore(None if self.path is None else self.path / name, cols)

    def _file(self, name: str) -> Path:
        assert self.path is not None
        return self.path / f"{name}.bin"

    def append(self, **cols: NDArray) -> None:
        """Append rows: every column, the same number of rows."""
        n = {np.asarray(v).shape[0] for v in cols.values()}
        if set(cols) != set(self.columns) or len(n) != 1:
            raise ValueError(f"append needs the columns {sorted(self.columns)} with as many rows each")
        for name, (shape, dtype) in self.columns.items():
            a = np.ascontiguousarray(cols[name], dtype=dtype)
            if a.shape[1:] != shape:
                raise ValueError(f"column {name}: rows of shape {a.shape[1:]}, not {shape}")
            if self._mem is not None:
                self._mem[name].append(a.copy())
                continue
            with self._file(name).open("ab") as f:
                f.write(a.tobytes())
        self.n += n.pop()

    def _whole(self, name: str) -> NDArray:
        """Column ``name``'s rows in memory, as one array (read-only: the store's)."""
        assert self._mem is not None
        parts = self._mem[name]
        if len(parts) != 1:
            shape, dtype = self.columns[name]
            parts[:] = [np.concatenate(parts) if parts else np.zeros((0, *shape), dtype=dtype)]
        parts[0].flags.writeable = False
        return parts[0]

    def read(self, name: str, i0: int = 0, i1: int | None = None) -> NDArray:
        """Rows ``i0:i1`` of column ``name``."""
        shape, dtype = self.columns[name]
        i1 = self.n if i1 is None else min(i1, self.n)
        size = int(np.prod(shape, dtype=np.int64))
        dt = np.dtype(dtype)
        if i1 <= i0:
            return np.zeros((0, *shape), dtype=dt)
        if self._mem is not None:
            return self._whole(name)[i0:i1].copy()  # (the reader's own, as from the files)
        a = np.fromfile(self._file(name), dtype=dt, count=(i1 - i0) * size, offset=i0 * size * dt.itemsize)
        return a.reshape((i1 - i0, *shape))

    def column(self, name: str, j: int) -> NDArray:
        """Column ``j`` (N,) of the rows of the 2-D column ``name``, read a block of rows at a time."""
        shape, dtype = self.columns[name]
        out = np.empty(self.n, dtype=dtype)
        for i0 in range(0, self.n, ROW_BLOCK):
            out[i0:i0 + ROW_BLOCK] = self.read(name, i0, i0 + ROW_BLOCK)[:, j]
        return out

    def rows(self, i0: int = 0, i1: int | None = None) -> dict[str, NDArray]:
        return {name: self.read(name, i0, i1) for name in self.columns}

    def extend(self, other: RowStore) -> None:
        """Append the rows of ``other`` (the same columns; files: file to file, not through memory), and remove it."""
        if other.columns != self.columns:
            raise ValueError("extend needs a store of the same columns")
        for name in self.columns:
            if self._mem is not None:
                self._mem[name].append(other.read(name))
                continue
            if other._mem is not None:
                with self._file(name).open("ab") as f:
                    f.write(np.ascontiguousarray(other.read(name)).tobytes())
                continue
            with self._file(name).open("ab") as f, other._file(name).open("rb") as g:
                shutil.copyfileobj(g, f, 2**20)
        self.n += other.n
        other.remove()

    def remove(self) -> None:
        if self._mem is not None:
            self._mem = {name: [] for name in self.columns}
            self.n = 0
            return
        assert self.path is not None
        shutil.rmtree(self.path, ignore_errors=True)


class StampCursor:
    """The rows of a :class:`RowStore` before a time, found from its stamps read a block at a time
    (a long flight's stamps are not held in memory): :meth:`index` is ``np.searchsorted(t_s,
    t_edge)`` over all its stamps, for ``t_edge`` asked in increasing order."""

    def __init__(self, rows: RowStore, block: int = ROW_BLOCK) -> None:
        self.rows, self.block = rows, block
        self.base = 0  # the row of t[0]
        self.t = rows.read("t_s", 0, block)

    def index(self, t_edge: float) -> int:
        """The first row at or after ``t_edge`` [s] (not before an earlier call's answer)."""
        while True:
            j = int(np.searchsorted(self.t, t_edge))
            if j < self.t.size or self.base + self.t.size >= self.rows.n:
                self.base, self.t = self.base + j, self.t[j:]
                return self.base
            self.base += self.t.size
            self.t = self.rows.read("t_s", self.base, self.base + self.block)

    def first_last(self) -> tuple[float, float]:
        """The first and the last stamp [s] (the store has rows)."""
        return float(self.rows.read("t_s", 0, 1)[0]), float(self.rows.read("t_s", self.rows.n - 1)[0])


def nav_of(cols: dict[str, NDArray]) -> NavSeries:
    return NavSeries(cols["t_s"], cols["q_nb"], cols["vel_n_mps"], cols["llh"])


@dataclass
class RowBlock:
    """Rows ``i0:i1`` of an antenna (or a sub-IMU) as arrays: ``traj`` (N) with ``sigma`` (N, 9)
    attitude (rad, rotation about local ENU), velocity (m/s, ENU), position (m, ENU) 1-sigma and
    ``flags`` (N,) (:mod:`dpos_core.ta.flags`)."""

    traj: NavSeries
    sigma: FloatArray
    flags: ta_flags.FlagArray

    @classmethod
    def of(cls, rows: RowStore, i0: int = 0, i1: int | None = None, step: int = 1) -> RowBlock:
        """The rows ``i0:i1`` (every ``step``-th) of ``rows``: at most ROW_BLOCK rows read at a time (a
        multiple of step: every step-th row from i0), the kept rows copied out (a strided view would
        hold its whole block: a 4 h antenna's rows for its QC figure)."""
        i1 = rows.n if i1 is None else min(i1, rows.n)
        span = step * max(1, ROW_BLOCK // step)
        parts = [{k: (v[::step].copy() if step > 1 else v) for k, v in rows.rows(a, min(a + span, i1)).items()}
                 for a in range(i0, max(i1, i0 + 1), span)]
        c = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in rows.columns}
        return cls(nav_of(c), c["sigma"], c["flags"])


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (None elsewhere), looked up once: ``ctypes.util.find_library`` runs
    ``ldconfig`` in a subprocess, ~10 ms a call (and it is called once per bag batch)."""
    try:
        fn: Callable[[int], int] = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
        return fn
    except (OSError, AttributeError):
        return None


def release_memory() -> None:
    """Give the C heap's free pages back to the system (glibc ``malloc_trim``; nothing elsewhere): a
    worker's heap otherwise keeps what a task grew it to while it idles or runs a smaller task."""
    fn = _malloc_trim()
    if fn is not None:
        fn(0)


@contextmanager
def drained(futures: Callable[[], Iterable[cf.Future]]) -> Iterator[None]:
    """On an error inside, cancel the pool's tasks ``futures()`` that have not started and wait for
    those running: they write into a directory the caller removes (the rows' scratch, the products)."""
    try:
        yield
    except BaseException:
        fs = list(futures())
        for f in fs:
            f.cancel()
        cf.wait(fs)
        raise


def scratch_dir(out_root: Path) -> tempfile.TemporaryDirectory:
    """A temporary directory for the rows spilled to disk, beside the products (same file system, likely room)."""
    Path(out_root).mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix=".dpos_rows_", dir=out_root)
