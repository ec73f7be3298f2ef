"""solve(TASettings(use_position=False)): [Gong2018]'s attitude + velocity matching, the main POS's
position left out of the measurement (dpos-process / dpos-eval ``--no-position-matching``,
transfer_align_node ``position_matching``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta.pipeline import TASettings
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io.session import session_from_streams
from dpos_ros.products.evaluate import evaluate
from dpos_ros.products.solve import solve


@pytest.fixture(scope="module")
def walked_master():
    """60 s of paper_su whose main-POS position walks north by 2 m over the last 40 s while its
    velocity and attitude stay true (a position-only fault the two settings must see differently)."""
    sc = load_scenario("paper_su")
    ss = SimulatedSession(sc, 3, 60.0)
    sess = session_from_streams(session_streams(ss), session_custom_data(ss, ""), "pm")
    m = sess.master
    t = m.t_s - m.t_s[0]
    north_m = 2.0 * np.clip((t - 20.0) / 40.0, 0.0, 1.0)
    R_m, _ = earth.radii_of_curvature(m.llh[:, 0])
    llh = m.llh.copy()
    llh[:, 0] += north_m / (R_m + llh[:, 2])
    sess.master = dataclasses.replace(m, llh=llh)
    return sc, sess


@pytest.mark.parametrize("matching", [True, False])
def test_position_matching_follows_or_ignores_the_main_pos_position(walked_master, matching: bool) -> None:
    """With position matching the antenna is pulled along the walking main-POS position (error
    > 1 m at the end, and the fault reaches the attitude through the lever arm); without it the
    antenna keeps the velocity-integrated track (< 0.1 m) and the fault reaches nothing."""
    sc, sess = walked_master
    ants, _ = solve(sess, sc.aircraft, TASettings(method="urtss", use_position=matching))
    ev = evaluate(sess, ants)["ant_r"]
    lat_err_end = abs(float(ev["errors"]["lat_m"][-1]))
    if matching:
        assert lat_err_end > 1.0, lat_err_end
    else:
        assert lat_err_end < 0.1, lat_err_end
        assert ev["rmse"]["vel_n_mps"] < 0.02 and ev["rmse"]["heading_deg"] < 0.2, ev["rmse"]
