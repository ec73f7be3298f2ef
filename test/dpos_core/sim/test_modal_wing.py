"""The modal wing: cantilever mode shapes, turbulence statistics, quasi-static
bending under the load factor, and sub-IMU samples consistent with the deformed truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import attitude_error, mount_dcm, rotvec_to_dcm
from dpos_core.config.aircraft import load_aircraft
from dpos_core.config.files import ConfigError
from dpos_core.config.flexure import ModalWing, WingMode
from dpos_core.sim.flexure import ModalRealization, bending_shape, load_factor, static_shape, torsion_shape
from dpos_core.sim.flight import Flight, FlightStart, Segment
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState, Strapdown


def _d(f, x: float, k: int, h: float = 1e-3) -> float:
    """k-th derivative by central differences (k <= 3)."""
    c = {1: [-0.5, 0, 0.5], 2: [1, -2, 1], 3: [-0.5, 1, 0, -1, 0.5]}[k]
    off = np.arange(len(c)) - len(c) // 2
    return float(np.dot(c, [f(x + o * h) for o in off]) / h**k)


@pytest.mark.parametrize("order", [1, 2])
def test_bending_modes_are_cantilever_modes(order: int) -> None:
    """Clamped root ``phi(0) = phi'(0) = 0``, free tip ``phi''(1) = phi'''(1) = 0`` (no moment, no
    shear), the analytic slope is the derivative of the shape, and ``phi'''' = b^4 phi``
    (Euler-Bernoulli, uniform beam; fourth difference with h = 0.01: 2e-3 relative)."""
    phi = lambda x: float(bending_shape(x, order)[0])  # noqa: E731
    b = (1.8751040687, 4.6940911330)[order - 1]
    p0, d0 = bending_shape(0.0, order)
    assert abs(p0) < 1e-12 and abs(d0) < 1e-12
    x = np.linspace(0.05, 0.95, 7)
    for xi in x:
        assert bending_shape(xi, order)[1] == pytest.approx(_d(phi, xi, 1, 1e-5), rel=1e-6)
    # free-end conditions from the closed forms of the second and third derivatives at x = 1
    s = (np.cosh(b) + np.cos(b)) / (np.sinh(b) + np.sin(b))
    d2 = b**2 * (np.cosh(b) + np.cos(b) - s * (np.sinh(b) + np.sin(b)))
    d3 = b**3 * (np.sinh(b) - np.sin(b) - s * (np.cosh(b) + np.cos(b)))
    assert _d(lambda z: float(bending_shape(z, order)[1]), 0.7, 1, 1e-5) == pytest.approx(
        b**2 * (np.cosh(0.7 * b) + np.cos(0.7 * b) - s * (np.sinh(0.7 * b) + np.sin(0.7 * b))), rel=1e-6)
    assert abs(d2) < 1e-8 * b**2 and abs(d3) < 1e-8 * b**3
    # phi'''' = b^4 phi: fourth difference of the shape
    for xi in (0.3, 0.6):
        d4 = (phi(xi - 2e-2) - 4 * phi(xi - 1e-2) + 6 * phi(xi) - 4 * phi(xi + 1e-2) + phi(xi + 2e-2)) / 1e-8
        assert d4 == pytest.approx(b**4 * phi(xi), rel=2e-3, abs=2e-3 * b**4)
    assert abs(bending_shape(1.0, order)[0]) == pytest.approx(2.0, rel=1e-9)
    # torsion: zero twist at the root, zero torque (d/dx = 0) at the tip
    assert torsion_shape(0.0) == 0.0 and torsion_shape(1.0) == pytest.approx(1.0)
    assert _d(lambda z: float(torsion_shape(z)), 1.0, 1, 1e-5) == pytest.approx(0.0, abs=1e-9)


