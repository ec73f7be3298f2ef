"""Standstill detection and the level at the start (dpos_core.ifa.standstill) on the simulated MEMS
vehicle (scenario mems_vehicle: 30 s at rest with a 4 / -7 deg mount tilt, then driving and
turning; an automotive MEMS unit worse than its datasheet, jittered stamps)."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.config.sensors import imu_model
from dpos_core.ifa.model import IfaFilterConfig, IfaModel
from dpos_core.ifa.reference import start
from dpos_core.ifa.standstill import detect_standstill, standstill_statistic, start_level
from dpos_core.series import GnssSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState
from dpos_core.units import DEG


@pytest.fixture(scope="module")
def session():
    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 3, duration_s=120.0)
    g = ss.gnss()
    off = float(sc.ifa["gnss_time_offset_s"])
    gnss = GnssSeries(g.t_s - off, g.llh, g.pos_sigma_m, g.vel_n_mps, g.vel_sigma_mps)  # on the IMU's clock
    return ss, ss.master_imu(), gnss, sc.aircraft.master_imu


def _window(imu, t0: float, t1: float):
    k = (imu.t_s > t0) & (imu.t_s <= t1)
    return imu.omega_radps[k], imu.f_mps2[k]


def test_statistic_is_about_one_at_rest_and_large_in_motion(session):
    ss, imu, gnss, model = session
    w, f = _window(imu, 10.0, 11.0)
    rest = detect_standstill(w, f, model, 0.01, np.zeros(3))
    assert rest.at_rest and 0.3 < rest.statistic < 3.0, rest  # the datasheet noise (the unit is worse: up to ~2)
    for t in (35.0, 55.0, 72.0):  # accelerating, straight at 15 m/s (no vibration simulated), turning
        w, f = _window(imu, t, t + 1.0)
        v = ss.truth("master", np.array([t + 1.0])).vel_n_mps[0]
        moving = detect_standstill(w, f, model, 0.01, v)
        assert not moving.at_rest, (t, moving)
    # the IMU alone sees the turn (a mean rate far above the gyro bias); a steady acceleration
    # without rotation is a tilt to it: only the GNSS speed tells (module docstring)
    w, f = _window(imu, 72.0, 73.0)
    assert not detect_standstill(w, f, model, 0.01).at_rest
    w, f = _window(imu, 36.0, 37.0)
    assert standstill_statistic(w, f, *model.white_sigma(0.01)) < 3.0
    with pytest.raises(ValueError):
        standstill_statistic(np.zeros((1, 3)), np.zeros((1, 3)), 1.0, 1.0)


def test_level_at_rest_and_in_a_turn_is_not_the_raw_level(session):
    """At rest the level is the mount's tilt to the accelerometer bias (the unit's 20 mg: 1.1 deg);
    in the 90 deg turn at 15 m/s (1.6 m/s^2 sideways) the raw level is ~9 deg off in roll, the
    compensated one is within its sigma, and without the previous fix the raw level's sigma covers it."""
    ss, imu, gnss, model = session
    tilt = 1.2 * np.arcsin(model.accel_bias_ug * 1e-6 * np.sqrt(2.0))  # the bias's tilt (two axes)

    def case(t_fix: float, drop_previous: bool = False):
        j = int(np.argmin(np.abs(gnss.t_s - t_fix)))
        g = gnss
        if drop_previous:
            keep = np.arange(gnss.t_s.size) != j - 1
            g = GnssSeries(gnss.t_s[keep], gnss.llh[keep], gnss.pos_sigma_m[keep], gnss.vel_n_mps[keep], gnss.vel_sigma_mps[keep])
            j -= 1
        tr = ss.truth("master", np.array([g.t_s[j]]))
        heading, pitch, roll = tr.hpr_rad[0]
        lv = start_level(imu, g, j, float(g.t_s[j]), float(heading), 1.0, model)
        return lv, pitch, roll

    lv, pitch, roll = case(20.0)
    assert lv.how == "rest" and lv.sigma_rad == pytest.approx(2.0 * np.arcsin(0.02))  # the 20 mg bias's tilt
    assert abs(lv.pitch_rad - pitch) < tilt and abs(lv.roll_rad - roll) < tilt
    lv, pitch, roll = case(73.0)
    w, f = _window(imu, 72.0, float(gnss.t_s[int(np.argmin(np.abs(gnss.t_s - 73.0)))]))
    from dpos_core.ifa.mechanization import level_from_specific_force

    p_raw, r_raw = level_from_specific_force(f.mean(axis=0))
    raw_err = np.hypot(p_raw - pitch, r_raw - roll)
    assert raw_err > 6.0 * DEG  # a level from the turn is not to be trusted
    assert lv.how == "compensated"
    err = np.hypot(lv.pitch_rad - pitch, lv.roll_rad - roll)
    assert err < 0.3 * raw_err and err < 3.0 * lv.sigma_rad + tilt, (err / DEG, raw_err / DEG, lv.sigma_rad / DEG)  # 2.9 vs 10.5 deg
    lv, pitch, roll = case(73.0, drop_previous=True)
    assert lv.how == "raw" and lv.sigma_rad > 5.0 * DEG
    assert np.hypot(lv.pitch_rad - pitch, lv.roll_rad - roll) < 3.0 * lv.sigma_rad + tilt
    # reference.start(level="auto") uses it: at the first fix (at rest) the level is the rest one
    s, lv0 = start(imu, gnss, 0.0, heading_rad=0.0, level="auto", imu_model=model)
    assert lv0 is not None and lv0.how == "rest" and s.t_s < 30.0
    with pytest.raises(ValueError, match="level must be"):
        start(imu, gnss, 0.0, heading_rad=0.0, level="tilted")


