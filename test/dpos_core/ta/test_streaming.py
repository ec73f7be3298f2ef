"""The transfer alignment without its nominal trajectory in memory: the output pass
re-integrates each interval from the integrator's state stored at its start
(``TransferAlignmentModel.keep_nominal=False``, ``pipeline.KEEP_NOMINAL``) and builds the rows a
block of intervals at a time; the result is the one of the stored nominal, bit for bit."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from dpos_core.evaluation import ta as from_sim
from dpos_core.filters import gaussian, runners
from dpos_core.filters.store import EpochArray
from dpos_core.sim.flight import Segment
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.ta import pipeline, qc
from dpos_core.ta.model import TAConfig, TransferAlignmentModel
from dpos_core.ta.pipeline import TASettings


@pytest.fixture(scope="module")
def flight():
    sc = load_scenario("paper_su", aircraft="paper_su_pair")
    sc = replace(sc, segments=(Segment(8.0, name="lead_in"), Segment(12.0, heading_change_deg=30.0, name="turn")))
    ss = SimulatedSession(sc, 2, None)
    return from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")


def _same(a: pipeline.TAResult, b: pipeline.TAResult) -> None:
    for f in fields(pipeline.TAResult):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if isinstance(va, np.ndarray):
            assert np.array_equal(va, vb, equal_nan=True), f.name
        elif f.name not in ("qc", "cg"):
            assert va == vb, f.name


@pytest.mark.parametrize("method", ["urtss", "ups"])
def test_re_integrated_nominal_gives_the_stored_nominals_result(flight, monkeypatch, method) -> None:
    imu, master, ins = flight
    cfg = TAConfig(attitude_sigma_deg=1.0)
    monkeypatch.setattr(pipeline, "KEEP_NOMINAL", True)
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 10**6)  # every row at once, as one block
    stored = pipeline.run_segments(imu, master, ins, TASettings(method=method, particles=16, seed=3), cfg=cfg)
    monkeypatch.setattr(pipeline, "KEEP_NOMINAL", False)
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 3)
    replayed = pipeline.run_segments(imu, master, ins, TASettings(method=method, particles=16, seed=3), cfg=cfg)
    assert stored.t_s.size == imu.t_s.size
    _same(stored, replayed)


def test_model_replays_each_interval_bit_for_bit(flight) -> None:
    imu, master, ins = flight
    init = pipeline.initial_from_master(master, ins)
    kept = TransferAlignmentModel(imu, master, ins, TAConfig(), init)
    lean = TransferAlignmentModel(imu, master, ins, TAConfig(), init, keep_nominal=False)
    rng = np.random.default_rng(0)
    for k in range(kept.n_epochs - 1):
        c = rng.normal(0.0, 1e-4, kept.n)  # any correction: the same on both
        kept.feedback(k, c)
        lean.feedback(k, c)
    assert np.array_equal(kept.interval_sizes(), lean.interval_sizes())
    for k in (0, 5, kept.n_epochs - 2):
        a, b = kept.nominal_chunk(k), lean.nominal_chunk(k)
        for name in ("t_s", "q_nb", "vel_n_mps", "llh"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), (k, name)
        assert np.array_equal(kept.vibration_variance(k + 1)[0], lean.vibration_variance(k + 1)[0])
    assert not lean._chunks and len(kept._chunks) == kept.n_epochs - 1


def test_strapdown_snapshot_restore_continues_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    s0 = NavState(0.0, np.array([1.0, 0.0, 0.0, 0.0]), np.array([100.0, 0.0, 0.0]), np.array([0.6, 1.9, 1000.0]))
    t = np.arange(1, 401) * 0.01
    dth, dv = rng.normal(0, 1e-4, (400, 3)), rng.normal(0, 1e-3, (400, 3)) + [0.0, 0.0, 0.098]
    a = Strapdown(s0)
    a.run_increments(t[:150], dth[:150], dv[:150])
    snap = a.snapshot()
    rest = a.run_increments(t[150:], dth[150:], dv[150:])
    b = Strapdown(s0)
    b.restore(snap)
    again = b.run_increments(t[150:], dth[150:], dv[150:])
    assert np.array_equal(rest.q_nb, again.q_nb) and np.array_equal(rest.llh, again.llh)


@pytest.mark.parametrize("method", ["ups", "upf", "urtss", "cdkf_rts", "ukf"])
def test_per_epoch_arrays_on_disk_give_the_same_result(flight, monkeypatch, method) -> None:
    """The filter's and the smoother's per-epoch arrays in files (the threshold 0), read back in blocks
    that do not divide the epochs (backward pass, quality measures, output rows): the same result."""
    imu, master, ins = flight
    cfg = TAConfig(attitude_sigma_deg=1.0)
    mem = pipeline.run_segments(imu, master, ins, TASettings(method=method, particles=16, seed=5), cfg=cfg)
    made: list[bool] = []
    real = pipeline.EpochStore

    def spy(directory=None):
        made.append(directory is not None)
        return real(directory)

    monkeypatch.setattr(pipeline, "EpochStore", spy)
    monkeypatch.setattr(pipeline, "TRACK_IN_MEMORY_BYTES", 0)  # every track to files
    monkeypatch.setattr(runners, "FFBSM_BLOCK", 4)
    monkeypatch.setattr(gaussian, "RTS_BLOCK", 3)
    monkeypatch.setattr(qc, "QC_BLOCK", 5)
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 2)
    disk = pipeline.run_segments(imu, master, ins, TASettings(method=method, particles=16, seed=5), cfg=cfg)
    assert made == [True] and mem.x.shape[0] > 5
    _same(mem, disk)
    assert mem.qc is not None and disk.qc is not None and mem.qc.smoothed == disk.qc.smoothed
    for f in fields(mem.qc):
        if f.name != "smoothed":
            assert np.array_equal(getattr(mem.qc, f.name), getattr(disk.qc, f.name), equal_nan=True), f.name


def test_ffbsm_of_a_track_on_disk_is_the_track_in_memory(tmp_path, monkeypatch) -> None:
    from dpos_core.filters.model import LinearGaussianModel

    F = np.array([[1.0, 0.1], [0.0, 0.95]])
    rng = np.random.default_rng(2)
    ys = rng.normal(0.0, 1.0, (40, 1))
    m = LinearGaussianModel(F=F, Q=np.diag([1e-3, 1e-2]), H=np.array([[1.0, 0.0]]), R=np.array([[0.5]]), ys=ys)
    a = runners.run_upf(m, np.zeros(2), np.eye(2), 30, np.random.default_rng(4), sampled=[1])
    b = runners.run_upf(m, np.zeros(2), np.eye(2), 30, np.random.default_rng(4), sampled=[1], store=tmp_path)
    assert isinstance(b.particles, EpochArray) and b.particles.on_disk
    whole = runners.ffbsm(a)
    monkeypatch.setattr(runners, "FFBSM_BLOCK", 7)  # blocks that do not divide the epochs
    assert np.array_equal(whole, runners.ffbsm(b)) and np.array_equal(whole, runners.ffbsm(a))
    b.close()
    assert not list(tmp_path.iterdir())


def test_epoch_array_round_trip(tmp_path) -> None:
    rng = np.random.default_rng(0)
    want = rng.normal(size=(7, 3, 2))
    a = EpochArray(7, (3, 2), tmp_path / "a.f64")
    for k in (3, 0, 6, 1, 2, 5, 4):  # any order
        a[k] = want[k]
    assert np.array_equal(a[2], want[2]) and np.array_equal(a[-1], want[-1]) and np.array_equal(a[1:5], want[1:5])
    assert np.array_equal(np.asarray(a), want) and a.shape == (7, 3, 2) and len(a) == 7
    with pytest.raises(IndexError):
        a[7]
    a.close()
    assert not (tmp_path / "a.f64").exists()
    m = EpochArray(2, (3,))
    m[1] = [1.0, 2.0, 3.0]
    assert not m.on_disk and np.array_equal(m[1], [1.0, 2.0, 3.0])


def test_sink_gets_the_rows_in_blocks(flight, monkeypatch) -> None:
    imu, master, ins = flight
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 6)
    cfg = TAConfig(attitude_sigma_deg=1.0)
    whole = pipeline.run_segments(imu, master, ins, TASettings(method="urtss"), cfg=cfg)
    blocks: list[tuple] = []
    lean = pipeline.run_segments(imu, master, ins, TASettings(method="urtss"), cfg=cfg, sink=lambda *b: blocks.append(b))
    assert len(blocks) > 1 and lean.llh.shape == (0, 3) and lean.sigma.shape == (0, 9)
    assert np.array_equal(lean.t_s, whole.t_s) and np.array_equal(lean.flags, whole.flags)
    # the epoch estimates are not kept with a sink; what the products need from them is
    assert lean.x.shape == (0, whole.x.shape[1]) and lean.P.shape == (0, *whole.P.shape[1:]) and whole.x.shape[0] > 1
    assert lean.installation == whole.installation and np.array_equal(lean.epochs_s, whole.epochs_s)
    assert lean.qc is not None and whole.qc is not None
    assert all(np.array_equal(getattr(lean.qc, f), getattr(whole.qc, f), equal_nan=True) for f in ("nis", "dof", "sep", "sep_norm", "nz2"))
    for i, name in enumerate(("t_s", "llh", "vel_n_mps", "q_nb", "sigma")):
        assert np.array_equal(np.concatenate([b[i] for b in blocks]), getattr(whole, name)), name


def test_installation_states_with_the_re_integrated_nominal(flight, monkeypatch) -> None:
    """The time-offset state's matches use the nominal's acceleration before the epoch and its
    output shift moves rows across blocks: the same result with the nominal kept or re-integrated."""
    imu, master, ins = flight
    ins = replace(ins, time_offset_sigma_s=0.002, lever_arm_sigma_m=0.05)
    cfg = TAConfig(attitude_sigma_deg=1.0, master_error_tau_s=30.0)
    monkeypatch.setattr(pipeline, "KEEP_NOMINAL", True)
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 10**6)
    stored = pipeline.run_segments(imu, master, ins, TASettings(method="urtss"), cfg=cfg)
    assert stored.installation["time_offset"]["sigma"][0] > 0
    monkeypatch.setattr(pipeline, "KEEP_NOMINAL", False)
    monkeypatch.setattr(pipeline, "APPLY_BLOCK", 3)
    _same(stored, pipeline.run_segments(imu, master, ins, TASettings(method="urtss"), cfg=cfg))


@pytest.mark.parametrize("M", [3, 4, 50, 1000])
def test_imu_rates_by_block_are_the_functions_at_once(M) -> None:
    from dpos_core.ta.antenna import ImuRates, rate_at, rate_interpolation_var

    rng = np.random.default_rng(M)
    t = np.cumsum(rng.uniform(0.004, 0.006, M))
    w = rng.normal(size=(M, 3))
    x = np.sort(rng.uniform(t[0] - 0.01, t[-1] + 0.01, 3 * M))  # before the first and after the last sample too
    want_w, want_v = rate_at(t, w, x), rate_interpolation_var(t, w, x)
    assert np.any(want_v > 0)
    for block in (1, 7, 100, 10**6):
        r = ImuRates(t, w)
        assert np.array_equal(np.concatenate([r.rate_at(x[i:i + block]) for i in range(0, x.size, block)]), want_w), block
        assert np.array_equal(np.concatenate([r.interpolation_var(x[i:i + block]) for i in range(0, x.size, block)]), want_v), block
    r = ImuRates(t, w)  # blocks out of order: the running sum restarts
    assert np.array_equal(np.concatenate([r.interpolation_var(x[x.size // 2:]), r.interpolation_var(x[:x.size // 2])]),
                          np.concatenate([want_v[x.size // 2:], want_v[:x.size // 2]]))


@pytest.mark.parametrize("method", ["urtss", "ups"])
def test_model_dropping_the_passed_epochs_gives_the_same_track(flight, method) -> None:
    """keep_epoch_data=False (what pipeline.run does): the forward pass and the smoother give the same
    numbers; the epochs and intervals the filter has passed are gone."""
    from dpos_core.filters.store import in_memory

    imu, master, ins = flight
    init = pipeline.initial_from_master(master, ins)
    out = []
    for keep in (True, False):
        m = TransferAlignmentModel(imu, master, ins, TAConfig(attitude_sigma_deg=1.0), init, keep_nominal=False, keep_epoch_data=keep)
        x0, P0 = m.prior()
        if method == "ups":
            tr = runners.run_upf(m, x0, P0, 12, np.random.default_rng(1))
            out.append((m, tr.mixture, *runners.rb_smooth(tr)[1:]))
        else:
            tr = runners.run_sigma_point_filter(m, x0, P0)
            out.append((m, tr, *runners.smooth_gaussian(tr)))
    (kept, a, xa, Pa), (lean, b, xb, Pb) = out
    for name in ("x_f", "P_f", "x_p", "P_p", "C", "corrections", "nu", "S"):
        assert np.array_equal(in_memory(getattr(a, name)), in_memory(getattr(b, name)), equal_nan=True), name
    assert np.array_equal(xa, xb) and np.array_equal(Pa, Pb)
    x = np.zeros(lean.n)
    kept.h(0, x), kept.f(0, x)  # (kept: still there)
    for call in (lambda: lean.h(0, x), lambda: lean.f(0, x), lambda: lean.Q(0), lambda: lean.nominal_at_epochs()):
        with pytest.raises(RuntimeError):
            call()
    assert sum(e is not None for e in lean._epochs) <= 2 and sum(e is not None for e in kept._epochs) == kept.n_epochs
