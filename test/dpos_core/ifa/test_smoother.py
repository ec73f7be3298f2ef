"""The main POS smoothed offline (dpos_core.ifa.smoother): RTS over the in-flight alignment."""

from __future__ import annotations

import types
import warnings

import numpy as np
import pytest

from dpos_core.attitude import quat_to_dcm
from dpos_core.evaluation.ifa import filter_config, initial_state
from dpos_core.filters.dd2 import dd2_predict, dd2_update
from dpos_core.filters.gaussian import kf_predict, kf_update, rts_smooth
from dpos_core.filters.linalg import chol
from dpos_core.filters.runners import smooth_gaussian
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.pipeline import SmootherStep, _Engine, run
from dpos_core.ifa.smoother import segments, smooth, track_of
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