def test_static_deflection_is_a_uniformly_loaded_cantilever() -> None:
    """``S(x) = x^2 (6 - 4x + x^2) / 3``: S(0) = S'(0) = 0, S''(1) = S'''(1) = 0, S'''' constant
    (uniform load), S(1) = 1 and the tip slope 4/3 (q L^3 / 6 EI over q L^4 / 8 EI)."""
    P = np.polynomial.Polynomial([0, 0, 6, -4, 1]) / 3.0
    x = np.linspace(0.0, 1.0, 11)
    S, dS = static_shape(x)
    np.testing.assert_allclose(S, P(x), atol=1e-15)
    np.testing.assert_allclose(dS, P.deriv()(x), atol=1e-14)
    assert S[0] == 0.0 and dS[0] == 0.0 and S[-1] == pytest.approx(1.0) and dS[-1] == pytest.approx(4.0 / 3.0)
    assert P.deriv(2)(1.0) == pytest.approx(0.0, abs=1e-14) and P.deriv(3)(1.0) == pytest.approx(0.0, abs=1e-14)
    assert P.deriv(4).degree() == 0


def test_modal_angles_have_the_configured_variance() -> None:
    """paper_wing's modes over T = 20,000 s at 100 Hz (seed 42).  The slope about x at the 5 m
    reference span must have the configured 0.15 deg^2, the twist (y) and the in-plane slope (z)
    0.01 deg^2: a lightly damped mode's sample variance has a relative standard error
    sqrt(2 int rho^2 / T) with int_-inf^inf rho^2 ~ 1 / (2 zeta omega) = 2.65 s for the first bending:
    1.6 %; tolerance 7 % (4 sigma).  The rate variance is sum omega_i^2 sigma_i^2 (same tolerance);
    the first bending's autocorrelation at half its period is -exp(-zeta omega T/2) = -0.91 (0.05).
    The slope grows along the span as the first mode's slope (x 2.753 / 2.045 at the 12.5 m tip)."""
    ac = load_aircraft("paper_wing")
    wing = ac.wing
    assert wing is not None
    r = ModalRealization.sample(wing, 1, 20000.0, 0.01, np.random.default_rng(42))
    th, thd, d, _ = r.deformation(r.t0_s + r.dt_s * np.arange(r.q.shape[0] - 1), 5.0)
    np.testing.assert_allclose(np.var(np.rad2deg(th), axis=0), [0.15, 0.01, 0.01], rtol=0.07)
    np.testing.assert_allclose(np.var(np.rad2deg(th), axis=0), ac.flexure.variance_deg2, rtol=0.07)
    rate_var = [sum((m.omega * m.sigma_deg) ** 2 for m in wing.modes if m.kind == k) for k in ("bending", "torsion", "inplane")]
    np.testing.assert_allclose(np.var(np.rad2deg(thd), axis=0), rate_var, rtol=0.07)
    m1 = wing.modes[0]
    k = int(round(0.5 / m1.frequency_hz / 0.01))
    q = r.q[:, 0]
    assert np.mean(q[:-k] * q[k:]) / np.mean(q * q) == pytest.approx(-np.exp(-m1.damping * m1.omega * 0.5 / m1.frequency_hz), abs=0.05)
    # right wing, FLU: bending up is a rotation about -x, and the section moves up with the slope
    assert np.corrcoef(th[:, 0], d[:, 2])[0, 1] < -0.9
    tip, _, _, _ = r.deformation(r.t0_s + r.dt_s * np.arange(r.q.shape[0] - 1), 12.5)
    ratio = float(np.std(tip[:, 0]) / np.std(th[:, 0]))
    # the second bending mode (slope ratio 9.56 / 2.02) adds 1e-4 of 0.15 deg^2: ratio 1.35 +- 4 %
    assert ratio == pytest.approx(2.753 / 2.045, rel=0.04)


def _turn_flight(heading_change_deg: float) -> Flight:
    """Level flight, a coordinated turn of 200 s (10 s ramps), level flight."""
    return Flight(FlightStart(40.0, 116.0, 1000.0, 100.0, 0.0),
                  [Segment(30.0), Segment(200.0, heading_change_deg, ramp_s=10.0), Segment(30.0)])


