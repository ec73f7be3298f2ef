"""The vibration measure's residuals (dpos_core.ta._vibration_kernel): the lever arm in local ENU."""

from __future__ import annotations

import numpy as np

from dpos_core import earth
from dpos_core.frames import C_nb_from_hpr
from dpos_core.ta import _vibration_kernel
from dpos_core.units import DEG


def test_a_rigid_lever_arm_through_a_turn_entry_leaves_no_residual() -> None:
    """A sub-IMU 10 m out on a rigid wing, exactly where the main POS and the lever arm put it,
    through a heading kink (0 then 20 deg/s at mid-interval: not a straight line, so detrending
    does not hide an error in the lever-arm term): the position and velocity residual variances are
    zero.  With the lever arm subtracted in the wrong axis order (North/East swapped) the position
    residual varied by metres."""
    n = 101
    tm = np.linspace(100.0, 101.0, n)
    rate = np.where(tm > 100.5, 20.0 * DEG, 0.0)
    heading = 30.0 * DEG - np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(tm))])
    C_m = C_nb_from_hpr(heading, np.zeros(n), np.zeros(n))
    w_m = np.zeros((n, 3))
    w_m[:, 2] = rate
    r0 = np.array([0.5, 10.0, -0.3])
    lm = np.tile([40.0 * DEG, 116.0 * DEG, 500.0], (n, 1))
    vm = np.zeros((n, 3))
    lever_n = np.einsum("nij,j->ni", C_m, r0)
    lc = np.array([earth.offset_llh(lm[i], lever_n[i]) for i in range(n)])
    vc = np.einsum("nij,nj->ni", C_m, np.cross(w_m, r0))
    cov = np.zeros((n, 3, 3))
    out, mean_var = np.empty(6), np.empty(6)
    _vibration_kernel.residual_variance(tm, tm, vc, lc, vm, lm, C_m, w_m, r0, cov, cov, out, mean_var)
    assert np.all(out[3:] < 1e-8), out
    assert np.all(out[:3] < 1e-8), out
