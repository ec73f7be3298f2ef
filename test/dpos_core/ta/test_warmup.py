"""The warm-up of the transfer-alignment workers (dpos_core.ta.warmup): its synthetic session is
physically consistent (a resting sub-IMU stays where the lever arm puts it), so warming runs the
real filters end to end, for every method."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.ta.model import TAConfig
from dpos_core.ta.pipeline import METHODS, TASettings, run_segments
from dpos_core.ta.warmup import resting_session, warm_up


@pytest.mark.parametrize("method", METHODS)
def test_resting_sub_imu_stays_at_its_lever_arm(method: str) -> None:
    imu, master, install = resting_session()
    res = run_segments(imu, master, install, TASettings(method=method, particles=8), cfg=TAConfig(attitude_sigma_deg=1.0))
    assert res.t_s[-1] - res.t_s[0] > 2.5  # rows up to the last filter epoch (1 Hz)
    expected = earth.offset_llh(master.llh[0], master.C_nb[0] @ install.lever_arm_m)
    d_enu = earth.dllh_to_enu(res.llh - expected, res.llh)
    assert np.max(np.abs(d_enu)) < 0.01  # exact data (a sign error of gravity or the lever arm: metres)
    assert np.max(np.abs(res.vel_n_mps)) < 0.01
    assert not res.not_estimated


def test_warm_up_runs_each_method() -> None:
    for method in METHODS:
        assert warm_up(method) > 0.0
