"""The SINS/SAR model of [Yan2016] (dpos_core/sar) on short paper_sar sessions: the error
equations against the simulated truth, the measurement model, the fix availability and the
filters' accuracy."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.evaluation.sar import problem, run_methods, truth_errors
from dpos_core.sar.pipeline import METHODS, ORACLE, run
from dpos_core.sim.sar import baro_heights, sar_fixes
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession


@pytest.fixture(scope="module")
def prob():
    return problem(SimulatedSession(load_scenario("paper_sar"), 1, duration_s=300.0))


def test_error_equations_propagate_the_true_errors(prob) -> None:
    """f applied to the true error state at k predicts the true error state at k + 1 to the
    process noise: the attitude quaternion and velocity residuals are the IMU noise (rms within
    30 % of sqrt(Q)), the position residual within the model term; the free SINS's errors are
    change by 20x more per step (so a sign error would show)."""
    m, xt = prob.model, prob.truth_x
    pred = np.array([m.f(k, xt[k]) for k in range(m.n_epochs - 1)])
    rms = np.sqrt(np.mean((pred - xt[1:]) ** 2, axis=0))
    sq = np.sqrt(np.diag(m.Q(0)))
    np.testing.assert_allclose(rms[1:7], sq[1:7], rtol=0.3)
    assert np.all(rms[7:10] < 1.5 * sq[7:10])
    assert np.all(rms[10:] == 0.0)  # the simulated biases are constants
    step = np.sqrt(np.mean(np.diff(xt, axis=0) ** 2, axis=0))
    assert np.all(step[4:7] > 20 * rms[4:7])


def test_measurement_model_at_the_truth_is_white_with_R(prob) -> None:
    m, xt = prob.model, prob.truth_x
    z = [m.residual(m.y(k), m.h(k, xt[k])) / np.sqrt(np.diag(m.R(k))) for k in range(m.n_epochs) if m.meas.sar[k]]
    rms = np.sqrt(np.mean(np.array(z) ** 2, axis=0))
    assert np.all((rms > 0.8) & (rms < 1.2)), rms


def test_sar_fixes_only_while_the_radar_images() -> None:
    ss = SimulatedSession(load_scenario("paper_sar"), 2, duration_s=500.0)
    fx = sar_fixes(ss)
    a, b = ss.flight.segment_bounds("turn_right")
    assert not np.any((fx.t_s > a) & (fx.t_s < b))
    assert (a, b) == (360.0, 420.0)
    assert fx.t_s.size == 500 - 59  # 1 Hz, none strictly inside the turn
    bh = baro_heights(ss)
    assert bh.t_s.size == 5000
    tr = ss.truth("master", bh.t_s)
    assert np.std(bh.h_m - tr.llh[:, 2]) == pytest.approx(2.0, rel=0.05)


def test_gaussian_filters_and_oracle_reach_metres_and_arcminutes(prob) -> None:
    """EKF, UKF and the oracle over 100-300 s: position errors of a few metres (the fixes' 10 m
    averaged), heading to a fraction of an arcminute; the free SINS is off by tens to hundreds
    of metres."""
    r = run_methods(prob, ["ekf", "ukf", ORACLE], 100, 1)
    free = truth_errors(prob)
    for m, v in r.items():
        st = v["stats"]
        assert st["lon"]["mae"] < 4.0 and st["lat"]["mae"] < 4.0 and st["alt"]["mae"] < 1.0, (m, st)
        assert st["yaw"]["mae"] < 0.6 and st["pitch"]["mae"] < 0.6 and st["roll"]["mae"] < 0.6, (m, st)
    assert np.max(np.abs(free[100:, 3:5])) > 30.0


def test_bootstrap_pf_impoverishes_and_mcmc_moves_are_tried(prob) -> None:
    """The classical PF's cloud collapses ([Yan2016]'s degeneracy): after 100 s its velocity
    spread is below a tenth of the EKF's sigma on the same data while its error is larger; the
    modified PF's Metropolis-Hastings moves are tried and some accepted."""
    pf = run("pf", prob.model, prob.x0, prob.P0, n_particles=300, rng=np.random.default_rng(0))
    ekf = run("ekf", prob.model, prob.x0, prob.P0)
    sd_pf = np.sqrt(np.diagonal(pf.P[100:], axis1=1, axis2=2))[:, 4:7]
    sd_ekf = np.sqrt(np.diagonal(ekf.P[100:], axis1=1, axis2=2))[:, 4:7]
    assert np.median(sd_pf / sd_ekf) < 0.1
    err = lambda x: np.sqrt(np.mean((x[100:, 4:7] - prob.truth_x[100:, 4:7]) ** 2))  # noqa: E731
    assert err(pf.x) > err(ekf.x)
    mc = run("mcmc_rpf_literal", prob.model, prob.x0, prob.P0, n_particles=300, rng=np.random.default_rng(0))
    acc = mc.extra["accept"]
    assert np.isfinite(acc).any() and 0.0 < np.nanmean(acc) < 1.0
    assert np.all(np.isfinite(mc.x))


