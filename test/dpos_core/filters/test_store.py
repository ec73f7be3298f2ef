"""The per-epoch arrays of the filters and smoothers in files (memory flat with the
flight's length): :class:`~dpos_core.filters.store.EpochStore` round trips, and the backward passes
read and written a block of epochs at a time give the numbers of the arrays in memory at once."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.filters import runners
from dpos_core.filters.gaussian import rts_smooth
from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.store import EpochArray, EpochStore, blocks, in_memory
from dpos_core.ta.qc import epoch_qc


class _Gappy(LinearGaussianModel):
    """No measurement (None) where ``ys`` is NaN."""

    def y(self, k: int):
        v = self.ys[k]
        return None if np.isnan(v).any() else v


def _model(K: int = 41, gaps: tuple[int, ...] = (0, 7, 8)) -> LinearGaussianModel:
    """A 3-state linear model with a 2-component measurement, none at the epochs ``gaps``."""
    F = np.array([[1.0, 0.1, 0.0], [0.0, 0.95, 0.1], [0.0, 0.0, 0.9]])
    rng = np.random.default_rng(3)
    ys = rng.normal(0.0, 1.0, (K, 2))
    ys[list(gaps)] = np.nan
    return _Gappy(F=F, Q=np.diag([1e-3, 1e-2, 1e-2]), H=np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                               R=np.diag([0.5, 0.2]), ys=ys)


def test_store_round_trip_in_files(tmp_path) -> None:
    rng = np.random.default_rng(0)
    st = EpochStore(tmp_path)
    a = st.array("a", 9, (2, 3))
    want = rng.normal(size=(9, 2, 3))
    a[2:7] = want[2:7]  # a block
    for k in (8, 0, 1, 7):  # and single epochs, in any order
        a[k] = want[k]
    assert isinstance(a, EpochArray) and a.on_disk and a.shape == (9, 2, 3)
    assert np.array_equal(a[3:8], want[3:8]) and np.array_equal(a[-1], want[-1]) and np.array_equal(in_memory(a), want)
    z = st.array("z", 5, (4,), fill=np.nan)
    assert np.all(np.isnan(in_memory(z))) and in_memory(z).shape == (5, 4)
    with pytest.raises(ValueError):
        st.array("a", 3, (1,))  # one file per name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.f64", "z.f64"]
    st.close()
    assert not list(tmp_path.iterdir())


def test_buffered_writes_are_read_back(tmp_path, monkeypatch) -> None:
    """Records written one epoch after the other are gathered before they reach the file: every read
    sees them, in any order of writes and reads."""
    from dpos_core.filters import store

    monkeypatch.setattr(store, "WRITE_BUFFER_BYTES", 3 * 16)  # 3 records of (2,) a buffer
    rng = np.random.default_rng(5)
    want = rng.normal(size=(11, 2))
    a = EpochArray(11, (2,), tmp_path / "b.f64")
    for k in (0, 1, 2, 3, 4):  # a full buffer written, then two records pending
        a[k] = want[k]
    assert np.array_equal(a[3], want[3]) and np.array_equal(a[0:5], want[0:5])
    a[7] = want[7]  # not after the pending ones: they are written first
    a[5] = want[5]
    a[6] = 0.0  # (broadcast)
    a[6] = want[6]  # the same epoch again
    a[8:11] = want[8:11]  # a block
    assert np.array_equal(in_memory(a), want)
    a.close()


def test_store_in_memory_is_numpy() -> None:
    st = EpochStore()
    a = st.array("a", 4, (2,), fill=0.0)
    assert isinstance(a, np.ndarray) and not st.on_disk and np.array_equal(a, np.zeros((4, 2)))
    assert list(blocks(10, 4)) == [(0, 4), (4, 8), (8, 10)] and list(blocks(10, 4, reverse=True)) == [(8, 10), (4, 8), (0, 4)]


@pytest.mark.parametrize("block", [1, 3, 7, 1000])
def test_rts_blockwise_in_files_equals_at_once_in_memory(tmp_path, block) -> None:
    m = _model()
    mem = runners.run_sigma_point_filter(m, np.zeros(3), np.eye(3))
    st = EpochStore(tmp_path)
    disk = runners.run_sigma_point_filter(m, np.zeros(3), np.eye(3), store=st)
    assert isinstance(disk.P_f, EpochArray) and isinstance(disk.nu, EpochArray)
    for name in ("x_f", "P_f", "x_p", "P_p", "C", "corrections", "nu", "S"):
        assert np.array_equal(in_memory(getattr(mem, name)), in_memory(getattr(disk, name)), equal_nan=True), name
    assert np.all(np.isnan(in_memory(disk.nu)[[0, 7, 8]])) and np.all(np.isfinite(in_memory(disk.nu)[1:7]))
    x, P = rts_smooth(mem.x_f, mem.P_f, mem.x_p, mem.P_p, mem.C, block=10**6)
    xd, Pd = rts_smooth(disk.x_f, disk.P_f, disk.x_p, disk.P_p, disk.C, store=st, block=block)
    assert isinstance(Pd, EpochArray)
    assert np.array_equal(x, in_memory(xd)) and np.array_equal(P, in_memory(Pd))
    assert not np.array_equal(x[0], mem.x_f[0])  # (the smoother moved the estimate: the comparison tests something)
    st.close()
    assert not list(tmp_path.iterdir())


def test_ups_smoother_in_files_equals_in_memory(tmp_path, monkeypatch) -> None:
    m = _model(33)
    a = runners.run_upf(m, np.zeros(3), np.eye(3), 20, np.random.default_rng(4), sampled=[1])
    lw_a, x_a, P_a = runners.rb_smooth(a)
    b = runners.run_upf(m, np.zeros(3), np.eye(3), 20, np.random.default_rng(4), sampled=[1], store=tmp_path)
    assert isinstance(b.logw, EpochArray) and isinstance(b.mixture.P_f, EpochArray)
    monkeypatch.setattr(runners, "FFBSM_BLOCK", 5)
    from dpos_core.filters import gaussian

    monkeypatch.setattr(gaussian, "RTS_BLOCK", 4)
    lw_b, x_b, P_b = runners.rb_smooth(b)
    assert isinstance(P_b, EpochArray)
    assert np.array_equal(lw_a, in_memory(lw_b)) and np.array_equal(x_a, in_memory(x_b)) and np.array_equal(P_a, in_memory(P_b))
    for name in ("x_f", "P_f", "x_p", "P_p", "C", "nu", "S", "corrections"):
        assert np.array_equal(in_memory(getattr(a.mixture, name)), in_memory(getattr(b.mixture, name)), equal_nan=True), name
    b.close()
    assert not list(tmp_path.iterdir())


def test_ups_of_the_sampled_components_alone_equals_the_full_track(tmp_path) -> None:
    """run_upf(full_track=False): only the proposed particles' sampled components are kept, the
    smoother's numbers are the full track's."""
    m = _model(29)
    a = runners.run_upf(m, np.zeros(3), np.eye(3), 16, np.random.default_rng(6), sampled=[1])
    b = runners.run_upf(m, np.zeros(3), np.eye(3), 16, np.random.default_rng(6), sampled=[1], full_track=False, store=tmp_path)
    assert b.particles is None and b.proposed is None and b.proposed_sampled is not None and b.proposed_sampled.shape == (29, 16, 1)
    assert a.proposed is not None and np.array_equal(in_memory(b.proposed_sampled), np.asarray(a.proposed)[:, :, [1]])
    for x, y in zip(runners.rb_smooth(a), runners.rb_smooth(b), strict=True):
        assert np.array_equal(in_memory(x), in_memory(y))
    b.close()
    assert not list(tmp_path.iterdir())
    every = runners.run_upf(m, np.zeros(3), np.eye(3), 8, np.random.default_rng(6), full_track=False)
    with pytest.raises(ValueError):
        runners.rb_smooth(every)  # (every component sampled: the smoother takes the particles' moments)


def test_epoch_qc_in_blocks_equals_at_once(tmp_path) -> None:
    m = _model()
    st = EpochStore(tmp_path)
    tr = runners.run_sigma_point_filter(m, np.zeros(3), np.eye(3), store=st)
    xs, Ps = runners.smooth_gaussian(tr, st)
    t = np.arange(m.n_epochs, dtype=float)
    at_once = epoch_qc(t, in_memory(tr.nu), in_memory(tr.S), in_memory(tr.x_f), in_memory(tr.P_f), in_memory(xs), in_memory(Ps),
                       block=10**6)
    blocked = epoch_qc(t, tr.nu, tr.S, tr.x_f, tr.P_f, xs, Ps, block=6)
    for name in ("epochs_s", "nis", "dof", "sep", "sep_dof", "sep_norm", "nz2"):
        assert np.array_equal(getattr(at_once, name), getattr(blocked, name), equal_nan=True), name
    assert blocked.smoothed and np.isnan(blocked.nis[0]) and np.isfinite(blocked.nis[1])
    st.close()