def test_the_prior_level_sigma_is_at_least_the_accelerometer_bias_tilt():
    """#31 part 1: no per-recording level sigma.  The filter's prior level 1 sigma is the configured
    one, but never below the tilt the accelerometer turn-on bias leaves in any levelling
    (``2 asin(b / g)``: 2.29 deg for automotive MEMS' 20 mg), the figure walk_0827 once set by hand
    (3 deg against the former 1 deg default); a navigation-grade prior is left as configured."""
    mems = IfaFilterConfig(imu=imu_model({"preset": "automotive_mems"}, "test"))
    assert mems.level_sigma_rad / DEG == pytest.approx(2.292, abs=1e-3)
    assert IfaFilterConfig(imu=mems.imu, level_sigma_deg=5.8).level_sigma_rad / DEG == pytest.approx(5.8)
    assert IfaFilterConfig().level_sigma_rad / DEG == pytest.approx(1.0)  # [Fang2012]'s 100 ug unit
    init = NavState.from_hpr(0.0, [0.0, 0.0, 0.0], np.zeros(3), np.array([0.7, 0.2, 100.0]))
    _, P = IfaModel(init, np.zeros(3), mems).prior()
    att = np.sqrt(np.diag(P)[6:9]) / DEG
    assert att[0] == pytest.approx(2.292, abs=1e-3) and att[1] == pytest.approx(2.292, abs=1e-3)
    assert att[2] == pytest.approx(mems.heading_sigma_deg)


def test_raw_level_in_a_coordinated_turn_has_a_sigma_that_covers_the_bank():
    """Without a previous fix the level is the raw one; in a coordinated turn (an aircraft banked at
    30 deg at 20 m/s, turning at g tan(30 deg) / 20 m/s = 16 deg/s) the specific force is along the
    body's vertical, without spread: the raw level is wings-level, 30 deg off, which the former sigma
    (max(1 m/s^2, spread of f) / g: 5.8 deg) did not cover (thor_flight75 started in a 41 deg bank,
    docs/ifa.md).  The centripetal bound |w| |v| / g is the bank itself here."""
    bank, speed, g0 = 30.0 * DEG, 20.0, 9.80665
    turn = g0 * np.tan(bank) / speed
    n = 100
    t = np.arange(1, n + 1) * 0.01
    om = np.tile([0.0, turn * np.sin(bank), turn * np.cos(bank)], (n, 1))  # FLU body rates of a level turn, rolled by the bank
    f = np.tile([0.0, 0.0, g0 / np.cos(bank)], (n, 1))
    f = f + 0.01 * np.random.default_rng(1).standard_normal(f.shape)
    from dpos_core.series import ImuSeries

    imu = ImuSeries(t, om, f)
    gnss = GnssSeries(np.array([1.0]), np.array([[0.7, 0.2, 300.0]]), np.full((1, 3), 3.0), np.array([[speed, 0.0, 0.0]]),
                      np.full((1, 3), 0.5))
    lv = start_level(imu, gnss, 0, 1.0, 0.0, 1.0, imu_model({"preset": "automotive_mems"}, "test"))
    assert lv.how == "raw" and abs(lv.roll_rad) < 1.0 * DEG  # wings-level: 30 deg off
    spread = float(np.sqrt(np.mean(np.sum((f - f.mean(axis=0)) ** 2, axis=1))))
    assert np.arctan(max(spread, 1.0) / g0) < bank / 5.0  # the former sigma: 5 sigma off
    assert lv.sigma_rad == pytest.approx(bank, rel=1e-3)  # |w| |v| / g = tan(bank)
