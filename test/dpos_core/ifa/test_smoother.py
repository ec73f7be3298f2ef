"""The main POS smoothed offline (dpos_core.ifa.smoother): RTS over the in-flight alignment."""

from __future__ import annotations

import types
import warnings

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import attitude_error, quat_to_dcm
from dpos_core.evaluation.ifa import filter_config, initial_state
from dpos_core.filters.dd2 import dd2_predict, dd2_update
from dpos_core.filters.gaussian import kf_predict, kf_update, rts_smooth
from dpos_core.filters.linalg import chol
from dpos_core.filters.runners import smooth_gaussian
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.pipeline import SmootherStep, _Engine, run
from dpos_core.ifa.reference import initial_state as data_initial_state
from dpos_core.ifa.smoother import segments, smooth, track_of
from dpos_core.series import GnssSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG


def _linear(rng: np.random.Generator, n: int = 4, p: int = 2):
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    A = rng.standard_normal((n, n))
    Q = 0.05 * A @ A.T + 0.01 * np.eye(n)
    H = rng.standard_normal((p, n))
    R = 0.3 * np.eye(p)
    return F, Q, H, R


def test_closed_loop_dd2_steps_smooth_to_the_open_loop_rts() -> None:
    """Linear-Gaussian model: a closed-loop DD2 (every update fed back, x -> x - c, the steps
    recorded as the engine does, prediction and cross-covariance re-expressed by the shift's
    divided-difference linearization) smoothed by track_of + smooth_gaussian equals the open-loop
    Kalman filter's RTS, once the fed-back corrections are added back."""
    rng = np.random.default_rng(7)
    F, Q, H, R = _linear(rng)
    n, K = F.shape[0], 30
    ys = rng.standard_normal((K, H.shape[0]))
    x0, P0 = rng.standard_normal(n), np.eye(n) * 2.0
    # open loop
    xk, Pk = x0.copy(), P0.copy()
    xf, Pf, xp, Pp, Cs = [], [], [], [], []
    for k in range(K):
        if k > 0:
            pr = kf_predict(xk, Pk, F, Q)
            xp.append(pr.x)
            Pp.append(pr.P)
            Cs.append(pr.C)
            xk, Pk = pr.x, pr.P
        up = kf_update(xk, Pk, ys[k], H, R)
        xk, Pk = up.x, up.P
        xf.append(xk)
        Pf.append(Pk)
    xs_ref, Ps_ref = rts_smooth(np.array(xf), np.array(Pf), np.array(xp), np.array(Pp), np.array(Cs))
    # closed loop: the measurement of the error state is y - H o (o: the corrections so far, propagated)
    eng = types.SimpleNamespace(method="dd2")
    x, S, o = x0.copy(), chol(P0), np.zeros(n)
    steps: list[SmootherStep] = []
    offsets = []
    for k in range(K):
        pred, C = (x.copy(), S.copy(), S @ S.T), S @ S.T
        if k > 0:
            pd = dd2_predict(x, S, lambda X: X @ F.T, chol(Q))
            x, S, C = pd.x, pd.S, pd.C
            o = F @ o
            pred = (x.copy(), S.copy(), S @ S.T)
        ud = dd2_update(x, S, ys[k] - H @ o, lambda X: X @ H.T, chol(R))
        c = ud.x.copy()
        o = o + c
        x, S = ud.x - c, ud.S
        st = _Engine._smoother_step(eng, 0.0, float(k), pred, C, lambda X, c=c: X - c, x, S @ S.T, c)  # type: ignore[arg-type]
        if k == 0:
            st = SmootherStep(0.0, x.copy(), S @ S.T, c)
        steps.append(st)
        offsets.append(o.copy())
    xs, Ps = smooth_gaussian(track_of(steps, 0, K - 1))
    np.testing.assert_allclose(xs + np.array(offsets), xs_ref, atol=1e-8, rtol=0)
    np.testing.assert_allclose(Ps, Ps_ref, atol=1e-8, rtol=0)


def test_segments_break_at_a_restart() -> None:
    z = np.zeros(2)
    P = np.eye(2)
    steps = [SmootherStep(float(k), z, P, z, z, P, P) for k in range(6)]
    steps[2].restart = (z + 1.0, 3.0 * P)
    assert segments(steps) == [(0, 2), (2, 5)]
    tr = track_of(steps, 2, 5)
    np.testing.assert_allclose(tr.x_f[0], 1.0)  # the chain after the restart starts from it
    np.testing.assert_allclose(tr.P_f[0], 3.0 * P)
    assert tr.x_p.shape == (3, 2)


