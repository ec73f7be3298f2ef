"""The row stores of the products (dpos_ros.products.rows), in memory and spilled to files: read
back by row ranges, a column at a time, and the rows before a time found from stamps read a block
at a time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_ros.products import rows, solve
from dpos_ros.products.solve import decimate


@pytest.fixture(params=["memory", "files"])
def where(request, tmp_path: Path) -> Path | None:
    """Where the store keeps its rows: in memory (None) or in files under a directory."""
    return None if request.param == "memory" else tmp_path / "rows"


def _store(where: Path | None, t: np.ndarray) -> rows.RowStore:
    st = rows.RowStore(where)
    n = t.size
    rng = np.random.default_rng(3)
    for a in range(0, n, 7):  # appended in uneven pieces
        b = min(n, a + 7)
        st.append(t_s=t[a:b], q_nb=rng.standard_normal((b - a, 4)), vel_n_mps=rng.standard_normal((b - a, 3)),
                  llh=rng.standard_normal((b - a, 3)), sigma=rng.standard_normal((b - a, 9)), flags=np.arange(a, b, dtype=np.uint32))
    return st


def test_column_is_the_column_of_all_rows(where: Path | None, monkeypatch) -> None:
    monkeypatch.setattr(rows, "ROW_BLOCK", 5)  # several blocks, the last one short
    st = _store(where, np.arange(23) * 0.5)
    sigma = st.read("sigma")
    for j in range(9):
        assert np.array_equal(st.column("sigma", j), sigma[:, j])
    assert np.array_equal(st.read("flags"), np.arange(23))
    assert np.array_equal(st.read("sigma", 4, 11), sigma[4:11]) and st.read("t_s", 30, 40).shape == (0,)


def test_extend_appends_and_empties_the_other(where: Path | None, tmp_path: Path) -> None:
    """A window's rows appended to an antenna's, from a store kept the other way or the same."""
    a = _store(where, np.arange(10) * 0.5)
    for other_where in (None, tmp_path / "other"):
        b = _store(other_where, 5.0 + np.arange(6) * 0.5)
        n, t_b = a.n, b.read("t_s").copy()
        a.extend(b)
        assert a.n == n + 6 and np.array_equal(a.read("t_s", n), t_b)
    assert np.array_equal(a.read("t_s")[:10], np.arange(10) * 0.5)


def test_rows_read_are_the_readers_own(where: Path | None) -> None:
    """A reader changing what it was given does not change the stored rows."""
    st = _store(where, np.arange(12) * 0.5)
    before = st.read("sigma")
    got = st.read("sigma", 2, 5)
    got[0, 0] = 1e9
    assert got.flags.writeable and np.array_equal(st.read("sigma"), before)


@pytest.mark.parametrize("block", [1, 3, 64])
def test_stamp_cursor_is_searchsorted(where: Path | None, block: int) -> None:
    t = np.concatenate([np.arange(10) * 0.1, 5.0 + np.arange(12) * 0.1])  # with a gap
    st = _store(where, t)
    cur = rows.StampCursor(st, block=block)
    assert cur.first_last() == (0.0, float(t[-1]))
    edges = [-1.0, 0.0, 0.05, 0.3, 0.3, 2.0, 5.0, 5.55, 6.1, 7.0, np.inf]
    assert [cur.index(e) for e in edges] == [int(np.searchsorted(t, e)) for e in edges]


@pytest.mark.parametrize("rate", [0.0, 30.0, 7.0])
def test_kept_rows_by_block_are_the_decimation(rate: float) -> None:
    t = np.cumsum(np.random.default_rng(2).uniform(0.004, 0.006, 3000))
    want = np.zeros(t.size, dtype=bool)
    want[decimate(t, rate)] = True
    for block in (1, 13, 500, 10**6):
        got = np.concatenate([solve._kept(t, i0, min(i0 + block, t.size), rate) for i0 in range(0, t.size, block)])
        assert np.array_equal(got, want), block
    assert 0 < want.sum() <= t.size
