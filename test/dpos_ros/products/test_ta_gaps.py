"""Sub-IMU gaps and unusable sub-IMU data in the session products: the span
of a gap is reported as not estimated, the rows after it flagged and covered by their sigma; a
sub-IMU without usable data gives ``not estimated`` for its antennas, the others unaffected."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core.config import config_text, load_aircraft
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import flags as F
from dpos_core.ta.pipeline import TASettings
from dpos_ros.devices.sim_streams import TopicStream, session_custom_data, session_streams
from dpos_ros.io import bag
from dpos_ros.io.session import read_session
from dpos_ros.products.solve import solve
from dpos_ros.products.write import write

SAMPLE_BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
_NAN = np.frombuffer(np.array([np.nan]).tobytes(), dtype=np.uint8)


def _nan_rows(s: TopicStream, sel: np.ndarray) -> TopicStream:
    """The stream with linear_acceleration.x (double 25 of 37 of sensor_msgs/Imu) := NaN on the rows ``sel``."""
    assert s.rows is not None
    rows = s.rows.copy()
    n = rows.shape[1]
    rows[np.ix_(sel, np.arange(n - 8 * 12, n - 8 * 11))] = _NAN
    return TopicStream(s.topic, s.msgtype, s.t_ns, rows=rows)


@pytest.fixture(scope="module")
def nan_session(tmp_path_factory: pytest.TempPathFactory):
    """45 s of paper_su_pair (seed 1) recorded with sub_l entirely NaN and 100 NaN samples of sub_r
    (stamps in (20, 21] s), read back: the reader removes them, leaving sub_l empty and a 1 s gap."""
    ss = SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 1, 45.0)
    t0_ns = int(round(ss.scenario.start_time_s * 1e9))
    streams = []
    for s in session_streams(ss):
        if s.topic == "/sub_imu/sub_l/imu":
            s = _nan_rows(s, np.arange(len(s)))
        elif s.topic == "/sub_imu/sub_r/imu":
            t = (s.t_ns - t0_ns) * 1e-9
            s = _nan_rows(s, np.nonzero((t > 20.0 + 1e-6) & (t <= 21.0 + 1e-6))[0])
        streams.append(s)
    d = tmp_path_factory.mktemp("nanbag")
    bag.write_streams(d / "bag", streams, custom_data=session_custom_data(ss, config_text("aircraft", "paper_su_pair")))
    return read_session(d / "bag"), d


def test_nan_samples_give_a_reported_gap_and_an_unusable_sub_imu_is_not_estimated(nan_session) -> None:
    sess, d = nan_session
    assert sess.sub_imus["sub_l"].t_s.size == 0 and np.sum(np.diff(sess.sub_imus["sub_r"].t_s) > 0.5) == 1
    ants, _ = solve(sess, load_aircraft("paper_su_pair"), TASettings(method="urtss"))
    # the all-NaN sub-IMU: not estimated, with a warning, instead of a traceback
    assert ants["ant_l"].status.startswith("not estimated: sub-IMU sub_l:") and ants["ant_l"].rows is None
    assert any(w.startswith("sub-IMU sub_l:") and "not estimated" in w for w in sess.warnings), sess.warnings
    # the other one: estimated except over the gap, which the status and a warning name
    a = ants["ant_r"]
    assert a.status == "estimated (not estimated over 20.0-21.0 s: sub-IMU gap of 1.010 s)", a.status
    assert any(w.startswith("sub-IMU sub_r: no pose over 20.0-21.0 s") for w in sess.warnings), sess.warnings
    b = a.block()
    t = b.traj.t_s
    assert not np.any((t > 20.0 + 1e-6) & (t <= 21.0 + 1e-6))
    after = t > 21.0
    restarted = (b.flags & F.RESTARTED_AFTER_GAP) != 0
    assert np.all(restarted[after & (t < 30.9)]) and not np.any(restarted[~after | (t > 31.1)])
    # the antenna after the gap against the truth: heading and horizontal position within 2 sigma
    tr = sess.truth["antenna/ant_r"]
    i = np.searchsorted(tr.t_s, t - 1e-7)
    assert np.allclose(tr.t_s[i], t, atol=1e-6)
    e_h = np.abs(np.rad2deg(hpr_error(hpr_from_C_nb(b.traj.C_nb), hpr_from_C_nb(tr.C_nb[i]))[:, 0]))
    d_llh = b.traj.llh - tr.llh[i]
    e_p = np.hypot(d_llh[:, 0] * 6.378e6, d_llh[:, 1] * 6.378e6 * np.cos(tr.llh[i, 0]))
    s_h, s_p = np.rad2deg(b.sigma[:, 2]), np.hypot(b.sigma[:, 6], b.sigma[:, 7])
    assert np.mean(e_h[after] <= 2 * s_h[after]) >= 0.95, (e_h[after].max(), s_h[after].min())
    assert np.mean(e_p[after] <= 2 * s_p[after]) >= 0.95, (e_p[after].max(), s_p[after].min())
    # the products: the flags column, the statuses
    out = write(d / "out", sess, ants, "urtss", {"processing_s": 1.0, "data_s": 45.0})
    rows = list(csv.DictReader(ln for ln in (out / "ant_r.csv").open() if not ln.startswith('#')))
    assert len(rows) == t.size
    fl = np.array([int(r["flags"]) for r in rows])
    np.testing.assert_array_equal(fl, b.flags)
    assert not (out / "ant_l.csv").exists()
    st = json.loads((out / "status.json").read_text())["antennas"]
    assert st["ant_r"].startswith("estimated (not estimated over") and st["ant_l"].startswith("not estimated")


@pytest.mark.parametrize("keep", [0, 50], ids=["empty", "half_a_second"])
def test_an_empty_or_too_short_sub_imu_is_not_estimated_and_the_other_is(keep: int) -> None:
    sess = read_session(SAMPLE_BAG)
    imu = sess.sub_imus["sub_l"]
    sess = replace(sess, sub_imus={**sess.sub_imus, "sub_l": imu.select(slice(0, keep))}, warnings=[])
    ants, _ = solve(sess, load_aircraft("paper_su_pair"), TASettings(method="ukf"))
    assert ants["ant_l"].status.startswith("not estimated: sub-IMU sub_l:") and ("sample" in ants["ant_l"].status or "too short" in ants["ant_l"].status)
    assert ants["ant_r"].status == "estimated" and ants["ant_r"].rows is not None
    assert not np.any(ants["ant_r"].rows.read("flags"))
    assert any(w.startswith("sub-IMU sub_l:") for w in sess.warnings), sess.warnings

