"""ZUPT, ZARU and NHC (dpos_core.ifa.constraints) in the in-flight alignment (#31 part 2): a
simulated standstill (an IMU at rest with turn-on biases and its datasheet white noise, GNSS fixes
at 1 Hz) with the updates on and off."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import dcm_to_quat
from dpos_core.config.sensors import imu_model
from dpos_core.frames import C_nb_from_hpr
from dpos_core.ifa import constraints
from dpos_core.ifa.model import IfaFilterConfig, IfaModel
from dpos_core.ifa.pipeline import run
from dpos_core.series import GnssSeries, ImuSeries
from dpos_core.strapdown import NavState
from dpos_core.units import DEG

LLH = np.array([np.radians(45.0), np.radians(10.0), 100.0])
HPR = (np.radians(30.0), np.radians(2.0), np.radians(-3.0))
B_G = np.radians([0.10, -0.05, 0.15])  # deg/s, inside the preset's 0.2 deg/s (720 deg/h) turn-on sigma
B_A = np.array([0.03, -0.02, 0.0])  # m/s^2 (the preset's 20 mg: 0.2 m/s^2)
DT = 0.01


def _standstill(duration_s: float = 40.0, seed: int = 4):
    imu = imu_model({"preset": "automotive_mems"}, "test")
    C = C_nb_from_hpr(*HPR)
    n = int(round(duration_s / DT))
    t = DT * np.arange(1, n + 1)
    s_g, s_a = imu.white_sigma(DT)
    rng = np.random.default_rng(seed)
    om = C.T @ earth.earth_rate_n(LLH[0]) + B_G + s_g * rng.standard_normal((n, 3))
    f = C.T @ (-earth.gravity_n(LLH[0], LLH[2])) + B_A + s_a * rng.standard_normal((n, 3))
    tg = np.arange(1.0, duration_s + 1e-9, 1.0)
    m = tg.size
    gnss = GnssSeries(tg, np.tile(LLH, (m, 1)), np.tile([0.05, 0.05, 0.1], (m, 1)), np.zeros((m, 3)), np.tile(0.03, (m, 3)))
    init = NavState(0.0, dcm_to_quat(C), np.zeros(3), LLH.copy())
    cfg = IfaFilterConfig(imu=imu, gnss_pos_sigma_m=(0.05, 0.05, 0.1), gnss_vel_sigma_mps=(0.03, 0.03, 0.03), heading_hypotheses=1,
                          gyro_axis_errors="noise")
    return ImuSeries(t, om, f), gnss, init, cfg


@pytest.fixture(scope="module")
def runs():
    imu, gnss, init, cfg = _standstill()
    out = {}
    for on in (True, False):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out[on] = run(imu, gnss, np.zeros(3), replace(cfg, standstill_updates=on, zupt=True), "add2", init, record_smoother=True)
    return out


def _gyro_bias(res):
    e = res.engine
    ie, _ = e.model.bias_index
    return res.gyro_bias_radps, np.sqrt(np.diag(e.cov)[ie])


def test_zaru_recovers_the_gyro_bias_to_its_sigma(runs):
    on, off = runs[True], runs[False]
    assert np.all(on.at_rest == 1.0) and all(c == ("zupt", "zaru") for c in on.constraints)
    assert np.all(off.at_rest == 1.0) and all(c == () for c in off.constraints)  # detected, not used
    b, sig = _gyro_bias(on)
    prior = 720.0 / 3600.0 * DEG
    assert np.all(np.abs(b - B_G) < 3.0 * sig), (np.degrees(b), np.degrees(sig))
    # the heading axis from ZARU (1 s windows of 0.05 deg/s samples, 40 of them), the level axes from
    # the tilt they drive, which ZUPT sees
    assert np.all(sig < 0.05 * prior), np.degrees(sig)
    assert np.all(np.abs(b - B_G) < np.radians(0.01)), np.degrees(b - B_G)
    # without ZARU the heading axis's bias is not observable at rest (no heading reference)
    _, sig_off = _gyro_bias(off)
    assert sig_off[2] > 0.5 * prior, np.degrees(sig_off)


def test_zupt_bounds_the_velocity(runs):
    """Once the level has settled (15 s), the navigation's speed at rest stays below 1.5 cm/s between
    the 1 Hz epochs with ZUPT (measured 0.011 m/s), its velocity sigma below 6 mm/s; with the GNSS
    velocity (3 cm/s) alone the speed reaches 4.8 cm/s and the sigma stays above 6 mm/s."""
    speed = {}
    for on in (True, False):
        res = runs[on]
        speed[on] = float(np.linalg.norm(res.vel_n_mps[res.t_s > 15.0], axis=1).max())
        sig_v = np.array([np.sqrt(np.diag(P)[3:6]) for t, P in res.track if t > 15.0])
        assert (sig_v.max() < 0.006) if on else (sig_v.min() > 0.006), (on, sig_v.max(), sig_v.min())
    assert speed[True] < 0.015 < speed[False], speed


def test_constraint_measurements_see_their_states():
    """h of each constraint is the error state it observes (module docstring's signs)."""
    _, _, init, cfg = _standstill(2.0)
    m = IfaModel(init, np.zeros(3), cfg, DT)
    C = C_nb_from_hpr(*HPR)
    x = np.zeros(m.n)
    x[3:6] = [0.1, -0.2, 0.05]  # dv
    x[9:12] = [1e-3, 2e-3, -3e-3]  # eps
    _, h, R = constraints.zupt(np.zeros(3), 0.005, m.full)
    np.testing.assert_allclose(h(x[None])[0], x[3:6])
    np.testing.assert_allclose(np.diag(R), 0.005**2)
    wie = earth.earth_rate_n(LLH[0])
    w = np.tile(C.T @ wie + x[9:12], (100, 1))
    y, h, _ = constraints.zaru(w, np.zeros(3), C, wie, 1e-4, m.full)
    np.testing.assert_allclose(y, h(x[None])[0], atol=1e-12)  # no attitude error: y = eps
    x2 = x.copy()
    x2[6:9] = [0.0, 0.0, 0.5]  # a heading error: the earth rate seen through the wrong attitude
    C_true = C_nb_from_hpr(HPR[0] - 0.5, HPR[1], HPR[2])  # C_true = E C_est, E = expm([phi x]), phi about Up
    w2 = np.tile(C_true.T @ wie + x[9:12], (100, 1))
    y2, h2, _ = constraints.zaru(w2, np.zeros(3), C, wie, 1e-4, m.full)
    np.testing.assert_allclose(y2, h2(x2[None])[0], atol=1e-10)
    # NHC: a vehicle driving along its x axis; a velocity error sideways is seen, one along it not
    v_true = C @ np.array([10.0, 0.0, 0.0])
    for dv, seen in ((C @ np.array([0.0, 0.3, 0.0]), True), (C @ np.array([0.3, 0.0, 0.0]), False)):
        y3, h3, R3 = constraints.nhc(v_true + dv, C, 0.1, m.full)
        x3 = np.zeros(m.n)
        x3[3:6] = dv
        np.testing.assert_allclose(y3, h3(x3[None])[0], atol=1e-10)
        assert (np.abs(y3).max() > 0.1) == seen and R3.shape == (2, 2)
