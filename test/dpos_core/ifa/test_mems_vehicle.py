"""A MEMS main POS with real-device timing (scenario mems_vehicle): jittered IMU stamps, 1 % lost
samples, fixes 4.3 ms off the IMU grid and stamped 20 ms late, a tilted mount, a 30 s standstill
before the vehicle moves, a unit worse than its datasheet.  Started from the data as on a real
recording; NEES / NIS against the truth, the datasheet filter beside the oracle that knows the unit."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.evaluation import ifa as E
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession


@pytest.fixture(scope="module")
def result():
    sc = load_scenario("mems_vehicle")
    return sc, E.consistency(sc, [3], "add2", None, (150.0, 180.0))


def test_scenario_has_the_real_device_timing():
    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 3)
    imu, g = ss.master_imu(), ss.gnss()
    dt = np.diff(imu.t_s)
    assert dt.min() < 0.0097 and np.max(dt[dt < 0.015]) > 0.0103  # jittered stamps
    assert 0.005 < np.mean(dt > 0.015) < 0.02  # ~1 % lost
    k = np.searchsorted(imu.t_s, g.t_s)
    assert np.all(np.abs(imu.t_s[np.clip(k, 0, imu.t_s.size - 1)] - g.t_s) > 1e-4)  # fixes between samples
    tr = ss.truth("master", np.array([10.0, 29.0]))
    np.testing.assert_allclose(tr.vel_n_mps, 0.0, atol=1e-9)  # standstill
    np.testing.assert_allclose(np.degrees(tr.hpr_rad[0, 1:]), [4.0, -7.0], atol=1e-6)  # tilted mount


def test_aligns_from_the_data_without_rejecting_a_fix(result):
    _, c = result
    for kind in ("datasheet", "oracle"):
        r = c[kind][0]
        assert r["aligned_t_s"] is not None and r["aligned_t_s"] < 120.0
        assert r["rejected"] == 0 and r["restarts"] == 0 and r["diverged_epochs"] == 0


def test_covariance_is_consistent_with_the_error(result):
    """The oracle is consistent (NEES ~3 per block, NIS ~6); the datasheet filter, which does not
    know that its unit is worse, is at most ~2x optimistic, never the 1e3-1e6 of a silent divergence."""
    _, c = result
    o = c["oracle"][0]["consistency"]
    for k in ("pos", "vel", "att"):
        assert 1.0 < o[f"nees_{k}_mean"] < 4.5, (k, o)
        assert o[f"nees_{k}_in95"] > 0.85, (k, o)
    assert 4.5 < o["nis_mean"] < 8.0
    d = c["datasheet"][0]["consistency"]
    for k in ("pos", "vel", "att"):
        assert d[f"nees_{k}_mean"] < 9.0, (k, d)


def test_errors_before_during_after_the_outage(result):
    _, c = result
    for kind in ("datasheet", "oracle"):
        r = c[kind][0]
        e = r["horizontal_error_m"]
        assert e["before"]["rms"] < 0.6 and e["after"]["rms"] < 0.8
        assert 1.0 < e["during"]["max"] < 40.0
        assert min(r["inside_3sigma"].values()) > 0.95
