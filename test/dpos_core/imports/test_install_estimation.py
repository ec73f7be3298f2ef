"""Clock offset/drift and mounting of a sub-IMU from the data (dpos_core.imports.clock, .mounting):
a simulated sub-IMU with a known clock and mounting is recovered within its sigma; no manoeuvre is
refused; the leap seconds come from the table (a UTC stamp of 2016 and one of 2017)."""

from __future__ import annotations

import calendar
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from dpos_core.attitude import dcm_to_rotvec, mount_dcm
from dpos_core.imports.clock import ClockNotObservable, ClockSettings, estimate_clock, interval_means
from dpos_core.imports.mounting import MountingNotObservable, estimate_mounting, rpy_from_dcm
from dpos_core.imports.timescales import datetime_ns, gps_minus_utc_s, gpst_to_utc_ns, utc_to_gpst_ns, week_sow_ns
from dpos_core.units import DEG

_spec = importlib.util.spec_from_file_location("install_sim", Path(__file__).with_name("install_sim.py"))
assert _spec is not None and _spec.loader is not None
sim = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sim)
C_nb, sub_rates = sim.C_nb, sim.sub_rates

NS = 1_000_000_000
MOUNT = (2.0, -3.0, 35.0)


def _scene(duration_s: float, offset_s: float, drift: float, manoeuvre: bool = True, noise_dps: float = 0.3):
    t_main = np.arange(0.0, duration_s + 20.0, 0.1)  # 10 Hz main solution
    dt = 0.01
    t_dev = np.arange(0.0, duration_s, dt)  # the sub-IMU's own clock
    t_true = 10.0 + t_dev + offset_s + drift * t_dev  # starts 10 s (+ offset) into the solution
    w = sub_rates(t_true, dt * (1 + drift), MOUNT, manoeuvre, bias_dps=(0.5, -0.3, 0.2), noise_dps=noise_dps)
    return t_main, C_nb(t_main, manoeuvre), t_dev, w, t_true


def test_clock_offset_recovered_within_sigma_short_log() -> None:
    t_main, C, t_dev, w, t_true = _scene(40.0, 0.0371, 0.0)
    c = estimate_clock(t_main, C, t_dev, w)
    true_offset = 10.0371
    assert c.drift_sigma is None and c.drift == 0.0  # 40 s: no drift estimate
    assert abs(c.offset_s - true_offset) < max(3 * c.offset_sigma_s, 1e-3)
    assert c.offset_sigma_s < 5e-3 and c.peak > 0.9
    assert np.isfinite(c.second_peak) and c.second_peak < 0.9 * c.peak


def test_clock_offset_and_drift_recovered_within_sigma_long_log() -> None:
    drift = 80e-6  # 80 ppm: 16 ms over the log
    t_main, C, t_dev, w, t_true = _scene(200.0, -0.213, drift)
    c = estimate_clock(t_main, C, t_dev, w)
    assert c.drift_sigma is not None
    assert abs(c.drift - drift) < 3 * c.drift_sigma + 5e-6, (c.drift, c.drift_sigma)
    t_est = c.to_gpst_ns(t_dev) * 1e-9
    err = t_est - t_true
    assert np.max(np.abs(err)) < max(4 * c.offset_sigma_s, 2e-3)
    # without the drift the ends would be 8 ms off
    assert np.max(np.abs(err)) < 0.5 * drift * 100.0


def test_no_manoeuvre_is_refused_naming_the_log() -> None:
    t_main, C, t_dev, w, _ = _scene(60.0, 0.0, 0.0, manoeuvre=False, noise_dps=0.5)
    with pytest.raises(ClockNotObservable, match=r"^--sub left \(x.csv\): clock offset not observable: no manoeuvre"):
        estimate_clock(t_main, C, t_dev, w, name="--sub left (x.csv)")


def test_search_window_excludes_the_true_offset() -> None:
    """A search range that excludes the truth finds no credible peak there (no guess)."""
    t_main, C, t_dev, w, _ = _scene(40.0, 0.0, 0.0)
    with pytest.raises(ClockNotObservable):
        estimate_clock(t_main, C, t_dev, w, ClockSettings(search_s=(30.0, 40.0)))


def test_interval_means_of_a_constant_rate_and_outside() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    w = np.tile([0.1, -0.2, 0.3], (t.size, 1))
    m, inside = interval_means(t, w, np.array([1.0, 9.95, -1.0]), np.array([1.1, 10.5, 0.5]))
    assert inside.tolist() == [True, False, False]
    np.testing.assert_allclose(m[0], [0.1, -0.2, 0.3], rtol=1e-12)
    assert np.isnan(m[1]).all()