def test_windowed_mcmc_rpf_tracks_where_the_pf_collapses(prob) -> None:
    """The windowed MCMC-RPF (trajectory moves, filters/trajectory_move.py) with 300 particles over
    100-300 s: attitude MAE several times below the bootstrap PF's (same data, same particle
    count) and within 3x the EKF's (measured 1.8x), position within 3x (1.5x), its cloud not collapsed
    (velocity spread within a factor 2 of the EKF's sigma) and its moves accepted."""
    t = prob.model.track.t_s
    r = run_methods(prob, ["ekf", "pf", "mcmc_rpf"], 300, 0)
    att = {m: np.mean([r[m]["stats"][c]["mae"] for c in ("pitch", "roll", "yaw")]) for m in r}
    pos = {m: np.mean([r[m]["stats"][c]["mae"] for c in ("lon", "lat", "alt")]) for m in r}
    assert att["mcmc_rpf"] < att["pf"] / 3, att
    assert att["mcmc_rpf"] < 3 * att["ekf"] and pos["mcmc_rpf"] < 3 * pos["ekf"], (att, pos)
    mc = run("mcmc_rpf", prob.model, prob.x0, prob.P0, n_particles=300, rng=np.random.default_rng(0))
    ekf = run("ekf", prob.model, prob.x0, prob.P0)
    sel = t >= 100
    ratio = np.sqrt(np.diagonal(mc.P[sel], axis1=1, axis2=2))[:, 4:7] / np.sqrt(np.diagonal(ekf.P[sel], axis1=1, axis2=2))[:, 4:7]
    assert 0.5 < np.median(ratio) < 2.0, np.median(ratio)
    assert 0.1 < np.nanmean(mc.extra["accept"]) < 0.9


def test_unknown_method_is_named(prob) -> None:
    with pytest.raises(ValueError, match="unknown SINS/SAR method 'kf'"):
        run("kf", prob.model, prob.x0, prob.P0)
    with pytest.raises(ValueError, match="needs the true error states"):
        run(ORACLE, prob.model, prob.x0, prob.P0)
    assert METHODS == ("ekf", "ukf", "pf", "rpf", "mcmc_rpf", "mcmc_rpf_literal")


def test_bad_sar_block_is_named(tmp_path) -> None:
    """A non-positive rate or sigma in the sar: block is a ConfigError naming the key."""
    import yaml

    from dpos_core.config import ConfigError
    from dpos_core.config.files import read_yaml

    src = read_yaml("scenarios", "paper_sar")[0]
    src["sar"] = {**src["sar"], "baro_rate_hz": 0.0}
    p = tmp_path / "bad_sar.yaml"
    p.write_text(yaml.safe_dump({**src, "aircraft": "paper_sar"}))
    with pytest.raises(ConfigError, match="sar.baro_rate_hz must be > 0"):
        load_scenario(p)
