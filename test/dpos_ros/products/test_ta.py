"""Transfer alignment waits for the main POS to be aligned (its /master/nav covariance)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from repo_paths import REPO

from dpos_core.config import load_aircraft
from dpos_core.ta.pipeline import TASettings
from dpos_ros.io.session import read_session
from dpos_ros.products.solve import SubImuSource, solve
from dpos_ros.runtime.pool import process_pool

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"


def _session_with_unaligned_start(unaligned_s: float):
    sess = read_session(BAG)
    m = sess.master
    att_cov = m.att_cov.copy()
    early = m.t_s < m.t_s[0] + unaligned_s
    att_cov[early] = np.eye(3) * np.deg2rad(30.0) ** 2  # what pos_master_node publishes before the IFA aligns
    return replace(sess, master=replace(m, att_cov=att_cov), warnings=[])


def test_antenna_poses_start_when_the_main_pos_is_aligned() -> None:
    sess = _session_with_unaligned_start(10.0)
    ants, _ = solve(sess, load_aircraft("paper_su_pair"), TASettings(method="ukf", initial_attitude_error_deg=1.0))
    t0 = sess.master.t_s[0]
    first_aligned = sess.master.t_s[sess.master.t_s >= t0 + 10.0][0]
    for a in ants.values():
        assert a.status == "estimated" and a.rows is not None
        t_first = a.rows.read("t_s", 0, 1)[0]
        assert first_aligned - 1e-9 <= t_first < first_aligned + 0.02
    assert any("unaligned" in w and "10.0 s" in w for w in sess.warnings), sess.warnings


def test_a_never_aligned_main_pos_gives_no_antenna_and_says_why() -> None:
    sess = _session_with_unaligned_start(1e9)
    ants, _ = solve(sess, load_aircraft("paper_su_pair"), TASettings(method="ukf"))
    assert {a.status for a in ants.values()} == {"not estimated: the main POS is never aligned"}
    assert any("never aligned" in w for w in sess.warnings), sess.warnings


def test_an_imported_solution_is_aligned_and_its_attitude_sigma_kept() -> None:
    """An imported navigation solution (``dpos.master_source: solution``) whose attitude 1-sigma is
    0.3 deg throughout - its stated accuracy, not an in-flight alignment's state - is aligned from
    its first epoch (the live threshold would call it never aligned), and the sub-IMUs' attitude
    sigma does not fall below it, nor their velocity and position sigmas below the solution's (the
    filter averages the solution as white noise; its errors are correlated in time, so the rows
    add its covariances back).  The recorded main POS
    (the same data without the metadata) keeps the live rule."""
    sess = read_session(BAG)
    m = sess.master
    att_cov = np.repeat((np.eye(3) * np.deg2rad(0.3) ** 2)[None], m.t_s.size, axis=0)
    sess = replace(sess, master=replace(m, att_cov=att_cov), warnings=[])
    ac, st = load_aircraft("paper_su_pair"), TASettings(method="ukf", initial_attitude_error_deg=1.0)
    ants, _ = solve(sess, ac, st)
    assert {a.status for a in ants.values()} == {"not estimated: the main POS is never aligned"}
    sess = replace(sess, custom={**sess.custom, "dpos.master_source": "solution"}, warnings=[])
    ants, _ = solve(sess, ac, st)
    for a in ants.values():
        assert a.status == "estimated" and a.rows is not None
        assert abs(a.rows.read("t_s", 0, 1)[0] - m.t_s[0]) < 0.05
        sig = a.rows.read("sigma", 0, a.rows.n)
        assert np.all(sig[:, 0:3] >= np.deg2rad(0.3) * (1 - 1e-9)), sig[:, 0:3].min()
        for cols, cov in ((slice(3, 6), m.vel_cov), (slice(6, 9), m.pos_cov)):  # (velocity, position: the same)
            floor = np.sqrt(np.diagonal(cov, axis1=1, axis2=2).min(axis=0))
            assert np.all(sig[:, cols] >= floor * (1 - 1e-9)), (sig[:, cols].min(axis=0), floor)
    assert not any("aligned" in w for w in sess.warnings), sess.warnings


def test_workers_reading_the_recording_align_against_the_main_pos_they_are_sent() -> None:
    """A main POS other than the recorded one (dpos-process --master-reference forward | smoothed:
    here the recorded one made unaligned for 10 s) is sent to the workers that read their sub-IMU
    from the recording (``read_master=False``), not read there: the poses start when it is aligned."""
    sess = _session_with_unaligned_start(10.0)
    src = SubImuSource(bag=str(BAG), read_master=False)
    pool = process_pool(2)
    try:
        ants, _ = solve(replace(sess, sub_imus={}), load_aircraft("paper_su_pair"), TASettings(method="ukf", initial_attitude_error_deg=1.0),
                        source=src, pool=pool, sub_imus=sorted(sess.sub_imus))
    finally:
        pool.shutdown()
    first_aligned = sess.master.t_s[sess.master.t_s >= sess.master.t_s[0] + 10.0][0]
    assert {a.status for a in ants.values()} == {"estimated"}
    for a in ants.values():
        assert a.rows is not None and first_aligned - 1e-9 <= a.rows.read("t_s", 0, 1)[0] < first_aligned + 0.02