@pytest.fixture(scope="module")
def flight():
    """paper_ifa seed 1, 200 s, 30 deg initial heading error, ADD2 with the smoother's record."""
    sc = load_scenario("paper_ifa")
    ss = SimulatedSession(sc, 1, 200.0)
    imu, gnss = ss.master_imu(), ss.gnss()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run(imu, gnss, sc.aircraft.gnss_lever_arm_m, filter_config(sc), "add2", initial_state(ss, 30.0), record_smoother=True)
    sm = smooth(res, imu)
    return res, sm, ss.truth("master", sm.nav.t_s)


def _att_err_deg(nav, truth) -> np.ndarray:
    return hpr_error(hpr_from_C_nb(quat_to_dcm(nav.q_nb)), hpr_from_C_nb(quat_to_dcm(truth.q_nb))) / DEG


def test_smoothed_main_pos_beats_the_forward_one_mid_flight(flight) -> None:
    """Measured (100-150 s, RMSE deg): forward heading / pitch / roll 0.165 / 0.019 / 0.011,
    smoothed 0.073 / 0.0072 / 0.0076."""
    res, sm, truth = flight
    w = (sm.nav.t_s >= 100.0) & (sm.nav.t_s <= 150.0)
    rms = lambda e: np.sqrt(np.mean(e[w] ** 2, axis=0))  # noqa: E731
    fwd, smo = rms(_att_err_deg(sm.forward, truth)), rms(_att_err_deg(sm.nav, truth))
    assert np.all(smo < fwd), (fwd, smo)
    assert smo[0] < 0.6 * fwd[0] and smo[1] < 0.6 * fwd[1], (fwd, smo)
    # the smoothed covariance is below the forward one there, and consistent in size with the errors
    sig_s = np.sqrt(np.diagonal(sm.nav.att_cov[w], axis1=1, axis2=2))
    sig_f = np.sqrt(np.diagonal(sm.forward.att_cov[w], axis1=1, axis2=2))
    assert np.all(sig_s <= sig_f + 1e-12)
    assert sm.nav.omega_eb_b_radps is not None and sm.nav.pos_cov is not None and sm.nav.vel_cov is not None
    # the coarse phase (5-20 s, before the first turn): the chain ends at the fine phase's smoothed
    # estimate, so the 30 deg heading error is gone there too (measured: forward 33 deg, smoothed 0.073 deg)
    c = (sm.nav.t_s >= 5.0) & (sm.nav.t_s <= 20.0)
    h_f = np.sqrt(np.mean(_att_err_deg(sm.forward, truth)[c, 0] ** 2))
    h_s = np.sqrt(np.mean(_att_err_deg(sm.nav, truth)[c, 0] ** 2))
    assert h_f > 10.0 and h_s < 0.5, (h_f, h_s)


def test_smoothed_equals_forward_at_the_last_epoch(flight) -> None:
    res, sm, _ = flight
    # the forward series is the run's own navigation (the final hypothesis, every row after the pruning)
    late = sm.forward.t_s >= 60.0
    i = np.searchsorted(res.t_s, sm.forward.t_s[late])
    np.testing.assert_allclose(sm.forward.llh[late], res.llh[i], atol=1e-10, rtol=0)
    np.testing.assert_allclose(quat_to_dcm(sm.forward.q_nb[late]), quat_to_dcm(res.q_nb[i]), atol=1e-10, rtol=0)  # q or -q
    last = int(np.searchsorted(sm.nav.t_s, res.epochs_s[-1] - 1e-9))
    np.testing.assert_allclose(quat_to_dcm(sm.nav.q_nb[last:]), quat_to_dcm(sm.forward.q_nb[last:]), atol=1e-10, rtol=0)
    np.testing.assert_allclose(sm.nav.vel_n_mps[last:], sm.forward.vel_n_mps[last:], atol=1e-8, rtol=0)
    np.testing.assert_allclose(sm.nav.llh[last:, 2], sm.forward.llh[last:, 2], atol=1e-7, rtol=0)
    np.testing.assert_allclose(sm.nav.llh[last:, :2], sm.forward.llh[last:, :2], atol=1e-12, rtol=0)


