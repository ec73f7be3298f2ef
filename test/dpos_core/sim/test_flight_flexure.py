"""Simulator building blocks: segment flights integrate back with our strapdown; flexure statistics."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.analytic_trajectory import CoordinatedTurnClimb
from dpos_core.attitude import attitude_error, dcm_to_quat
from dpos_core.config.flexure import FlexureModel
from dpos_core.kinematics import increments_from_motion, integrate_increments
from dpos_core.sim.flexure import FlexureRealization
from dpos_core.sim.flight import Flight, FlightStart, Segment
from dpos_core.strapdown import NavState, Strapdown
from dpos_core.units import DEG


def test_by_parts_increments_equal_the_acceleration_form() -> None:
    traj = CoordinatedTurnClimb()

    def motion(t: np.ndarray):
        p, v, _, C, w = traj.ecef_kinematics(t)
        return p, v, C, w

    t = np.arange(0.0, 20.0 + 1e-9, 0.01)
    dth_a, dv_a = integrate_increments(traj.imu_rates, t)
    dth_b, dv_b = increments_from_motion(motion, t)
    np.testing.assert_allclose(dth_b, dth_a, atol=1e-15)
    np.testing.assert_allclose(dv_b, dv_a, atol=1e-12)


def _s_plus_u() -> Flight:
    segs = [Segment(100), Segment(100, 60), Segment(100, -60), Segment(400, name="AB"), Segment(100, 180), Segment(400, name="CD")]
    return Flight(FlightStart(40.0, 116.0, 500.0, 100.0, 40.0), segs)


def test_segment_flight_is_smooth_and_follows_the_plan() -> None:
    fl = _s_plus_u()
    assert fl.duration_s == 1200.0
    p = fl.profiles([0.0, 100.0, 200.0, 300.0, 700.0, 800.0, 1200.0])
    np.testing.assert_allclose(np.rad2deg(p.heading) % 360.0, [40, 40, 100, 40, 40, 220, 220], atol=1e-9)
    np.testing.assert_allclose(p.speed, 100.0)
    assert fl.segment_bounds("CD") == (800.0, 1200.0)
    # continuity at the joins: no step in bank, heading rate, or acceleration
    for tj in (100.0, 200.0, 300.0, 700.0, 800.0):
        a, b = fl.profiles([tj - 1e-7]), fl.profiles([tj + 1e-7])
        for name in ("bank", "heading_rate", "bank_rate", "gamma"):
            assert abs(getattr(a, name)[0] - getattr(b, name)[0]) < 1e-6, (tj, name)
    # coordinated 180 deg in 100 s with 10 s ramps: 2 deg/s -> bank atan(V r / g)
    bank = fl.profiles([750.0]).bank[0]
    assert bank == pytest.approx(np.arctan(100.0 * 2.0 * DEG / 9.80665), rel=1e-9)
    # level flight stays at its height on the ellipsoid
    llh = fl.llh(np.linspace(0, 1200, 50))
    np.testing.assert_allclose(llh[:, 2], 500.0, atol=1e-6)


def test_segment_flight_integrates_back_with_the_strapdown() -> None:
    """The ideal IMU of a 1200 s S+U flight at 100 Hz reproduces the truth: the budget of
    test_strapdown (trapezoid position error N T^3/12 |jerk|, jerk <= V r^2 = 0.12 m/s^3 in the
    180 deg turn) gives < 1 cm; bounds 2 cm, 1e-4 m/s, 1e-8 rad."""
    fl = _s_plus_u()
    fs = 100.0
    t = np.arange(0.0, fl.duration_s + 0.5 / fs, 1.0 / fs)
    dth, dv = increments_from_motion(fl.ecef_motion, t)
    llh, v = fl.llh(t), fl.velocity_n(t)
    C, _ = fl.attitude(t)
    out = Strapdown(NavState(0.0, dcm_to_quat(C[0]), v[0], llh[0])).run_increments(t[1:], dth, dv)
    r_m, r_n = earth.radii_of_curvature(llh[1:, 0])
    d = out.llh - llh[1:]
    pos = np.abs(np.stack([d[:, 0] * r_m, d[:, 1] * r_n * np.cos(llh[1:, 0]), d[:, 2]], 1)).max(0)
    assert pos.max() < 0.02, pos
    assert np.abs(out.vel_n_mps - v[1:]).max() < 1e-4
    assert np.abs(attitude_error(out.C_nb, C[1:])).max() < 1e-8


def test_bad_segments_are_rejected() -> None:
    with pytest.raises(ValueError, match="duration_s"):
        Segment(0.0)
    with pytest.raises(ValueError, match="ramp_s"):
        Segment(10.0, 30.0, ramp_s=6.0)
    with pytest.raises(ValueError, match="speed"):
        Flight(FlightStart(40.0, 116.0, 500.0, 50.0, 0.0), [Segment(100.0, speed_change_mps=-60.0)])


def test_flexure_statistics_match_the_model() -> None:
    """[Gong2018] sec. 4.1.3: tau 2/5/2 s, variance 0.01/0.15/0.01 deg^2.

    Over T = 20,000 s the sample variance of a process with correlation time ~tau has a relative
    standard error of about sqrt(2 * T_c / T) with T_c = int rho^2 = 5 / (4 beta) ~ 0.6 tau:
    ~1.7 % for tau = 5 s; tolerance 7 % (4 sigma).  The normalized autocorrelation at lag tau
    must match (1 + beta tau) exp(-beta tau) = 0.368 within 0.05.
    """
    m = FlexureModel((2.0, 5.0, 2.0), (0.01, 0.15, 0.01))
    r = FlexureRealization.sample(m, 20000.0, 0.01, np.random.default_rng(42))
    np.testing.assert_allclose(np.var(np.rad2deg(r.theta), axis=0), [0.01, 0.15, 0.01], rtol=0.07)
    np.testing.assert_allclose(np.var(r.theta_dot, axis=0), m.beta**2 * m.sigma_rad**2, rtol=0.07)
    for i, tau in enumerate(m.tau_s):
        k = int(round(tau / 0.01))
        rho = np.mean(r.theta[:-k, i] * r.theta[k:, i]) / np.mean(r.theta[:, i] ** 2)
        assert rho == pytest.approx((1 + 2.146) * np.exp(-2.146), abs=0.05)
    # the interpolated rate is the derivative of the interpolated angle: within each grid interval
    # the angle is cubic, so Simpson's rule integrates the rate exactly to d theta
    t0 = 100.0 + 0.01 * np.arange(500)
    th0, d0 = r.at(t0)
    th1, d1 = r.at(t0 + 0.01)
    _, dm = r.at(t0 + 0.005)
    np.testing.assert_allclose(0.01 / 6.0 * (d0 + 4.0 * dm + d1), th1 - th0, atol=1e-12 * np.abs(th0).max())
    t = np.linspace(100.0, 110.0, 2001)
    th, thd = r.at(t)
    # span scaling
    th2, _ = r.at(t, span_m=-10.0)
    np.testing.assert_allclose(th2, 2.0 * th)


def test_flexure_discretization_is_consistent() -> None:
    """Phi Pinf Phi' + Q = Pinf: the exact discretization preserves the stationary covariance."""
    m = FlexureModel((2.0, 5.0, 2.0), (0.01, 0.15, 0.01))
    Phi, Q = m.discrete(0.01)
    P = m.stationary_cov()
    np.testing.assert_allclose(Phi @ P @ np.swapaxes(Phi, 1, 2) + Q, P, rtol=1e-9, atol=1e-20)
