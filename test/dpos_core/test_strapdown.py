"""Strapdown mechanization: a perfect IMU integrates back to the truth.

Error budgets (stated per test) come from the algorithm's truncation errors; the mechanization is
second order in the step T (halving T quarters the error, checked below), so the bounds are
derived from the leading term and are not tuned to the measurement.
"""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.analytic_trajectory import CoordinatedTurnClimb
from dpos_core.attitude import attitude_error, dcm_to_quat, quat_conj, quat_mul, quat_to_dcm, rotvec_to_dcm
from dpos_core.frames import C_nb_from_hpr, _rx
from dpos_core.kinematics import imu_from_ecef_kinematics, integrate_increments, nav_from_ecef
from dpos_core.series import NavSeries
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.units import DEG

LAT0, LON0, H0 = 40.0 * DEG, 116.0 * DEG, 500.0


def _errors(out: NavSeries, llh: np.ndarray, vel: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Max |error| over the run: position ENU [m] (3,), velocity [m/s] (3,), attitude phi [rad] (3,)."""
    r_m, r_n = earth.radii_of_curvature(llh[:, 0])
    d = out.llh - llh
    dp = np.stack([d[:, 1] * (r_n + llh[:, 2]) * np.cos(llh[:, 0]), d[:, 0] * (r_m + llh[:, 2]), d[:, 2]], axis=1)
    return (
        np.abs(dp).max(axis=0),
        np.abs(out.vel_n_mps - vel).max(axis=0),
        np.abs(attitude_error(out.C_nb, C)).max(axis=0),
    )


@pytest.mark.parametrize("mode", ["increments", "rates"])
def test_perfect_imu_at_rest_for_one_hour(mode: str) -> None:
    """At rest at 40N, 200 Hz, 1 h: within 1 cm, 1 mm/s, 1 urad of the start.

    The IMU senses Earth rate and gravity exactly; the mechanization must cancel them to
    rounding, despite the unstable vertical channel (time constant sqrt(R/2g) ~ 570 s).
    """
    C = C_nb_from_hpr(30 * DEG, 2 * DEG, -1 * DEG)
    w_b = C.T @ earth.earth_rate_n(LAT0)
    f_b = C.T @ np.array([0.0, 0.0, earth.normal_gravity(LAT0, H0)])
    fs, n = 200.0, 720000
    s0 = NavState(0.0, dcm_to_quat(C), np.zeros(3), [LAT0, LON0, H0])
    sd = Strapdown(s0)
    if mode == "increments":
        out = sd.run_increments(np.arange(1, n + 1) / fs, np.tile(w_b / fs, (n, 1)), np.tile(f_b / fs, (n, 1)))
    else:
        out = sd.run_rates(np.arange(n + 1) / fs, np.tile(w_b, (n + 1, 1)), np.tile(f_b, (n + 1, 1)))
    pos, vel, phi = _errors(out, np.tile([LAT0, LON0, H0], (len(out), 1)), np.zeros((len(out), 3)), np.tile(C, (len(out), 1, 1)))
    assert out.t_s[-1] == pytest.approx(3600.0)
    assert pos.max() < 0.01, pos
    assert vel.max() < 1e-3, vel
    assert phi.max() < 1e-6, phi


def _analytic_run(fs: float, duration_s: float, mode: str = "increments", **kw: bool) -> tuple[np.ndarray, ...]:
    traj = CoordinatedTurnClimb()
    t = np.arange(0.0, duration_s + 0.5 / fs, 1.0 / fs)
    llh, vel, C = traj.truth(t)
    s0 = NavState(0.0, dcm_to_quat(C[0]), vel[0], llh[0])
    sd = Strapdown(s0, **kw)
    if mode == "increments":
        dth, dv = integrate_increments(traj.imu_rates, t)
        out = sd.run_increments(t[1:], dth, dv)
        return _errors(out, llh[1:], vel[1:], C[1:])
    om, f = traj.imu_rates(t)
    out = sd.run_rates(t, om, f)
    return _errors(out, llh, vel, C)


@pytest.mark.parametrize("mode", ["increments", "rates"])
def test_perfect_imu_on_coordinated_turn_with_climbs(mode: str) -> None:
    """100 m/s, 30 deg bank (turn rate 0.0566 rad/s = 3.24 deg/s, 5.4 full circles), +-150 m sinusoidal climbs
    (period 120 s, pitch up to +-4.5 deg), 600 s at 200 Hz, closed-form truth.

    Position: the trapezoidal position update has a local error of T^3/12 |jerk| with
    |jerk| = V r^2 = 0.32 m/s^3, i.e. 3.3e-9 m per step and N T^3/12 |jerk| = 4.0e-4 m after
    120,000 steps; bound 2e-3 m (5x).  Velocity and attitude: the second-order rotation,
    sculling and coning terms leave O(T^2) global errors ~ (r T)^2 |f| t ~ 5e-6 m/s and
    ~ (r T)^2 r t ~ 1e-9 rad; bounds 3e-5 m/s and 5e-9 rad.
    """
    pos, vel, phi = _analytic_run(200.0, 600.0, mode)
    assert pos.max() < 2e-3, pos
    assert vel.max() < 3e-5, vel
    assert phi.max() < 5e-9, phi


def test_mechanization_is_second_order() -> None:
    """Halving the step divides the final errors by ~4."""
    e100 = _analytic_run(100.0, 300.0)
    e200 = _analytic_run(200.0, 300.0)
    for a, b in zip(e100, e200):
        ratio = a.max() / b.max()
        assert 3.5 < ratio < 4.5, ratio


def _oscillating_body(kind: str):
    """Body at rest at LAT0/LON0/H0 with a coning or sculling motion (closed form)."""
    C_en0 = earth.C_en(LAT0, LON0)
    p0 = earth.geodetic_to_ecef(LAT0, LON0, H0)
    W = 2 * np.pi * (5.0 if kind == "coning" else 4.0)

    def kin(t: np.ndarray):
        t = np.asarray(t, dtype=float)
        z = np.zeros_like(t)
        if kind == "coning":  # body axis precessing on a 1.15 deg half-angle cone at 5 Hz
            s, c = np.sin(0.01), np.cos(0.01)
            q = np.stack([np.full_like(t, c), s * np.cos(W * t), s * np.sin(W * t), z], -1)
            qd = np.stack([z, -s * W * np.sin(W * t), s * W * np.cos(W * t), z], -1)
            om = 2.0 * quat_mul(quat_conj(q), qd)[..., 1:]
            C_wb, p_w = quat_to_dcm(q), np.zeros((t.size, 3))
            v_w = a_w = p_w
        else:  # roll angle and lateral acceleration in phase at 4 Hz: rectified vertical force
            phi0, a0 = 0.02, 2.0
            C_wb = _rx(phi0 * np.sin(W * t))
            om = np.stack([phi0 * W * np.cos(W * t), z, z], -1)
            p_w = np.stack([z, -a0 / W**2 * np.sin(W * t), z], -1)
            v_w = np.stack([z, -a0 / W * np.cos(W * t), z], -1)
            a_w = np.stack([z, a0 * np.sin(W * t), z], -1)
        return p0 + p_w @ C_en0.T, v_w @ C_en0.T, a_w @ C_en0.T, C_en0 @ C_wb, om

    return kin


@pytest.mark.parametrize("kind", ["coning", "sculling"])
def test_coning_and_sculling_compensation(kind: str) -> None:
    """On a coning (sculling) motion at 100 Hz, the compensation removes most of the attitude
    (velocity) drift that the uncompensated algorithm accumulates."""
    kin = _oscillating_body(kind)
    fs = 100.0
    t = np.arange(0.0, 60.0 + 0.5 / fs, 1.0 / fs)
    p_e, v_e, _, C_eb, _ = kin(t)
    llh, vel, C = nav_from_ecef(p_e, v_e, C_eb)
    dth, dv = integrate_increments(lambda tt: imu_from_ecef_kinematics(*kin(tt)), t)
    s0 = NavState(0.0, dcm_to_quat(C[0]), vel[0], llh[0])
    errs = {}
    for on in (True, False):
        flags = {"coning": on} if kind == "coning" else {"sculling": on}
        out = Strapdown(s0, **flags).run_increments(t[1:], dth, dv)
        errs[on] = _errors(out, llh[1:], vel[1:], C[1:])
    idx = 2 if kind == "coning" else 1  # attitude for coning, velocity for sculling
    assert errs[True][idx].max() * 10.0 < errs[False][idx].max(), (errs[True][idx], errs[False][idx])


def test_chunked_integration_equals_one_call() -> None:
    traj = CoordinatedTurnClimb()
    fs = 100.0
    t = np.arange(0.0, 60.0 + 0.5 / fs, 1.0 / fs)
    llh, vel, C = traj.truth(t[:1])
    dth, dv = integrate_increments(traj.imu_rates, t)
    s0 = NavState(0.0, dcm_to_quat(C[0]), vel[0], llh[0])
    whole = Strapdown(s0).run_increments(t[1:], dth, dv)
    sd = Strapdown(s0)
    cuts = [0, 1, 2, 57, 100, 3001, 6000]
    parts = [sd.run_increments(t[1:][a:b], dth[a:b], dv[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    chunked = NavSeries.concatenate(parts)
    np.testing.assert_array_equal(chunked.t_s, whole.t_s)
    np.testing.assert_allclose(chunked.q_nb, whole.q_nb, atol=1e-15)
    np.testing.assert_allclose(chunked.vel_n_mps, whole.vel_n_mps, atol=1e-12)
    np.testing.assert_allclose(chunked.llh, whole.llh, atol=1e-12)
    # rate input likewise
    om, f = traj.imu_rates(t)
    whole_r = Strapdown(s0).run_rates(t, om, f)
    sd = Strapdown(s0)
    parts = [sd.run_rates(t[a:b], om[a:b], f[a:b]) for a, b in zip([0, 1, 333, 4000], [1, 333, 4000, 6001])]
    np.testing.assert_allclose(NavSeries.concatenate(parts).llh, whole_r.llh, atol=1e-12)


def test_closed_loop_correction_restores_the_truth() -> None:
    """Start with 5 deg / 2 m/s / 30 m errors, integrate 20 s, feed back the exact errors at that
    epoch with the papers' sign convention: the state equals the truth and stays on it."""
    traj = CoordinatedTurnClimb()
    fs = 100.0
    t = np.arange(0.0, 60.0 + 0.5 / fs, 1.0 / fs)
    llh, vel, C = traj.truth(t)
    dth, dv = integrate_increments(traj.imu_rates, t)
    phi0 = np.array([3.0, -2.0, 5.0]) * DEG
    r_m, r_n = earth.radii_of_curvature(llh[0, 0])
    s0 = NavState(
        0.0,
        dcm_to_quat(rotvec_to_dcm(-phi0) @ C[0]),
        vel[0] + [2.0, -1.0, 0.5],
        llh[0] + [30.0 / r_m, -20.0 / (r_n * np.cos(llh[0, 0])), 10.0],
    )
    sd = Strapdown(s0)
    k = 2000
    first = sd.run_increments(t[1 : k + 1], dth[:k], dv[:k])
    est = first.state(-1)
    assert np.abs(attitude_error(est.C_nb, C[k])).max() > 1 * DEG  # the errors did grow
    sd.correct(
        phi_n_rad=attitude_error(est.C_nb, C[k]),
        dvel_n_mps=est.vel_n_mps - vel[k],
        dllh=est.llh - llh[k],
    )
    s = sd.state
    np.testing.assert_allclose(s.C_nb, C[k], atol=1e-12)
    np.testing.assert_allclose(s.vel_n_mps, vel[k], atol=1e-12)
    np.testing.assert_allclose(s.llh, llh[k], atol=1e-12)
    rest = sd.run_increments(t[k + 1 :], dth[k:], dv[k:])
    pos, v, phi = _errors(rest, llh[k + 1 :], vel[k + 1 :], C[k + 1 :])
    # 40 s at 100 Hz: 4x the 200 Hz trapezoid budget per second of flight
    assert pos.max() < 2e-3 and v.max() < 3e-5 and phi.max() < 5e-9, (pos, v, phi)


def test_bad_input_is_rejected_with_a_clear_error() -> None:
    s0 = NavState(0.0, [1.0, 0, 0, 0], np.zeros(3), [LAT0, LON0, H0])
    sd = Strapdown(s0)
    good = np.zeros((3, 3))
    bad = good.copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="dtheta_rad.*non-finite.*index 1"):
        sd.run_increments([0.01, 0.02, 0.03], bad, good)
    with pytest.raises(ValueError, match="strictly increasing"):
        sd.run_increments([0.01, 0.03, 0.02], good, good)
    with pytest.raises(ValueError, match="strictly increasing"):
        sd.run_increments([0.01, 0.01, 0.02], good, good)
    with pytest.raises(ValueError, match="shape"):
        sd.run_increments([0.01, 0.02, 0.03], np.zeros((3, 2)), good)
    with pytest.raises(ValueError, match="first rate sample"):
        Strapdown(s0).run_rates([0.5, 0.6, 0.7], good, good)
    with pytest.raises(ValueError, match="strictly increasing"):
        Strapdown(s0).run_rates([0.0, 0.6, 0.6], good, good)
    with pytest.raises(ValueError, match="not finite"):
        NavState(0.0, [1.0, 0, 0, 0], [np.nan, 0, 0], [LAT0, LON0, H0])
    # nothing was integrated by the rejected calls
    assert sd.state.t_s == 0.0
    out = sd.run_increments([0.01], good[:1], good[:1])
    assert len(out) == 1
    with pytest.raises(ValueError, match="cannot mix"):
        sd.run_rates([0.01, 0.02], good[:2], good[:2])


