"""The row files of dpos-process --stream (dpos_ros.products.stream): read back by row
ranges, a column at a time, and the rows before a time found from stamps read a block at a time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_ros.products import rows, stream
from dpos_ros.products.solve import decimate


def _store(tmp_path: Path, t: np.ndarray) -> rows.RowStore:
    st = rows.RowStore(tmp_path / "rows")
    n = t.size
    rng = np.random.default_rng(3)
    for a in range(0, n, 7):  # appended in uneven pieces
        b = min(n, a + 7)
        st.append(t_s=t[a:b], q_nb=rng.standard_normal((b - a, 4)), vel_n_mps=rng.standard_normal((b - a, 3)),
                  llh=rng.standard_normal((b - a, 3)), sigma=rng.standard_normal((b - a, 9)), flags=np.arange(a, b, dtype=np.uint32))
    return st


def test_column_is_the_column_of_all_rows(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(rows, "ROW_BLOCK", 5)  # several blocks, the last one short
    st = _store(tmp_path, np.arange(23) * 0.5)
    sigma = st.read("sigma")
    for j in range(9):
        assert np.array_equal(st.column("sigma", j), sigma[:, j])
    assert np.array_equal(st.read("flags"), np.arange(23))


@pytest.mark.parametrize("block", [1, 3, 64])
def test_stamp_cursor_is_searchsorted(tmp_path: Path, block: int) -> None:
    t = np.concatenate([np.arange(10) * 0.1, 5.0 + np.arange(12) * 0.1])  # with a gap
    st = _store(tmp_path, t)
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
        got = np.concatenate([stream._kept(t, i0, min(i0 + block, t.size), rate) for i0 in range(0, t.size, block)])
        assert np.array_equal(got, want), block
    assert 0 < want.sum() <= t.size
