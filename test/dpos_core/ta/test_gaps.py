"""Sub-IMU gaps in the transfer alignment: a gap is bridged honestly or the
span reported as not estimated, and the rows are flagged.

A paper_su_pair-like flight, shortened: 30 s straight, then a 60 deg right turn over 60 s and
back over 60 s (seed 1, URTSS, 1 deg prior).  Without the gap handling (``pipeline.run`` on the
cut data) a 60 s gap gave heading errors of ~100 deg with a heading sigma of 0.0004 deg and a
1 s gap in the turn 0.11 deg with 0.0003 deg (measured by hand when this test was written).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dpos_core.errors import RejectedInput
from dpos_core.evaluation import ta as from_sim
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.series import ImuSeries
from dpos_core.sim.flight import Segment
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import flags as F
from dpos_core.ta import pipeline
from dpos_core.ta.model import TAConfig, gap_limit_s
from dpos_core.ta.pipeline import TASettings

CFG = TAConfig(attitude_sigma_deg=1.0)
URTSS, UKF = TASettings(method="urtss"), TASettings(method="ukf")
R_EARTH_M = 6.378e6


@pytest.fixture(scope="module")
def flight():
    sc = load_scenario("paper_su", aircraft="paper_su_pair")
    sc = replace(sc, segments=(Segment(30.0, name="lead_in"), Segment(60.0, heading_change_deg=60.0, name="s_right"),
                               Segment(60.0, heading_change_deg=-60.0, name="s_left")))
    ss = SimulatedSession(sc, 1, None)
    return ss, from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")


def _cut(imu: ImuSeries, t0: float, t1: float) -> ImuSeries:
    """The samples stamped in (t0, t1] removed (a 100 Hz sample covers the 10 ms before its stamp)."""
    return imu.select((imu.t_s <= t0 + 1e-9) | (imu.t_s > t1 + 1e-9))


def _errors(ss: SimulatedSession, r: pipeline.TAResult) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """|heading error| (N,) [deg], its sigma (rotation about Up) [deg], horizontal position error
    (N,) [m] and its sigma (root sum of the east and north variances) [m], against the truth."""
    tr = ss.truth("sub_imu/sub_r", r.t_s)
    e_h = np.abs(np.rad2deg(hpr_error(hpr_from_C_nb(r.C_nb), hpr_from_C_nb(tr.C_nb))[:, 0]))
    d = r.llh - tr.llh
    e_p = np.hypot(d[:, 1] * R_EARTH_M * np.cos(tr.llh[:, 0]), d[:, 0] * R_EARTH_M)
    return e_h, np.rad2deg(r.sigma[:, 2]), e_p, np.hypot(r.sigma[:, 6], r.sigma[:, 7])


def _covered(e: np.ndarray, s: np.ndarray) -> float:
    """The fraction of errors within 2 sigma."""
    return float(np.mean(e <= 2.0 * s))


def test_gap_limit_is_at_least_a_few_steps() -> None:
    t100 = np.arange(1, 1000) * 0.01
    assert gap_limit_s(t100, TAConfig()) == pytest.approx(0.05)
    assert gap_limit_s(np.arange(1, 100) * 0.1, TAConfig()) == pytest.approx(0.3)  # 10 Hz: 3 steps
    with pytest.raises(ValueError):
        TAConfig(max_imu_gap_s=0.0)


def test_without_gaps_run_segments_is_run(flight) -> None:
    ss, imu, master, ins = flight
    sub = imu.select(imu.t_s <= 40.0)
    a = pipeline.run(sub, master, ins, URTSS, cfg=CFG)
    b = pipeline.run_segments(sub, master, ins, URTSS, cfg=CFG)
    np.testing.assert_array_equal(a.t_s, b.t_s)
    np.testing.assert_allclose(b.llh, a.llh, rtol=0, atol=1e-10)
    np.testing.assert_allclose(b.sigma, a.sigma, rtol=1e-9, atol=0)
    assert b.not_estimated == [] and not b.flags.any()


def test_a_60_s_gap_is_not_estimated_and_the_restart_is_covered_by_its_sigma(flight) -> None:
    """Gap 50-110 s (in the turns).  No row inside; every row after the gap is within 2 sigma in
    heading and horizontal position (the old behaviour: none was); the first 10 s after the
    restart are flagged, nothing else is."""
    ss, imu, master, ins = flight
    r = pipeline.run_segments(_cut(imu, 50.0, 110.0), master, ins, URTSS, cfg=CFG)
    assert not np.any((r.t_s > 50.0 + 1e-9) & (r.t_s <= 110.0 + 1e-9))
    assert len(r.not_estimated) == 1
    t_from, t_to, why = r.not_estimated[0]
    assert 49.0 - 1e-9 <= t_from <= 50.0 + 1e-9 and 110.0 < t_to < 110.1 and "sub-IMU gap of 60.0" in why
    after = r.t_s > 110.0
    e_h, s_h, e_p, s_p = _errors(ss, r)
    assert _covered(e_h[after], s_h[after]) == 1.0, (e_h[after].max(), s_h[after].min())
    assert _covered(e_p[after], s_p[after]) >= 0.95
    _assert_restart_flags(r, after)
    assert not np.any(r.flags & F.BRIDGED_GAP)


def _assert_restart_flags(r: pipeline.TAResult, after: np.ndarray) -> None:
    """RESTARTED_AFTER_GAP on the first restart_flag_s (to within a sample) of the rows ``after`` the gap only."""
    restarted = (r.flags & F.RESTARTED_AFTER_GAP) != 0
    since = r.t_s - r.t_s[after][0]
    assert not np.any(restarted & ~after)
    assert np.all(restarted[after & (since < CFG.restart_flag_s - 0.02)])
    assert not np.any(restarted[since > CFG.restart_flag_s + 0.02])


def test_one_second_of_removed_samples_in_a_turn(flight) -> None:
    """What the session reader leaves of 100 NaN samples: 1 s without samples, at 60 s in the
    right turn.  Not estimated over it; the errors are covered by the sigma; the restart flagged."""
    ss, imu, master, ins = flight
    r = pipeline.run_segments(_cut(imu, 60.0, 61.0), master, ins, URTSS, cfg=CFG)
    assert not np.any((r.t_s > 60.0 + 1e-9) & (r.t_s <= 61.0 + 1e-9))
    assert [why for *_, why in r.not_estimated] == ["sub-IMU gap of 1.010 s"]
    e_h, s_h, e_p, s_p = _errors(ss, r)
    after = r.t_s > 61.0
    assert _covered(e_h[after], s_h[after]) == 1.0
    assert _covered(e_p[after], s_p[after]) >= 0.95
    _assert_restart_flags(r, after)


def test_a_short_gap_is_bridged_with_more_process_noise_and_flagged(flight) -> None:
    """40 ms without samples (below max_imu_gap_s) in the turn: integrated across, the interval's
    rows flagged, its attitude sigma larger than without the gap, the errors covered."""
    ss, imu, master, ins = flight
    sub = imu.select(imu.t_s <= 80.0)
    ref = pipeline.run_segments(sub, master, ins, UKF, cfg=CFG)
    r = pipeline.run_segments(_cut(sub, 60.0, 60.04), master, ins, UKF, cfg=CFG)
    assert r.not_estimated == []
    bridged = (r.flags & F.BRIDGED_GAP) != 0
    assert bridged.any() and np.all((r.t_s[bridged] > 59.0) & (r.t_s[bridged] <= 61.1))
    assert not np.any(r.flags & F.RESTARTED_AFTER_GAP)
    # the forward filter's attitude sigma at the epoch after the gap grows with the unmeasured time
    k = int(np.searchsorted(r.epochs_s, 60.04))
    k_ref = int(np.searchsorted(ref.epochs_s, r.epochs_s[k] - 1e-9))
    assert np.sqrt(r.P[k, 2, 2]) > 1.5 * np.sqrt(ref.P[k_ref, 2, 2])
    e_h, s_h, _, _ = _errors(ss, r)
    assert _covered(e_h[r.t_s > 10.0], s_h[r.t_s > 10.0]) >= 0.95


def test_too_short_segments_are_not_estimated_and_nothing_left_raises(flight) -> None:
    ss, imu, master, ins = flight
    sub = imu.select(imu.t_s <= 40.0)
    # 20.5-20.8 s between two gaps: shorter than a filter interval
    cut = sub.select(((sub.t_s <= 20.0) | (sub.t_s > 20.5)) & ((sub.t_s <= 20.8) | (sub.t_s > 22.0)))
    r = pipeline.run_segments(cut, master, ins, UKF, cfg=CFG)
    assert len(r.not_estimated) == 1 and "too short" in r.not_estimated[0][2]
    assert not np.any((r.t_s > 20.0 + 1e-9) & (r.t_s <= 22.0 + 1e-9))
    with pytest.raises(RejectedInput, match="too short"):
        pipeline.run_segments(sub.select(sub.t_s <= 0.5), master, ins, UKF, cfg=CFG)
    with pytest.raises(RejectedInput):
        pipeline.run_segments(sub.select(slice(0, 0)), master, ins, UKF, cfg=CFG)