def test_interval_sums_kernel_is_the_numpy_formula() -> None:
    """_error_kernel.interval_sums (IntervalIntegrals.add) = the midpoint rule written with numpy:
    ``sum_k C_mid_k f_k dt_k`` and ``sum_k C_mid_k dt_k``, ``C_mid_k = (C_k + C_{k-1}) / 2``."""
    from dpos_core import _error_kernel
    from dpos_core.attitude import quat_normalize, quat_to_dcm

    rng = np.random.default_rng(11)
    q = quat_normalize(rng.normal(size=(30, 4)))
    f, dt = rng.normal(size=(29, 3)) * 10.0, rng.uniform(0.004, 0.006, size=29)
    F_n, C_int = np.empty(3), np.empty((3, 3))
    _error_kernel.interval_sums(q[0], np.ascontiguousarray(q[1:]), f, dt, F_n, C_int)
    C = quat_to_dcm(q)
    C_mid = 0.5 * (C[1:] + C[:-1])
    np.testing.assert_allclose(F_n, np.einsum("kij,kj->i", C_mid, f * dt[:, None]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(C_int, np.einsum("kij,k->ij", C_mid, dt), rtol=1e-12, atol=1e-14)


def test_run_valid_increments_is_run_increments() -> None:
    """Strapdown.run_valid_increments (no checks) = run_increments, bit for bit, chunk after chunk."""
    from dpos_core.strapdown import NavState, Strapdown

    rng = np.random.default_rng(12)
    s0 = NavState(0.0, np.array([1.0, 0.0, 0.0, 0.0]), np.array([50.0, 10.0, 0.0]), np.array([0.6, 1.9, 1000.0]))
    t = np.arange(1, 41) * 0.01
    dth, dv = rng.normal(size=(40, 3)) * 1e-3, rng.normal(size=(40, 3)) * 0.1 + np.array([0.0, 0.0, 0.098])
    a, b = Strapdown(s0), Strapdown(s0)
    for lo, hi in ((0, 15), (15, 40)):
        ra = a.run_increments(t[lo:hi], dth[lo:hi], dv[lo:hi])
        rb = b.run_valid_increments(t[lo:hi], np.diff(t[lo:hi], prepend=t[lo - 1] if lo else 0.0), dth[lo:hi], dv[lo:hi])
        for x, y in ((ra.q_nb, rb.q_nb), (ra.vel_n_mps, rb.vel_n_mps), (ra.llh, rb.llh), (ra.t_s, rb.t_s)):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a.llh, b.llh)
        np.testing.assert_array_equal(a.state.llh, a.llh)