def test_quasi_static_bending_follows_the_load_factor() -> None:
    """Steady banked turns (no turbulence: sigma 0): the load factor is 1 / cos(bank) (within the
    G0 / local-g difference, 2e-3), the wing deflects up by (n - 1) x tip per g x S(x), and the
    deflection grows with n - 1.  A pull-up (climb entry) has n > 1, its push-over n < 1."""
    wing = ModalWing(12.5, 5.0, (WingMode("bending", 1.0, 0.03, 0.0),), tip_deflection_per_g_m=0.3)
    t = np.array([10.0, 130.0])  # level; the middle of the turn
    tips = []
    for dpsi in (180.0, 360.0, 540.0):
        fl = _turn_flight(dpsi)
        n1, n1d = load_factor(fl)(t)
        bank = fl.profiles(t).bank
        np.testing.assert_allclose(n1, 1.0 / np.cos(bank) - 1.0, atol=2e-3)
        assert abs(n1[0]) < 1e-9 and abs(n1d[1]) < 1e-6
        r = ModalRealization.sample(wing, 1, fl.duration_s, 0.01, np.random.default_rng(0), load=load_factor(fl))
        th, _, d, _ = r.deformation(t, 12.5)
        assert d[0] == pytest.approx(np.zeros(3), abs=1e-9)
        assert d[1, 2] == pytest.approx(0.3 * n1[1], rel=1e-12)
        assert -th[1, 0] == pytest.approx(0.3 * n1[1] * 4.0 / 3.0 / 12.5, rel=1e-12)  # right wing: slope up = about -x
        _, _, d5, _ = r.deformation(t, 5.0)
        assert d5[1, 2] == pytest.approx(0.3 * n1[1] * float(static_shape(0.4)[0]), rel=1e-12)
        tips.append((float(n1[1]), float(d[1, 2])))
    n_1, w = np.array(tips).T
    assert np.all(np.diff(n_1) > 0) and np.all(np.diff(w) > 0)
    np.testing.assert_allclose(w / n_1, 0.3, rtol=1e-12)
    # 30 deg bank at 100 m/s (the middle turn): n - 1 = 0.155 -> 4.6 cm at the tip
    assert tips[1][1] == pytest.approx(0.3 * (1 / np.cos(np.arctan(100.0 * 2 * np.pi / 190.0 / 9.80665)) - 1), rel=3e-3)
    climb = Flight(FlightStart(40.0, 116.0, 1000.0, 100.0, 0.0), [Segment(20.0), Segment(100.0, climb_rate_mps=10.0, ramp_s=20.0)])
    n1, _ = load_factor(climb)(np.array([30.0, 110.0]))
    assert n1[0] > 1e-3 and n1[1] < -1e-3


def test_modal_sub_imu_integrates_back_to_its_deformed_truth() -> None:
    """paper_su with the modal wing (paper_su_pair_modal), seed 3: the ideal 100 Hz samples of
    each sub-IMU, strapdown-integrated from its truth at the start of the S-turn (200-260 s, the
    turn's load factor bending the wing too), return its /truth/sub_imu trajectory.  Measured at
    100 Hz: 7 mm, 0.4 mm/s, 2e-8 rad over 60 s (converging with the rate: 0.7 mm at 200 Hz, 0.15 mm
    at 800 Hz: a sampling error of the 1-6 Hz modes, not an inconsistency); bounds 5 cm, 5 mm/s,
    1e-6 rad.  The wing really deforms: the lever arm differs from the nominal one by the
    realisation's deflection (and the section's rotation of the offset) and the attitude from
    master x mount by the flexure rotation."""
    sc = load_scenario("paper_su", aircraft="paper_su_pair_modal")
    ss = SimulatedSession(sc, seed=3, duration_s=300.0)
    fs = sc.rates.sub_imu_hz
    assert fs == 100.0
    for name in ("sub_r", "sub_l"):
        s = sc.aircraft.sub_imu(name)
        imu = ss.ideal_imu(f"sub_imu/{name}")
        tr = ss.truth(f"sub_imu/{name}")
        k0, k1 = 20000, 26000
        out = Strapdown(NavState(tr.t_s[k0], tr.q_nb[k0], tr.vel_n_mps[k0], tr.llh[k0])).run_increments(
            imu.t_s[k0:k1], imu.omega_radps[k0:k1] / fs, imu.f_mps2[k0:k1] / fs)
        llh = tr.llh[k0 + 1:k1 + 1]
        r_m, r_n = earth.radii_of_curvature(llh[:, 0])
        d = out.llh - llh
        pos = np.abs(np.stack([d[:, 0] * r_m, d[:, 1] * r_n * np.cos(llh[:, 0]), d[:, 2]], 1)).max()
        assert pos < 0.05, (name, pos)
        assert np.abs(out.vel_n_mps - tr.vel_n_mps[k0 + 1:k1 + 1]).max() < 5e-3
        assert np.abs(attitude_error(out.C_nb, tr.C_nb[k0 + 1:k1 + 1])).max() < 1e-6
        # deformed lever arm and attitude
        t = np.linspace(200.0, 260.0, 61)
        p_m, _, C_m, _ = ss.motion("master")(t)
        p_s, _, C_s, _ = ss.motion(f"sub_imu/{name}")(t)
        r = np.einsum("mji,mj->mi", C_m, p_s - p_m)
        fr = ss.flexure(1 if s.span_m > 0 else -1)
        assert isinstance(fr, ModalRealization)
        thb, _, dfl, _ = fr.deformation(t, s.span_m)
        r0 = np.asarray(s.lever_arm_m)
        off = r0 * [1.0, 0.0, 1.0]
        np.testing.assert_allclose(r, r0 + dfl + rotvec_to_dcm(thb) @ off - off, atol=1e-6)
        assert np.abs(dfl[:, 2]).max() > 0.02  # cm of deflection at 5 m
        C0 = mount_dcm(s.mount_rpy_deg, s.rho_deg)
        rel = attitude_error(C_s, C_m @ rotvec_to_dcm(thb) @ C0)
        assert np.abs(rel).max() < 1e-9
        assert np.rad2deg(np.abs(thb[:, 0]).max()) > 0.3
    # the antenna truth rides on its deformed sub-IMU
    pa, _, Ca, _ = ss.motion("antenna/ant_r")(np.array([230.0]))
    ps, _, Cs, _ = ss.motion("sub_imu/sub_r")(np.array([230.0]))
    np.testing.assert_allclose(Ca, Cs, atol=1e-15)
    np.testing.assert_allclose(Cs[0].T @ (pa - ps)[0], [0.0, 0.0, -0.2], atol=1e-8)