def test_mounting_recovered_within_sigma() -> None:
    t_main, C, t_dev, w, t_true = _scene(60.0, 0.0, 0.0, noise_dps=0.5)
    m = estimate_mounting(t_main, C, t_true, w)
    err = np.asarray(m.rpy_deg) - np.asarray(MOUNT)
    assert np.all(np.abs(err) < 3 * m.rpy_sigma_deg + 0.02), (m.rpy_deg, m.rpy_sigma_deg)
    assert np.all(m.rpy_sigma_deg < 0.5)
    np.testing.assert_allclose(m.bias_dps, [0.5, -0.3, 0.2], atol=0.1)
    # the same matrix as the aircraft file's
    np.testing.assert_allclose(mount_dcm(m.rpy_deg, (0, 0, 0)), m.C_bs, atol=1e-12)


def test_mounting_sigma_grows_with_noise_and_stays_honest() -> None:
    """Over seeds, the error / sigma of the yaw is of order one (not 10x too small, not 10x too big)."""
    t_main, C, t_dev, _, t_true = _scene(30.0, 0.0, 0.0)
    z = []
    for seed in range(8):
        w = sub_rates(t_true, 0.01, MOUNT, True, noise_dps=3.0, seed=seed)
        m = estimate_mounting(t_main, C, t_true, w)
        z.append((np.asarray(m.rpy_deg) - MOUNT) / m.rpy_sigma_deg)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.3 < rms < 2.5, rms


def test_mounting_without_rotation_is_refused() -> None:
    t_main, C, t_dev, w, t_true = _scene(30.0, 0.0, 0.0, manoeuvre=False)
    with pytest.raises(MountingNotObservable, match="fewer than two axes"):
        estimate_mounting(t_main, C, t_true, w)


def test_rpy_from_dcm_inverts_mount_dcm() -> None:
    for rpy in [(0, 0, 0), (10, -20, 170), (-5, 40, -90)]:
        np.testing.assert_allclose(np.rad2deg(rpy_from_dcm(mount_dcm(rpy, (0, 0, 0)))), rpy, atol=1e-9)
        assert np.linalg.norm(dcm_to_rotvec(mount_dcm(rpy, (0, 0, 0)))) >= 0 * DEG


def test_leap_seconds_from_the_table_2016_vs_2017() -> None:
    """A UTC stamp of 2016 is 17 s behind GPST, one of 2017 18 s; the inverse holds; the table's edge is exact."""
    u16 = datetime_ns("2016-07-07 08:10:25")
    u17 = datetime_ns("2017-07-07 08:10:25")
    assert (utc_to_gpst_ns(u16) - u16) == 17 * NS
    assert (utc_to_gpst_ns(u17) - u17) == 18 * NS
    assert gps_minus_utc_s(calendar.timegm((2016, 12, 31, 23, 59, 59)) * NS) == 17
    assert gps_minus_utc_s(calendar.timegm((2017, 1, 1, 0, 0, 0)) * NS) == 18
    assert gps_minus_utc_s(calendar.timegm((2005, 1, 1, 0, 0, 0)) * NS) == 13
    for u in (u16, u17):
        assert gpst_to_utc_ns(utc_to_gpst_ns(u)) == u
    # GPS week 1904 (2016-07-03), Thursday 08:10:42 GPST = 08:10:25 UTC on 2016-07-07
    assert week_sow_ns(1904, 4 * 86400 + 8 * 3600 + 10 * 60 + 42) == utc_to_gpst_ns(u16)


def test_datetime_forms() -> None:
    a = datetime_ns("2022-07-07 08:10:25.5")
    assert datetime_ns("2022/07/07T08:10:25.500Z") == a
    assert a % NS == NS // 2
    with pytest.raises(ValueError):
        datetime_ns("07/07/2022 08:10")


def test_relative_rotation_of_two_sub_imus() -> None:
    """Two sub-IMUs at known mountings: the rotation between them (C_b1^T C_b2) from their own rates."""
    from dpos_core.imports.mounting import relative_rotation

    dt = 0.01
    t = np.arange(0.0, 40.0, dt) + 5.0
    m2 = (-1.0, 4.0, -20.0)
    w1 = sub_rates(t, dt, MOUNT, True, noise_dps=0.5, seed=1)
    w2 = sub_rates(t, dt, m2, True, bias_dps=(0.3, 0.3, -0.3), noise_dps=0.5, seed=2)
    est = relative_rotation(t, w1, t, w2)
    C_true = mount_dcm(MOUNT, (0, 0, 0)).T @ mount_dcm(m2, (0, 0, 0))
    err = np.rad2deg(dcm_to_rotvec(est.C_bs @ C_true.T))
    assert np.linalg.norm(err) < 0.1, err
    assert np.all(np.abs(np.rad2deg(rpy_from_dcm(C_true)) - est.rpy_deg) < 3 * est.rpy_sigma_deg + 0.01)
