"""The SINS/SAR product path (dpos_core.sar.navigate: what sar_nav_node and dpos-sar run): it is the
evaluated filter on the same data, its settings reach the filter they name, and bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.attitude import quat_mul, rotvec_to_quat
from dpos_core.earth import enu_to_dllh
from dpos_core.evaluation.sar import ARCMIN, errors, noise_model, problem, run_methods
from dpos_core.sar import navigate as nav_mod
from dpos_core.sar.navigate import BaroSeries, SarNavSettings, navigate
from dpos_core.sar.pipeline import METHODS
from dpos_core.sim.sar import baro_heights, sar_fixes
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState


@pytest.fixture(scope="module")
def session():
    return SimulatedSession(load_scenario("paper_sar"), 1, duration_s=150.0)


def _initial_state(ss: SimulatedSession) -> NavState:
    """evaluate.problem's initial state: the truth with the scenario's initial errors."""
    d = ss.scenario.ifa
    tr0 = ss.truth("master", np.array([0.0]))
    q0 = quat_mul(rotvec_to_quat(np.asarray(d["initial_attitude_error_arcmin"]) * ARCMIN), tr0.q_nb[0])
    llh0 = tr0.llh[0] + enu_to_dllh(np.asarray(d["initial_position_error_m"], dtype=float), tr0.llh[0])
    return NavState(0.0, q0, tr0.vel_n_mps[0] + np.asarray(d["initial_velocity_error_mps"]), llh0)


def _settings(ss: SimulatedSession, **kw) -> SarNavSettings:
    nz = noise_model(ss)
    m = ss.scenario.master_imu
    return SarNavSettings(gyro_psd=nz.gyro_psd, accel_psd=nz.accel_psd, gyro_bias_sigma_deg_h=m.gyro_bias_deg_h,
                          accel_bias_sigma_ug=m.accel_bias_ug, **kw)


def test_navigate_is_the_evaluated_filter(session) -> None:
    """navigate() on the simulated IMU, fixes and barometer from evaluate.problem's initial state and
    prior gives the EKF of dpos-eval (run_methods) to rounding."""
    prob = problem(session)
    ref = run_methods(prob, ["ekf"], 10, seed=1)["ekf"]
    res = navigate(session.master_imu(), _initial_state(session), sar_fixes(session), baro_heights(session), _settings(session))
    np.testing.assert_allclose(res.t_s, prob.model.track.t_s)
    assert res.fixes_off_grid == 0 and res.sar.sum() == prob.model.meas.sar.sum()
    e = errors(prob, res.estimate.x)
    np.testing.assert_allclose(e, ref["err"], atol=1e-6)
    # the corrected SINS it returns is the one the errors are computed on; its covariances are proper
    assert np.all(np.linalg.eigvalsh(res.pos_cov) > 0) and np.all(np.linalg.eigvalsh(res.att_cov) > 0)
    assert np.all(np.sqrt(res.pos_cov[-1].diagonal()) < 5.0)


@pytest.mark.parametrize(("method", "particles", "seed", "bw"), [("ekf", 1000, 0, 1.0), ("ukf", 7, 3, 1.0), ("pf", 50, 4, 1.0),
                                                                 ("rpf", 60, 5, 0.5), ("mcmc_rpf", 70, 6, 2.0)])
def test_settings_reach_the_filter_they_name(session, monkeypatch, method, particles, seed, bw) -> None:
    """The method, particle count, bandwidth scale and seed of the settings are what pipeline.run gets
    (the seed as the generator's: the same seed, the same draws)."""
    seen: dict = {}
    real_run = nav_mod.run

    def spy(m, model, x0, P0, *, n_particles, rng, bandwidth_scale, **kw):
        seen.update(method=m, n_particles=n_particles, bandwidth_scale=bandwidth_scale, draw=rng.random())
        return real_run("ekf", model, x0, P0)

    monkeypatch.setattr(nav_mod, "run", spy)
    navigate(session.master_imu(), _initial_state(session), sar_fixes(session), baro_heights(session),
             _settings(session, method=method, n_particles=particles, seed=seed, bandwidth_scale=bw))
    assert seen["method"] == method and seen["n_particles"] == particles and seen["bandwidth_scale"] == bw
    assert seen["draw"] == np.random.default_rng(seed).random()


def test_a_particle_filter_runs_and_reports_its_ess(session) -> None:
    res = navigate(session.master_imu(), _initial_state(session), sar_fixes(session), baro_heights(session),
                   _settings(session, method="mcmc_rpf", n_particles=40, seed=2))
    assert 0 < res.extra["mean_ess"] <= 40 and 0 < res.extra["final_ess"] <= 40
    assert 0 <= res.extra["mean_accept"] <= 1
    assert np.all(np.isfinite(res.llh))


def test_bad_settings_and_data_are_refused(session) -> None:
    with pytest.raises(ValueError, match="unknown SINS/SAR method 'kf'"):
        SarNavSettings(method="kf")
    with pytest.raises(ValueError, match="n_particles >= 2"):
        SarNavSettings(method="pf", n_particles=1)
    assert SarNavSettings(method="ekf", n_particles=1).n_particles == 1  # unused by the Gaussian filters
    assert set(METHODS) == {"ekf", "ukf", "pf", "rpf", "mcmc_rpf", "mcmc_rpf_literal"}
    b = baro_heights(session)
    gap = (b.t_s < 40.0) | (b.t_s > 42.0)  # no barometer within half a step of t = 41 s
    with pytest.raises(ValueError, match="t = 41 s"):
        navigate(session.master_imu(), _initial_state(session), sar_fixes(session), BaroSeries(b.t_s[gap], b.h_m[gap], b.sigma_m),
                 _settings(session))
    with pytest.raises(ValueError, match="gyro_psd must be > 0"):
        navigate(session.master_imu(), _initial_state(session), sar_fixes(session), b, SarNavSettings())


def test_fixes_off_the_filter_grid_are_counted_not_used(session) -> None:
    fx = sar_fixes(session)
    moved = type(fx)(fx.t_s + np.where(np.arange(fx.t_s.size) % 10 == 0, 0.3, 0.0), fx.llh, fx.heading_rad, fx.pos_sigma_m, fx.heading_sigma_rad)
    res = navigate(session.master_imu(), _initial_state(session), moved, baro_heights(session), _settings(session))
    assert res.fixes_off_grid == int(np.ceil(fx.t_s.size / 10))
    assert res.sar.sum() == fx.t_s.size - res.fixes_off_grid