def test_smooth_needs_the_record() -> None:
    res = types.SimpleNamespace(engine=None)
    with pytest.raises(ValueError, match="record_smoother"):
        smooth(res, None)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def vehicle_outage():
    """mems_vehicle seed 3 (a MEMS unit, 1 Hz GNSS, a 30 s outage at 150-180 s while turning),
    started from the data (standing, any heading), the filter that knows the unit (oracle: its
    covariance can be held to the truth), ADD2 with the smoother's record."""
    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 3)
    imu, gnss = ss.master_imu(), ss.gnss()
    cfg = filter_config(sc, oracle=True)
    g = GnssSeries(gnss.t_s - cfg.gnss_time_offset_s, gnss.llh, gnss.pos_sigma_m, gnss.vel_n_mps, gnss.vel_sigma_mps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        init = data_initial_state(imu, g, 0.0, lever_arm_m=np.asarray(sc.aircraft.gnss_lever_arm_m))
        res = run(imu, gnss, sc.aircraft.gnss_lever_arm_m, cfg, "add2", init, record_smoother=True)
    sm = smooth(res, imu)
    tr = ss.truth("master", sm.nav.t_s)
    err = {k: np.array([earth.enu_between(a, b) for a, b in zip(n.llh, tr.llh)]) for k, n in (("s", sm.nav), ("f", sm.forward))}
    return sm, tr, err


@pytest.mark.slow
def test_smoothed_bridges_a_30_s_outage_from_both_ends(vehicle_outage) -> None:
    """Measured, horizontal rms / max against the truth [m]: 60-150 s forward 0.167 / 0.34, smoothed
    0.099 / 0.15; the outage 150-180 s forward 3.40 / 10.7, smoothed 0.49 / 0.71; 180-240 s forward
    0.28 / 0.62, smoothed 0.17 / 0.36."""
    sm, _, err = vehicle_outage
    t = sm.nav.t_s
    h = {k: np.hypot(e[:, 0], e[:, 1]) for k, e in err.items()}
    for lo, hi in ((60.0, 150.0), (150.0, 180.0), (180.0, 240.0)):
        m = (t >= lo) & (t < hi)
        rms = {k: float(np.sqrt(np.mean(v[m] ** 2))) for k, v in h.items()}
        assert rms["s"] < rms["f"] and h["s"][m].max() < h["f"][m].max(), (lo, rms)
    o = (t >= 150.0) & (t < 180.0)
    assert np.sqrt(np.mean(h["s"][o] ** 2)) < 0.25 * np.sqrt(np.mean(h["f"][o] ** 2))
    # the error does not grow towards the middle of the outage as a one-sided (forward) bridge does
    mid = (t >= 160.0) & (t < 170.0)
    assert h["s"][mid].max() < 1.0 < 3.0 < h["f"][o].max()


@pytest.mark.slow
def test_smoothed_covariance_is_consistent_and_the_interpolation_between_steps_holds(vehicle_outage) -> None:
    """NEES of the smoothed navigation against the truth at every IMU row after the alignment (3 per
    3-dof block when consistent; measured over 80-150 / 150-180 / 180-240 s: position 2.9 / 6.6 /
    4.6, velocity 3.2 / 2.1 / 5.1, attitude 4.6 / 4.8 / 2.8), errors within 3 sigma; and in the outage
    (time updates alone, 1.5 s apart) the error mid-way between two steps is that at the steps
    (measured rms 0.495 m against 0.492 m; 0.504 m with the position error interpolated linearly)."""
    sm, tr, err = vehicle_outage
    nav, t = sm.nav, sm.nav.t_s
    ev = nav.vel_n_mps - tr.vel_n_mps
    ea = attitude_error(quat_to_dcm(nav.q_nb), tr.C_nb)

    def nees(e: np.ndarray, P: np.ndarray) -> float:
        return float(np.mean(np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])))

    for lo, hi in ((80.0, 150.0), (150.0, 180.0), (180.0, 240.0)):
        m = (t >= lo) & (t < hi)
        for e, P in ((err["s"], nav.pos_cov), (ev, nav.vel_cov), (ea, nav.att_cov)):
            assert 0.5 < nees(e[m], P[m]) < 10.0, (lo, hi)
        sig = np.sqrt(np.diagonal(nav.pos_cov[m], axis1=1, axis2=2))
        assert np.all(np.mean(np.abs(err["s"][m]) <= 3.0 * sig, axis=0) >= 0.95), (lo, hi)
    o = (t >= 151.0) & (t < 179.0)
    T = sm.steps_s
    j = np.searchsorted(T, t[o])
    d = np.minimum(np.abs(t[o] - T[np.clip(j - 1, 0, None)]), np.abs(T[np.clip(j, 0, T.size - 1)] - t[o]))
    assert np.max(np.diff(T[(T > 150.0) & (T < 180.0)])) <= 1.5 + 1e-6  # the steps bridging the outage
    h = np.hypot(err["s"][o, 0], err["s"][o, 1])
    near, mid = np.sqrt(np.mean(h[d < 0.02] ** 2)), np.sqrt(np.mean(h[d > 0.5] ** 2))
    assert mid < 1.02 * near, (near, mid)
