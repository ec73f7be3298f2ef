"""Rows of the session products held a block at a time (docs/campaign.md "Long flights"): a
:class:`RowStore` per antenna (one file per column, appended as the transfer alignment hands the
rows over, read back by row ranges), :class:`StampCursor` over its stamps, and
:class:`StreamedAntenna`, an antenna whose rows are in a store."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.filters.variational import CGStats
from dpos_core.series import NavSeries
from dpos_core.ta import qc as Q

from .antenna import AntennaSolution

#: rows read or written at a time
ROW_BLOCK = 2**16


#: the columns of an antenna's (or a sub-IMU's) rows
ROW_COLUMNS: dict[str, tuple[tuple[int, ...], str]] = {
    "t_s": ((), "<f8"), "q_nb": ((4,), "<f8"), "vel_n_mps": ((3,), "<f8"), "llh": ((3,), "<f8"), "sigma": ((9,), "<f8"),
    "flags": ((), "<u4")}


@dataclass
class RowStore:
    """Rows appended to one file per column under ``path`` (created), read back by row ranges;
    picklable (the files are opened per call)."""

    path: Path
    columns: dict[str, tuple[tuple[int, ...], str]] = field(default_factory=lambda: dict(ROW_COLUMNS))
    n: int = 0

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        self.path.mkdir(parents=True, exist_ok=True)

    def _file(self, name: str) -> Path:
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
            with self._file(name).open("ab") as f:
                f.write(a.tobytes())
        self.n += n.pop()

    def read(self, name: str, i0: int = 0, i1: int | None = None) -> NDArray:
        """Rows ``i0:i1`` of column ``name``."""
        shape, dtype = self.columns[name]
        i1 = self.n if i1 is None else min(i1, self.n)
        size = int(np.prod(shape, dtype=np.int64))
        dt = np.dtype(dtype)
        if i1 <= i0:
            return np.zeros((0, *shape), dtype=dt)
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
        """Append the rows of ``other`` (the same columns), file to file (not through memory), and remove it."""
        if other.columns != self.columns:
            raise ValueError("extend needs a store of the same columns")
        for name in self.columns:
            with self._file(name).open("ab") as f, other._file(name).open("rb") as g:
                shutil.copyfileobj(g, f, 2**20)
        self.n += other.n
        other.remove()

    def remove(self) -> None:
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
class StreamedAntenna:
    """An antenna of the streamed products: :class:`~dpos_ros.products.antenna.AntennaSolution`'s fields
    with its rows in ``rows`` (None when not estimated)."""

    name: str
    sub_imu: str | None
    status: str
    rows: RowStore | None = None
    chol_jitter_repairs: int = 0
    not_estimated: list[tuple[float, float, str]] = field(default_factory=list)
    qc: Q.EpochQC | None = None
    cg: CGStats | None = None
    wing_fit: dict | None = None
    installation: dict = field(default_factory=dict)

    def solution(self, i0: int = 0, i1: int | None = None, step: int = 1) -> AntennaSolution:
        """An :class:`~dpos_ros.products.antenna.AntennaSolution` of the rows ``i0:i1`` (every ``step``-th)."""
        traj = sigma = flags = None
        if self.rows is not None:
            i1 = self.rows.n if i1 is None else min(i1, self.rows.n)
            # at most ROW_BLOCK rows read at a time (a multiple of step: every step-th row from i0), the kept rows
            # copied out (a strided view would hold its whole block: a 4 h antenna's rows for its QC figure)
            span = step * max(1, ROW_BLOCK // step)
            parts = [{k: (v[::step].copy() if step > 1 else v) for k, v in self.rows.rows(a, min(a + span, i1)).items()}
                     for a in range(i0, max(i1, i0 + 1), span)]
            c = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in self.rows.columns}
            traj, sigma, flags = nav_of(c), c["sigma"], c["flags"]
        return AntennaSolution(self.name, self.sub_imu, self.status, traj, sigma, self.chol_jitter_repairs, flags,
                                 list(self.not_estimated), qc=self.qc, cg=self.cg, wing_fit=self.wing_fit, installation=self.installation)
