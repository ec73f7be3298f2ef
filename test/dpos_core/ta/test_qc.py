"""Quality control without truth (dpos_core.ta.qc): NIS and its windowed test, the
forward/backward separation, the QC flags and the summary, on linear-Gaussian models."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.runners import run_sigma_point_filter, smooth_gaussian
from dpos_core.ta import flags as F
from dpos_core.ta import qc
from dpos_core.units import DEG


def _system(K: int, seed: int):
    """A 9-state system (3 x position/velocity/bias-like random walks) observed in 6 components at
    1 Hz: the shapes of the TA's first 9 states (the separation's groups)."""
    rng = np.random.default_rng(seed)
    n, p = 9, 6
    F_ = np.eye(n)
    F_[6:9, 3:6] = np.eye(3)  # position integrates velocity
    Q = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-4] * 3)
    H = np.zeros((p, n))
    H[0:3, 0:3] = np.eye(3)
    H[3:6, 6:9] = np.eye(3)
    R = np.diag([0.01] * 3 + [0.04] * 3)
    x = rng.normal(size=n) * 0.3
    ys = np.empty((K, p))
    for k in range(K):
        if k:
            x = F_ @ x + np.sqrt(np.diag(Q)) * rng.normal(size=n)
        ys[k] = H @ x + np.sqrt(np.diag(R)) * rng.normal(size=p)
    return F_, Q, H, R, ys, np.zeros(n), np.eye(n) * 0.3**2


def _run(K: int = 1200, seed: int = 0, r_scale: float = 1.0):
    F_, Q, H, R, ys, x0, P0 = _system(K, seed)
    tr = run_sigma_point_filter(LinearGaussianModel(F_, Q, H, R * r_scale, ys), x0, P0)
    xs, Ps = smooth_gaussian(tr)
    return qc.epoch_qc(np.arange(K, dtype=float), tr.nu, tr.S, tr.x_f, tr.P_f, xs, Ps)


def test_nis_of_a_consistent_filter_is_chi2_and_not_flagged() -> None:
    q = _run()
    assert np.all(q.dof == 6)
    assert abs(q.nis.mean() - 6.0) < 3 * np.sqrt(12.0 / q.nis.size)  # chi2_6: mean 6, variance 12
    lo, hi = qc.chi2_bounds(q.dof)
    out = np.mean((q.nis < lo) | (q.nis > hi))
    assert out < 0.025  # 1 % by chance
    side = qc.inconsistent(q.epochs_s, q.nis, q.dof)
    assert np.mean(side > 0) < 0.03 and np.mean(side != 0) < 0.05
    np.testing.assert_allclose(np.nanmean(q.nz2, axis=0), 1.0, atol=0.15)
    s = qc.summarize(q.epochs_s, np.ones((q.epochs_s.size, 9)), F.none(q.epochs_s.size), q)
    assert s["verdict"] == "ok", s


def test_r_too_small_by_ten_lights_the_flag() -> None:
    q = _run(r_scale=0.1)
    side = qc.inconsistent(q.epochs_s, q.nis, q.dof)
    assert np.mean(side > 0) > 0.9
    fl = qc.row_flags(np.arange(0.0, 1199.0, 0.1), q)
    assert np.mean((fl & F.INCONSISTENT_INNOVATIONS) != 0) > 0.9
    s = qc.summarize(q.epochs_s, np.ones((q.epochs_s.size, 9)), qc.row_flags(q.epochs_s, q), q)
    assert s["verdict"].startswith("check: inconsistent innovations") and "optimistic" in s["verdict"], s
    assert s["flags"]["inconsistent_innovations"]["fraction"] > 0.9


def test_r_too_large_is_a_note_not_a_flag() -> None:
    q = _run(r_scale=10.0)
    assert np.mean(qc.inconsistent(q.epochs_s, q.nis, q.dof) < 0) > 0.9
    assert not np.any(qc.row_flags(q.epochs_s, q))
    s = qc.summarize(q.epochs_s, np.ones((q.epochs_s.size, 9)), None, q)
    assert s["verdict"] == "ok" and any("smaller than their covariance" in n for n in s["notes"]), s


def test_separation_zero_at_the_last_epoch_and_chi2_elsewhere() -> None:
    q = _run(K=400)
    assert q.smoothed and q.sep.shape == (400, 3)
    np.testing.assert_allclose(q.sep_norm[-1], 0.0, atol=1e-12)
    assert np.all(q.sep_dof[-1] == 0) and np.all(np.isnan(q.sep[-1]))
    has = q.sep_dof > 0
    assert has[:-1].mean() > 0.9
    ratio = np.sum(q.sep[has]) / np.sum(q.sep_dof[has])
    assert 0.8 < ratio < 1.2, ratio  # chi2 per dof: 1
    s = qc.summarize(q.epochs_s, np.ones((400, 9)), None, q)
    for g in ("attitude", "velocity", "position"):
        assert s["separation"][g]["beyond_bound_fraction"] < 0.03, s["separation"]
        assert s["separation"][g]["max_sigmas"] < 3.0


def test_separation_of_a_wrong_model_is_large() -> None:
    """A filter whose R is 10x too small trusts each fix, and the later fixes pull the smoothed
    estimate beyond what P_f - P_s allows."""
    q = _run(K=400, r_scale=0.1)
    has = q.sep_dof > 0
    assert np.sum(q.sep[has]) / np.sum(q.sep_dof[has]) > 2.0


def test_correlation_factors_white_and_correlated_measurement_errors() -> None:
    """A filter whose measurement errors are white has white innovations: every component's
    ``1 + 2 sum rho`` about 1.  Measurement errors of the first three components an AR(1) at
    rho 0.9 per epoch (a main POS's errors correlated in time, of the variance R says) give factors
    of several there (the AR(1)'s own (1 + rho) / (1 - rho) = 19, less what the filter's states
    take up), above the others' (which see them only through the states); ``correlation_scale`` is their square root per output
    column, the position's the velocity's without position matching (6 components)."""
    q = _run(K=1200)
    f = qc.correlation_factors(q)
    assert f.shape == (6,) and np.all(f >= 1.0) and np.all(f < 1.6), f
    F_, Q, H, R, ys, x0, P0 = _system(1200, 1)
    rng = np.random.default_rng(2)
    e = np.zeros((1200, 3))
    for k in range(1, 1200):
        e[k] = 0.9 * e[k - 1] + np.sqrt(1 - 0.9**2) * 0.1 * rng.normal(size=3)
    ys = ys.copy()
    ys[:, :3] += e
    tr = run_sigma_point_filter(LinearGaussianModel(F_, Q, H, R * 2.0, ys), x0, P0)
    qa = qc.epoch_qc(np.arange(1200, dtype=float), tr.nu, tr.S, tr.x_f, tr.P_f)
    fa = qc.correlation_factors(qa)
    assert np.all(fa[:3] > 3.0) and fa[:3].min() > fa[3:].max(), fa
    sc = qc.correlation_scale(qa)
    np.testing.assert_allclose(sc[:6], np.sqrt(fa))
    np.testing.assert_allclose(sc[6:], sc[3:6])
    assert np.all(qc.correlation_scale(None) == 1.0)


def test_nis_handles_unmeasured_components_and_epochs() -> None:
    nu = np.array([[1.0, 2.0], [np.nan, 2.0], [np.nan, np.nan]])
    S = np.array([np.diag([1.0, 4.0]), np.diag([1.0, 4.0]), np.full((2, 2), np.nan)])
    v, dof = qc.nis(nu, S)
    np.testing.assert_allclose(v[:2], [2.0, 1.0])
    assert np.isnan(v[2]) and list(dof) == [2, 1, 0]


def test_rows_from_epochs_and_master_unaligned() -> None:
    ep = np.array([0.0, 1.0, 2.0, 3.0])
    rows = np.arange(0.0, 3.01, 0.25)
    got = qc.rows_from_epochs(ep, np.array([False, False, True, False]), rows)
    np.testing.assert_array_equal(rows[got], [1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75])
    sig = np.full(31, 0.01 * DEG)
    sig[10:15] = 0.5 * DEG  # 1.0-1.4 s
    tm = np.asarray(np.arange(31) * 0.1, dtype=np.float64)
    un = qc.master_unaligned(tm, sig, rows, 0.1 * DEG)
    np.testing.assert_array_equal(rows[un], [1.0, 1.25])  # a row between two master epochs: either unaligned
    fl = qc.row_flags(rows, None, tm, sig)
    assert np.all((fl[un] & F.MASTER_UNALIGNED) != 0) and not np.any(fl[~un])
    s = qc.summarize(rows, np.ones((rows.size, 9)), fl)
    assert s["verdict"].startswith("check: main POS unaligned"), s


@pytest.mark.parametrize("vf, verdict", [(1.2, "ok"), (9.0, "check")])
def test_fit_antenna_summary_reports_the_fit(vf: float, verdict: str) -> None:
    wing = {"degree": {"theta_x": 2}, "cv": {"theta_x": {"1": {"score": 3.0}, "2": {"score": 1.1}}},
            "variance_factor": {"theta_x": vf}}
    t = np.asarray(np.arange(100) * 0.1, dtype=np.float64)
    s = qc.summarize(t, np.ones((100, 9)), F.none(100) | np.uint32(F.WING_FIT), None, wing)
    assert "nis" not in s and s["wing_fit"]["cv_score"] == {"theta_x": 1.1}
    assert s["verdict"].startswith(verdict)
    assert s["flags"]["wing_fit"]["fraction"] == pytest.approx(1.0)
    carried = F.none(100) | np.uint32(F.WING_FIT | F.INCONSISTENT_INNOVATIONS)  # from its sub-IMUs
    s = qc.summarize(t, np.ones((100, 9)), carried, None, wing)
    assert s["verdict"].startswith("check") and "sub-IMUs of the fit with inconsistent innovations 10 s (100 %)" in s["verdict"]


@pytest.fixture(scope="module")
def short_flight():
    from dataclasses import replace

    from dpos_core.evaluation import ta as from_sim
    from dpos_core.sim.flight import Segment
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession

    sc = load_scenario("paper_su")
    sc = replace(sc, segments=(Segment(20.0, name="lead_in"), Segment(25.0, heading_change_deg=30.0, name="turn")))
    ss = SimulatedSession(sc, 1, None)
    return from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")


@pytest.mark.parametrize("method", ["urtss", "ups", "ukf"])
def test_pipeline_carries_the_epoch_qc(short_flight, method: str) -> None:
    """Every method's TAResult has the NIS of its 9 matches at the epochs and, for the smoothers,
    the separation (zero at the last epoch of each segment); across a gap the segments' measures
    are concatenated."""
    from dpos_core.ta import pipeline
    from dpos_core.ta.model import TAConfig
    from dpos_core.ta.pipeline import TASettings

    imu, master, ins = short_flight
    cut = imu.select((imu.t_s < 20.0) | (imu.t_s > 23.0))
    r = pipeline.run_segments(cut, master, ins, TASettings(method=method, particles=20), cfg=TAConfig(attitude_sigma_deg=1.0))
    q = r.qc
    assert q is not None and len(r.not_estimated) == 1
    np.testing.assert_array_equal(q.epochs_s, r.epochs_s)
    assert np.all(q.dof[1:] == 9) and np.all(np.isfinite(q.nis[1:]))
    assert 0.2 < np.nansum(q.nis) / q.dof.sum() < 2.0
    assert q.smoothed == (method != "ukf")
    if q.smoothed:
        last = [int(np.flatnonzero(q.epochs_s < 20.0)[-1]), q.epochs_s.size - 1]  # each segment's last epoch
        np.testing.assert_allclose(q.sep_norm[last], 0.0, atol=1e-9)
        assert np.all(np.isfinite(q.sep_norm)) and np.nanmax(q.sep / np.maximum(q.sep_dof, 1)) < 20.0
    else:
        assert np.all(np.isnan(q.sep))


def test_chi2_ppf_once_per_distinct_dof_is_the_elementwise_value() -> None:
    """chi2_ppf computes each distinct dof once: the same bits as gammaincinv element by element,
    any shape, NaN kept."""
    from scipy.special import gammaincinv

    rng = np.random.default_rng(3)
    d = rng.integers(1, 40, size=(50, 7)).astype(float)
    d[3, 2] = np.nan
    for q in (0.005, 0.5, 0.995):
        got = qc.chi2_ppf(q, d)
        assert got.shape == d.shape
        np.testing.assert_array_equal(got, 2.0 * gammaincinv(d / 2.0, q))
    assert qc.chi2_ppf(0.99, 3).shape == () and float(qc.chi2_ppf(0.99, 3)) == 2.0 * gammaincinv(1.5, 0.99)


def test_attitude_change_from_the_first_epoch() -> None:
    """A yaw of 90 deg at 3 deg/s from t = 10 s: the change from the first epoch, at the sample at or
    before each epoch."""
    t = np.arange(0.0, 60.0, 0.01)
    yaw = np.clip(t - 10.0, 0.0, 30.0) * 3.0 * DEG
    q = np.column_stack([np.cos(yaw / 2), np.zeros_like(t), np.zeros_like(t), np.sin(yaw / 2)])
    e = np.arange(0.0, 60.0, 1.0)
    a = qc.attitude_change(t, -q, e)  # (a quaternion's sign is no rotation)
    np.testing.assert_allclose(a, np.clip(e - 10.0, 0.0, 30.0) * 3.0 * DEG, atol=1e-9)
    assert qc.attitude_change(t, q, np.zeros(0)).size == 0


@pytest.mark.parametrize(("turn_deg", "says"), [(0.0, "no lever-arm error can show"), (2.0, "below about 2.9 m cannot show"),
                                               (20.0, "below about 0.29 m cannot show"), (60.0, None)])
def test_summary_says_when_the_data_cannot_check_the_lever_arm(turn_deg: float, says: str | None) -> None:
    q = _run(K=300)
    q.att_change = np.linspace(0.0, turn_deg * DEG, q.epochs_s.size)
    s = qc.summarize(q.epochs_s, np.ones((q.epochs_s.size, 9)), F.none(q.epochs_s.size), q)
    assert s["verdict"] == "ok" and abs(s["attitude_change_deg"] - turn_deg) < 1e-9
    note = [n for n in s["notes"] if "lever arm not checked by the data" in n]
    assert (note[0].count(says) == 1 if says else not note), s["notes"]
    assert qc.lever_arm_hidden_m(np.pi / 3) == pytest.approx(0.1) and qc.lever_arm_hidden_m(0.0) == np.inf
    both = qc.EpochQC.concat([q, q])
    assert both.att_change is not None and both.att_change.size == 2 * q.epochs_s.size
    q.att_change = None
    assert qc.EpochQC.concat([q, both]).att_change is None and "attitude_change_deg" not in qc.summarize(
        q.epochs_s, np.ones((q.epochs_s.size, 9)), None, q)


@pytest.fixture(scope="module")
def turning_flight():
    """paper_su's sub_r over 20 s straight, a 90 deg turn in 30 s, 30 s straight (80 s)."""
    from dataclasses import replace

    from dpos_core.evaluation import ta as from_sim
    from dpos_core.sim.flight import Segment
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession

    sc = load_scenario("paper_su")
    sc = replace(sc, segments=(Segment(20.0, name="lead_in"), Segment(30.0, heading_change_deg=90.0, name="turn"),
                               Segment(30.0, name="out")))
    ss = SimulatedSession(sc, 1, None)
    return from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")


@pytest.mark.parametrize(("dx_m", "straight", "verdict"), [(0.0, False, "ok"), (0.5, False, "check"), (0.2, False, "check"),
                                                           (0.0, True, "ok"), (0.5, True, "ok")])
def test_a_lever_arm_off_is_checked_through_a_turn(turning_flight, dx_m: float, straight: bool, verdict: str) -> None:
    """sub_r's configured lever arm dx_m off in x (the truth's unchanged): through a 90 deg turn the
    verdict is "check" (the forward/backward separation, the innovations), the honest arm "ok";
    over the straight first 20 s the error cannot show (the sub-IMU starts at the configured arm and
    follows it: docs/qc.md "Installation errors") and a note says the data did not check it."""
    from dataclasses import replace

    from dpos_core.ta import pipeline
    from dpos_core.ta.pipeline import TASettings

    imu, master, ins = turning_flight
    if straight:
        imu = imu.select(imu.t_s < 20.0)
    ins = replace(ins, lever_arm_m=np.asarray(ins.lever_arm_m, dtype=float) + np.array([dx_m, 0.0, 0.0]))
    r = pipeline.run_segments(imu, master, ins, TASettings(method="urtss"))
    assert r.qc is not None and r.qc.att_change is not None
    s = qc.summarize(r.qc.epochs_s, np.ones((r.qc.epochs_s.size, 9)), None, r.qc)
    assert s["verdict"].split(":")[0] == verdict, s["verdict"]
    assert any("lever arm not checked by the data" in n for n in s["notes"]) == straight, s["notes"]
    assert (s["attitude_change_deg"] > 80.0) == (not straight)
