"""ALIGNED on real units (#31 part 4): the heading sigma the IMU's grade can reach
(``IfaFilterConfig.aligned_heading_threshold_rad``), held over a window of epochs, with a consistent
NIS window.  On the simulated MEMS vehicle (scenario mems_vehicle, an automotive MEMS unit worse than
its datasheet, started from the data) with the default 0.1 deg floor, which a MEMS unit never reaches."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from dpos_core.config.sensors import imu_model
from dpos_core.evaluation import ifa as E
from dpos_core.frames import hpr_from_C_nb
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.ifa.pipeline import run
from dpos_core.ifa.reference import initial_state
from dpos_core.series import GnssSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG


def test_threshold_follows_the_grade():
    th = {g: IfaFilterConfig(imu=imu_model({"preset": g}, "test")).aligned_heading_threshold_rad / DEG
          for g in ("navigation_fog", "tactical", "automotive_mems", "consumer_mems")}
    assert th["navigation_fog"] == pytest.approx(0.1)  # the floor (aligned_heading_sigma_deg)
    assert th["tactical"] == pytest.approx(0.1146, abs=1e-3)  # 2 asin(1 mg)
    assert th["automotive_mems"] == pytest.approx(2.292, abs=1e-3)  # 2 asin(20 mg)
    assert th["consumer_mems"] > th["automotive_mems"]
    assert IfaFilterConfig().aligned_heading_threshold_rad / DEG == pytest.approx(0.1)  # paper_ifa's unit: unchanged


@pytest.fixture(scope="module")
def mems():
    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 3)
    imu, g = ss.master_imu(), ss.gnss()
    cfg = replace(E.filter_config(sc), aligned_heading_sigma_deg=0.1)  # not the scenario's hand-set 1.0
    on_imu = GnssSeries(g.t_s - cfg.gnss_time_offset_s, g.llh, g.pos_sigma_m, g.vel_n_mps, g.vel_sigma_mps)
    init = initial_state(imu, on_imu, 0.0, lever_arm_m=np.asarray(sc.aircraft.gnss_lever_arm_m))
    return sc, ss, imu, g, cfg, init


def _run(mems, t_end: float | None = None, **kw):
    sc, ss, imu, g, cfg, init = mems
    if t_end is not None:
        imu = imu.select(imu.t_s <= t_end)
        k = g.t_s <= t_end - 1.0
        g = GnssSeries(g.t_s[k], g.llh[k], g.pos_sigma_m[k], g.vel_n_mps[k], g.vel_sigma_mps[k])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run(imu, g, sc.aircraft.gnss_lever_arm_m, replace(cfg, **kw), "add2", init)


def test_a_converging_mems_run_aligns_with_its_heading_inside_the_sigma(mems):
    """With the standstill updates (the default): the vertical gyro bias from the 30 s at rest (ZARU)
    holds the heading the acceleration at 30-45 s gives, and it aligns before the first turn
    (measured 54 s, heading error -1.75 deg, sigma 1.16 deg); without them only after the first
    turn (65-80 s; measured 77 s).  The heading error at that epoch within 3 sigma and small from
    then on."""
    _, ss, *_ = mems
    res = _run(mems)
    assert res.aligned_t_s is not None and 50.0 < res.aligned_t_s < 120.0, res.aligned_t_s
    k = int(np.searchsorted(res.epochs_s, res.aligned_t_s))
    i = np.searchsorted(res.t_s, res.epochs_s[k:])
    h = hpr_from_C_nb(res.C_nb[i])[:, 0]
    err = np.angle(np.exp(1j * (h - ss.truth("master", res.t_s[i]).hpr_rad[:, 0]))) / DEG
    assert abs(err[0]) < 3.0 * res.heading_sigma_deg[k], (err[0], res.heading_sigma_deg[k])
    assert np.max(np.abs(err)) < 3.0  # deg, from the alignment to the end


def test_a_run_that_does_not_converge_does_not_align(mems):
    """Standing, then accelerating and driving straight (no turn, 0-62 s), without the standstill
    updates (no vertical gyro bias from the rest, so the heading the acceleration gives drifts): the
    heading sigma dips under the grade's reach during the acceleration and rises again - not
    ALIGNED; the same run with the filter's GNSS noise 10x too small (NIS inconsistent, the
    fixed-noise DD2) is not ALIGNED either."""
    assert _run(mems, 62.0, standstill_updates=False).aligned_t_s is None
    sc, ss, imu, g, cfg, init = mems
    cfg = replace(cfg, standstill_updates=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tight = replace(cfg, gnss_pos_sigma_m=(0.05, 0.05, 0.1), gnss_vel_sigma_mps=(0.005, 0.005, 0.01))
        res = run(imu, g, sc.aircraft.gnss_lever_arm_m, tight, "dd2", init)
    assert res.aligned_t_s is None
