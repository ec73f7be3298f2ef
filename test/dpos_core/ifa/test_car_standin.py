"""A simulated stand-in for #31's held-out car (#31 parts 1-2): the scenario mems_vehicle (an
automotive MEMS unit worse than its datasheet, 100 Hz, 30 s at rest before it drives, 1 Hz GNSS, a
30 s outage while turning) with the IMU mounted backwards, run as a new user runs it: the
``automotive_mems`` preset and the installation only (the mount's input rotation, yaw 180 deg; the
GNSS lever arm; the receiver's stamp offset and sigmas), everything else the defaults, the start at
the first fix, at rest (``dpos-ifa --min-course-speed 0``).  It must reach ALIGNED, use the
standstill, and keep its errors against the truth inside 3 sigma.  One run, about 3 s of CPU."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from dpos_core.config.sensors import imu_model
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.ifa.pipeline import run
from dpos_core.ifa.reference import Reference, compare, start
from dpos_core.series import ImuSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession

OUTAGE_S = (150.0, 180.0)


@pytest.fixture(scope="module")
def car():
    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 3)
    body, gnss = ss.master_imu(), ss.gnss()
    # the unit's axes in the body's: mounted backwards; its driver reports R^T b, the installation's
    # input rotation (pos_master_node's input_rotation_rpy_deg [0, 0, 180]) takes it back to the body's
    R = np.diag([-1.0, -1.0, 1.0])  # yaw 180 deg
    drv = ImuSeries(body.t_s, body.omega_radps @ R, body.f_mps2 @ R)
    assert np.abs(drv.f_mps2[:100, 0] + body.f_mps2[:100, 0]).max() < 1e-12  # x reversed
    imu = ImuSeries(drv.t_s, drv.omega_radps @ R.T, drv.f_mps2 @ R.T)
    lever = np.asarray(sc.aircraft.gnss_lever_arm_m)
    cfg = IfaFilterConfig(imu=imu_model({"preset": "automotive_mems"}, "car"), gnss_pos_sigma_m=tuple(sc.gnss.pos_sigma_m),
                          gnss_vel_sigma_mps=tuple(sc.gnss.vel_sigma_mps), gnss_time_offset_s=sc.gnss.stamp_offset_s)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        init, lv = start(imu, gnss, 0.0, heading_rad=0.0, lever_arm_m=lever, gnss_time_offset_s=cfg.gnss_time_offset_s,
                         level="auto", imu_model=cfg.imu)
        if lv is not None and lv.sigma_rad is not None and np.degrees(lv.sigma_rad) > cfg.level_sigma_deg:
            cfg = replace(cfg, level_sigma_deg=float(np.degrees(lv.sigma_rad)))  # as dpos-ifa does
        res = run(imu, gnss, lever, cfg, "add2", init, record_smoother=True)
    tr = ss.truth("master", np.arange(1.0, float(imu.t_s[-1]) - 1.0, 0.25))
    rep = compare(res, Reference(tr.t_s, tr.llh, tr.vel_n_mps, np.zeros((tr.t_s.size, 3))), OUTAGE_S)
    return cfg, res, rep


def test_the_preset_alone_sets_the_model(car):
    cfg, *_ = car
    assert not cfg.axis_states and cfg.standstill_updates and cfg.zaru and not cfg.zupt  # the preset's and the defaults


def test_aligns_using_the_standstill(car):
    """At rest 0-30 s (the drive's smooth start leaves the first second after it at rest too): ZARU at
    those epochs; ALIGNED once the drive starts (measured 53 s), no restart."""
    _, res, rep = car
    rest = res.epochs_s[res.at_rest == 1.0]
    assert rest.size >= 20 and rest.max() < 32.5, rest
    assert all(c == ("zaru",) for c, r in zip(res.constraints, res.at_rest) if r == 1.0)
    assert rep.aligned_t_s is not None and rep.aligned_t_s < 100.0 and res.restarts == 0 and not res.rejected


def test_the_fine_restart_keeps_the_vertical_gyro_bias_from_the_rest(car):
    """The end of the coarse phase restarts the attitude and bias covariance from the priors, except
    the gyro bias about Up, which keeps the variance the ZARU at rest gave (plus the bias walk since):
    with it reset to the preset's 0.2 deg/s the fine phase's heading error leaked into the vertical
    bias (docs/ifa.md, "ZUPT and ZARU")."""
    cfg, res, _ = car
    e = res.engine
    (step,) = [s for s in e.smoother_steps if s.restart is not None]
    ie, _ = e.model.bias_index
    B = step.restart[1][ie, ie]
    u = res.C_nb[int(np.searchsorted(res.t_s, step.t_s))][2]  # Up in IMU axes at the restart
    prior_dps = cfg.imu.gyro_bias_deg_h / 3600.0  # the preset's turn-on bias, 0.2 deg/s
    sig_up = np.degrees(np.sqrt(u @ B @ u))
    assert sig_up < 0.01 * prior_dps, sig_up  # deg/s: the rest's, not the prior's
    w, V = np.linalg.eigh(B)
    assert np.allclose(np.degrees(np.sqrt(w[1:])), prior_dps, rtol=1e-6), np.degrees(np.sqrt(w))  # the other two: the prior
    assert abs(V[:, 0] @ u) > 1.0 - 1e-9


def test_errors_inside_three_sigma(car):
    """Measured: before the outage rms 0.22 m, in it max 19.7 m (30 s, in a 120 deg turn), after rms
    0.29 m; every axis inside 3 sigma (1.00; at least 0.95 asserted; #31: the car's were 0.50-0.86)."""
    _, _, rep = car
    e = rep.horizontal_error_m
    print(f"car stand-in: aligned {rep.aligned_t_s:.0f} s; before rms {e['before']['rms']:.2f} m, during max {e['during']['max']:.1f} m, "
          f"after rms {e['after']['rms']:.2f} m; inside 3 sigma {rep.inside_3sigma}")
    assert min(rep.inside_3sigma.values()) >= 0.95, rep.inside_3sigma
    assert e["before"]["rms"] < 0.5 and e["after"]["rms"] < 1.0 and e["during"]["max"] < 40.0, e
