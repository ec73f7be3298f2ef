"""The aircraft file's ``mount_sigma_deg`` is the prior 1 sigma of the transfer alignment's rigid
misalignment rho (``Installation.rho_sigma_deg``); absent, ``TAConfig.rho_sigma_deg`` (1 deg)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dpos_core.evaluation import ta as from_sim
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import pipeline
from dpos_core.ta.model import RHO, Installation, TAConfig, TransferAlignmentModel
from dpos_core.ta.pipeline import TASettings
from dpos_core.units import DEG


@pytest.fixture(scope="module")
def su20():
    """20 s of paper_su's straight flight (rho = 0.5 / -0.5 / 0.5 deg, weakly observable before the S-turn)."""
    ss = SimulatedSession(load_scenario("paper_su"), 1, 20.0)
    return ss.scenario.aircraft, from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss)


def _install(aircraft, sigma: float | None) -> Installation:
    ac = replace(aircraft, sub_imus=tuple(replace(s, mount_sigma_deg=sigma) for s in aircraft.sub_imus))
    return Installation.from_aircraft(ac, "sub_r")


def _rho_sigma_deg(res: pipeline.TAResult) -> np.ndarray:
    """(K, 3) the filter's rho 1 sigma [deg] at its epochs."""
    return np.sqrt(np.diagonal(res.P[:, RHO, RHO], axis1=1, axis2=2)) / DEG


def test_the_mounting_sigma_is_rhos_prior(su20) -> None:
    aircraft, imu, master = su20
    default, given = _install(aircraft, None), _install(aircraft, 0.2)
    assert default.rho_sigma_deg is None and given.rho_sigma_deg == 0.2
    init = pipeline.initial_from_master(master, given, (0.0, 0.0, 0.0))
    for ins, want_deg in ((default, TAConfig().rho_sigma_deg), (given, 0.2)):
        _, P0 = TransferAlignmentModel(imu, master, ins, TAConfig(), init).prior()
        np.testing.assert_allclose(np.sqrt(np.diag(P0)[RHO]) / DEG, want_deg, rtol=1e-12)
        assert np.sqrt(np.diag(P0)[:3]) / DEG == pytest.approx(TAConfig().attitude_sigma_deg)  # nothing else moved


def test_the_filter_starts_rho_from_the_mounting_sigma(su20) -> None:
    """Through the pipeline (UKF, straight flight): with a 0.2 deg mounting sigma rho's sigma never
    exceeds 0.2 deg and the estimate stays nearer the given mounting than with the 1 deg default
    (rho is weakly observable here: the prior decides much of it)."""
    aircraft, imu, master = su20
    cfg = TAConfig(attitude_sigma_deg=1.0)
    wide = pipeline.run(imu, master, _install(aircraft, None), TASettings(method="ukf"), cfg=cfg)
    tight = pipeline.run(imu, master, _install(aircraft, 0.2), TASettings(method="ukf"), cfg=cfg)
    s_wide, s_tight = _rho_sigma_deg(wide), _rho_sigma_deg(tight)
    assert np.all(s_tight <= 0.2 + 1e-9), s_tight.max(axis=0)
    assert np.all(s_wide[0] > 0.5), s_wide[0]  # the 1 deg default, after one epoch
    assert np.all(s_tight[-1] <= s_wide[-1] + 1e-9), (s_tight[-1], s_wide[-1])
    assert np.linalg.norm(tight.x[-1, RHO]) < np.linalg.norm(wide.x[-1, RHO]) - 0.05 * DEG


def test_a_bad_rho_sigma_is_refused() -> None:
    ins = Installation.from_aircraft(load_scenario("paper_su").aircraft, "sub_r")
    for bad in (0.0, -0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="rho_sigma_deg"):
            replace(ins, rho_sigma_deg=bad)
