"""Quality flags of the least-squares wing fit's rows (dpos_core.ta.flags, dpos_core.ta.wingfit):
every fit row says it is one; a gap of a sub-IMU marks the rows fitted without it, and the
antennas it leaves outside the used sub-IMUs' spans as extrapolated; the sub-IMUs' own flags
reach the rows they entered."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dpos_core import earth
from dpos_core.attitude import rotvec_to_dcm
from dpos_core.config import load_aircraft
from dpos_core.frames import C_nb_from_hpr
from dpos_core.series import NavSeries
from dpos_core.ta import flags as F
from dpos_core.ta.wingfit import SubImuTrack, _flags_on_grid, fit_wing

SUB_SPANS = (1.0, 3.0, 5.0, 7.0, 9.0, 11.0)
ANT_SPANS = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
DT, T = 0.1, 300  # 30 s at 10 Hz
GAP = (10.0, 15.0)  # imu11 has no row here
RESTART_S = 2.0  # its rows after the gap: RESTARTED_AFTER_GAP
BRIDGED_AT = 22.0  # one row of imu11 with BRIDGED_GAP


def _wing(seed: int = 1) -> tuple[NavSeries, list[SubImuTrack], list[tuple[str, float, np.ndarray]]]:
    """A straight flight; six sub-IMUs on a wing bending as 1e-4 s^2 (slowly oscillating), with
    noise; the six antennas between and beyond them (paper_wing's layout)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * DT
    C = np.broadcast_to(C_nb_from_hpr(*np.deg2rad([30.0, 2.0, -3.0])), (T, 3, 3)).copy()
    vm = np.tile([50.0, 86.6, 0.0], (T, 1))
    llh = earth.offset_llh(np.tile([np.deg2rad(34.0), np.deg2rad(108.0), 1000.0], (T, 1)), vm * t[:, None])
    master = NavSeries.from_C_nb(t, C, vm, llh, omega_eb_b_radps=np.zeros((T, 3)))
    a = 1e-3 * np.sin(2 * np.pi * 0.2 * t)  # deflection z = a s^2, slope 2 a s about x
    subs = []
    for s in SUB_SPANS:
        r0 = np.array([0.0, -s, 0.0])
        th = np.stack([2 * a * s, 0 * t, 0 * t], -1)
        d = np.stack([0 * t, 0 * t, a * s * s], -1)
        Cs = rotvec_to_dcm(rng.normal(0.0, 5e-5, (T, 3))) @ C @ rotvec_to_dcm(th)
        p = earth.offset_llh(llh, np.einsum("tij,tj->ti", C, r0 + d) + rng.normal(0.0, 0.002, (T, 3)))
        v = vm + rng.normal(0.0, 0.001, (T, 3))
        sig = np.tile([5e-5] * 3 + [0.001] * 3 + [0.002] * 3, (T, 1))
        subs.append(SubImuTrack(f"imu{int(s):02d}", s, r0, np.eye(3), t, Cs, v, p, sig, F.none(T)))
    ants = [(f"ant{int(s):02d}", s, np.array([0.0, -s, 0.0])) for s in ANT_SPANS]
    return master, subs, ants


def _with_gap(tr: SubImuTrack) -> SubImuTrack:
    """``tr`` without its rows in GAP, the first RESTART_S after it flagged RESTARTED_AFTER_GAP and
    the row at BRIDGED_AT flagged BRIDGED_GAP (as pipeline.run_segments flags a sub-IMU)."""
    t = tr.t_s
    keep = (t < GAP[0] - 1e-9) | (t > GAP[1] - 1e-9)
    fl = F.none(t.size)
    fl[(t >= GAP[1] - 1e-9) & (t <= GAP[1] + RESTART_S + 1e-9)] |= F.RESTARTED_AFTER_GAP
    fl[np.abs(t - BRIDGED_AT) < 1e-9] |= F.BRIDGED_GAP
    return replace(tr, t_s=t[keep], C_nb=tr.C_nb[keep], vel_n_mps=tr.vel_n_mps[keep], llh=tr.llh[keep],
                   sigma=tr.sigma[keep], flags=fl[keep])


def test_uninterrupted_sub_imus_every_fit_row_is_flagged_wing_fit_and_the_outer_antenna_extrapolated() -> None:
    master, subs, ants = _wing()
    wf = fit_wing(master, subs, ants)
    for name, a in wf.antennas.items():
        assert a.flags is not None and a.flags.dtype == np.uint32 and a.flags.shape == a.traj.t_s.shape
        assert np.all(a.flags & F.WING_FIT), name
        assert not np.any(a.flags & (F.FEWER_SUB_IMUS | F.CARRIER_BITS)), (name, np.unique(a.flags))
        # ant12 is 1 m beyond the outermost sub-IMU (11 m); every other antenna is between two
        want = F.WING_FIT | (F.EXTRAPOLATED if name == "ant12" else 0)
        assert np.all(a.flags == want), (name, [F.describe(int(f)) for f in np.unique(a.flags)])


def test_a_sub_imu_gap_flags_the_rows_fitted_without_it() -> None:
    master, subs, ants = _wing(seed=2)
    subs[-1] = _with_gap(subs[-1])  # imu11, the outermost
    wf = fit_wing(master, subs, ants)
    t = wf.t_s
    in_gap = (t > GAP[0] - 1e-9) & (t < GAP[1] - 1e-9)
    restarted = (t >= GAP[1] - 1e-9) & (t <= GAP[1] + RESTART_S + 1e-9)
    bridged = np.abs(t - BRIDGED_AT) < 1e-9
    assert t.size == T and in_gap.sum() == 50 and restarted.sum() == 21 and bridged.sum() == 1  # the gap's epochs still have rows
    for name, a in wf.antennas.items():
        fl = a.flags
        assert fl is not None and np.all(fl & F.WING_FIT), name
        np.testing.assert_array_equal((fl & F.FEWER_SUB_IMUS) != 0, in_gap, err_msg=name)
        # imu11's own flags where it entered the fit (the restart and the bridged gap), nowhere else
        np.testing.assert_array_equal((fl & F.RESTARTED_AFTER_GAP) != 0, restarted, err_msg=name)
        np.testing.assert_array_equal((fl & F.BRIDGED_GAP) != 0, bridged, err_msg=name)
        # extrapolated: ant12 always; ant10 while imu11 (11 m) is missing (the outermost used is imu09 at 9 m)
        extra = (fl & F.EXTRAPOLATED) != 0
        want = np.ones(T, bool) if name == "ant12" else in_gap if name == "ant10" else np.zeros(T, bool)
        np.testing.assert_array_equal(extra, want, err_msg=name)


def test_a_gap_of_the_innermost_sub_imu_flags_the_inner_antenna_extrapolated() -> None:
    master, subs, ants = _wing(seed=3)
    subs = [*subs[1:], _with_gap(subs[0])]  # imu01 with the gap, last: the fit's epochs are subs[0]'s
    wf = fit_wing(master, subs, ants)
    in_gap = (wf.t_s > GAP[0] - 1e-9) & (wf.t_s < GAP[1] - 1e-9)
    fl = wf.antennas["ant02"].flags
    assert fl is not None
    np.testing.assert_array_equal((fl & F.EXTRAPOLATED) != 0, in_gap)  # 2 m is inside imu03 (3 m) then
    assert not np.any(wf.antennas["ant04"].flags & F.EXTRAPOLATED)


def test_a_flag_between_two_rows_reaches_the_epochs_between_them() -> None:
    """A sub-IMU on an offset grid (interpolated to the fit's epochs): a flagged row's bits reach
    both fit epochs it brackets; an epoch on a row's stamp takes that row's bits alone."""
    t = np.arange(10) * 0.1
    fl = F.none(10)
    fl[4] = F.BRIDGED_GAP
    tr = SubImuTrack("x", 1.0, np.zeros(3), np.eye(3), t + 0.05, np.tile(np.eye(3), (10, 1, 1)), np.zeros((10, 3)),
                     np.zeros((10, 3)), np.ones((10, 9)), fl)
    got = _flags_on_grid(tr, t)
    np.testing.assert_array_equal(np.nonzero(got)[0], [4, 5])  # 0.4 in (0.35, 0.45), 0.5 in (0.45, 0.55)
    np.testing.assert_array_equal(np.nonzero(_flags_on_grid(tr, t + 0.05))[0], [4])
    assert not np.any(_flags_on_grid(replace(tr, flags=None), t))
    fl[4] = 1 << 7  # a bit that is not the sub-IMU's own (reserved): not carried
    assert not np.any(_flags_on_grid(tr, t))


def test_fit_antennas_flags_every_row_when_a_sub_imu_of_the_wing_is_not_estimated() -> None:
    """products.solve.fit_antennas: paper_wing's right wing has six sub-IMUs; with imu09 not estimated
    at all the fit uses five and every fit row says so; with all six, none does."""
    from dpos_ros.products.solve import FIT_STATUS, fit_antennas

    aircraft = load_aircraft("paper_wing")
    master, subs, _ = _wing(seed=4)
    tracks = {tr.name: tr for tr in subs}
    warnings: list[str] = []
    full = fit_antennas(master, aircraft, tracks, warnings)
    del tracks["imu09"]
    five = fit_antennas(master, aircraft, tracks, warnings)
    assert not warnings
    fits = [a.name for a in aircraft.antennas if a.sub_imu is None]
    assert set(full) == set(five) == set(fits)
    for name in fits:
        assert full[name].status.startswith(FIT_STATUS) and five[name].status.startswith(FIT_STATUS), five[name].status
        f_full, f_five = full[name].flags, five[name].flags
        assert f_full is not None and f_five is not None and f_full.dtype == np.uint32
        assert np.all(f_full & F.WING_FIT) and not np.any(f_full & F.FEWER_SUB_IMUS), name
        assert np.all(f_five & F.WING_FIT) and np.all(f_five & F.FEWER_SUB_IMUS), name
    assert np.all(five["ant12"].flags & F.EXTRAPOLATED) and not np.any(five["ant08"].flags & F.EXTRAPOLATED)


def test_flag_names() -> None:
    assert F.describe(F.WING_FIT | F.EXTRAPOLATED | F.FEWER_SUB_IMUS | F.BRIDGED_GAP) == [
        "bridged_gap", "wing_fit", "extrapolated", "fewer_sub_imus"]
    assert F.describe(F.MASTER_UNALIGNED | F.INCONSISTENT_INNOVATIONS) == ["master_unaligned", "inconsistent_innovations"]
    assert F.describe(1 << 7) == ["bit7"]  # reserved