def test_gauss_markov_stays_the_default_and_modal_config_is_checked(tmp_path) -> None:
    assert load_aircraft("paper_su_pair").wing is None and load_aircraft("paper_su").wing is None
    ac = load_aircraft("paper_su_pair_modal")
    assert ac.wing is not None and ac.flexure.tau_s == (5.0, 2.0, 2.0)
    np.testing.assert_allclose(ac.flexure.variance_deg2, [0.15, 0.01, 0.01], rtol=1e-5)
    base = "name: w\nflexure: {model: modal, semi_span_m: 4, reference_span_m: 2, modes: MODES}\n" \
           "sub_imus: [{name: s, span_m: SPAN, lever_arm_m: [0, -SPAN, 0]}]\n"
    good = "[{kind: bending, frequency_hz: 1.0, damping: 0.03, sigma_deg: 0.3}]"
    assert load_aircraft("w", text=base.replace("MODES", good).replace("SPAN", "3")).wing is not None
    with pytest.raises(ConfigError, match="beyond the wing's semi_span_m"):
        load_aircraft("w", text=base.replace("MODES", good).replace("SPAN", "5"))
    with pytest.raises(ConfigError, match="kind"):
        load_aircraft("w", text=base.replace("MODES", good.replace("bending", "flutter")).replace("SPAN", "3"))
    with pytest.raises(ConfigError, match="non-empty list of modes"):
        load_aircraft("w", text=base.replace("MODES", "[]").replace("SPAN", "3"))
    with pytest.raises(ConfigError, match="model must be"):
        load_aircraft("w", text=base.replace("model: modal", "model: spline").replace("MODES", good).replace("SPAN", "3"))


def test_modal_oscillator_discretization_is_stationary() -> None:
    """Phi Pinf Phi' + Q = Pinf for each mode's exact discretization (Van Loan)."""
    for m in (WingMode("bending", 1.0, 0.03, 0.38), WingMode("torsion", 4.0, 0.02, 0.1)):
        Phi, Q = m.discrete(0.01)
        P = m.stationary_cov()
        np.testing.assert_allclose(Phi @ P @ Phi.T + Q, P, rtol=1e-9, atol=1e-20)
    assert replace(WingMode("bending", 1.0, 0.03, 0.38), damping=0.02).correlation_time_s == pytest.approx(1 / (0.02 * 2 * np.pi))
