"""Divergence guard of a transfer-alignment run: a result that is no estimate raises
:class:`~dpos_core.errors.AlignmentDiverged` (never rows marked good).

Three checks, each of something no working alignment does (gross, so that a merely optimistic
filter - the real logs' NIS are 2-5 times their dof, docs/qc.md's sigma inflation - passes):

* ``non_finite``: a state estimate or covariance at an epoch is NaN or infinite
  (:func:`check_finite`);
* ``nis``: the forward filter's normalized innovations squared summed over :data:`NIS_WINDOW`
  consecutive measured epochs exceed :data:`NIS_GROSS_FACTOR` times the chi-square
  ``1 - NIS_ALPHA`` point of their summed degrees of freedom (:func:`check_nis`): the filter no
  longer describes the data (e.g. a sub-IMU logged in the wrong units);
* ``position_bound``: an output position farther from the main POS (interpolated at the row's
  stamp, rows in its gaps or outside it not checked) than the lever arm can reach:
  ``|r0| + LEVER_ARM_SIGMAS x sqrt(3) lever_arm_sigma + POSITION_MARGIN_M``
  (:func:`check_positions`; the smoother's blow-up of docs/transfer_alignment.md: 1e69 m).
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv

from dpos_core.units import FloatArray

from .. import earth
from ..errors import AlignmentDiverged
from ..filters.store import PerEpoch
from ..series import NavSeries
from .model import MASTER_GAP_S, Installation
from .qc import EpochQC

#: measured epochs over which the NIS is summed (at the default 1 Hz: 10 s, a sustained stretch)
NIS_WINDOW = 10
#: the window's NIS sum may exceed its chi-square bound by this factor before the run is diverged: about
#: 37 sigma RMS innovations for 10 epochs (a wing's flexure left out of the model: NIS / dof 2200 on
#: paper_su; a gyro logged in deg/s read as rad/s: 7e4 - 7e6; the real quad_mimu logs: 2 - 5)
NIS_GROSS_FACTOR = 1000.0
#: the chi-square bound's tail probability
NIS_ALPHA = 1e-3
#: an output position may be this much [m] beyond the lever arm's reach from the main POS
POSITION_MARGIN_M = 10.0
#: the lever arm's survey sigma counts this many times (per axis, sqrt(3) for the three)
LEVER_ARM_SIGMAS = 5.0
#: epochs read at once from a per-epoch array on disk
_BLOCK = 256


def check_finite(x: PerEpoch, P: PerEpoch, epochs_s: FloatArray, what: str) -> None:
    """AlignmentDiverged (``non_finite``) if a state x (K, n) or covariance P (K, n, n) at the
    epochs ``epochs_s`` (K,) is not finite (read ``_BLOCK`` epochs at a time)."""
    K = len(x)
    for k0 in range(0, K, _BLOCK):
        xb, Pb = np.asarray(x[k0:k0 + _BLOCK]), np.asarray(P[k0:k0 + _BLOCK])
        bad = ~(np.isfinite(xb).all(axis=1) & np.isfinite(Pb).all(axis=(1, 2)))
        if bad.any():
            k = k0 + int(np.argmax(bad))
            raise AlignmentDiverged(f"{what}: non-finite state or covariance at epoch {k} (t = {epochs_s[k]:.3f} s)",
                                    reason="non_finite", what=what, t_s=float(epochs_s[k]))


def nis_bound(dof: int) -> float:
    """The gross bound of a NIS sum of ``dof`` degrees of freedom: :data:`NIS_GROSS_FACTOR` x its
    chi-square ``1 - NIS_ALPHA`` point."""
    return NIS_GROSS_FACTOR * float(2.0 * gammaincinv(dof / 2.0, 1.0 - NIS_ALPHA))


def check_nis(qc: EpochQC, what: str) -> None:
    """AlignmentDiverged (``nis``) if the NIS of ``qc`` summed over any :data:`NIS_WINDOW`
    consecutive measured epochs exceeds :func:`nis_bound` of its summed dof (module docstring).
    Fewer measured epochs than the window: not checked (no sustained stretch)."""
    m = np.flatnonzero((qc.dof > 0) & np.isfinite(qc.nis))
    if m.size < NIS_WINDOW:
        return
    nis, dof = qc.nis[m], qc.dof[m].astype(int)
    cn = np.concatenate([[0.0], np.cumsum(nis)])
    cd = np.concatenate([[0], np.cumsum(dof)])
    s_nis = cn[NIS_WINDOW:] - cn[:-NIS_WINDOW]
    s_dof = cd[NIS_WINDOW:] - cd[:-NIS_WINDOW]
    bounds = {int(d): nis_bound(int(d)) for d in np.unique(s_dof)}
    over = s_nis > np.array([bounds[int(d)] for d in s_dof])
    if over.any():
        i = int(np.argmax(over))
        k0, k1 = int(m[i]), int(m[i + NIS_WINDOW - 1])
        raise AlignmentDiverged(
            f"{what}: innovations grossly inconsistent with their covariance from t = {qc.epochs_s[k0]:.3f} s to "
            f"{qc.epochs_s[k1]:.3f} s (NIS {s_nis[i]:.3g} over {NIS_WINDOW} epochs, {s_dof[i]} dof; bound "
            f"{bounds[int(s_dof[i])]:.3g})", reason="nis", what=what, t_s=float(qc.epochs_s[k0]))


def position_bound_m(install: Installation) -> float:
    """How far [m] an output position may be from the main POS (module docstring)."""
    return float(np.linalg.norm(install.lever_arm_m) + LEVER_ARM_SIGMAS * np.sqrt(3.0) * install.lever_arm_sigma_m + POSITION_MARGIN_M)


def check_positions(t_s: FloatArray, llh: FloatArray, master: NavSeries, install: Installation, what: str) -> None:
    """AlignmentDiverged (``position_bound``) if a row (stamps t_s (N,), positions llh (N, 3)
    ``[lat_rad, lon_rad, h_m]``) is farther from the main POS than :func:`position_bound_m`: the
    main POS interpolated linearly at the stamps, rows outside it or between its epochs more than
    ``MASTER_GAP_S`` apart not checked; a non-finite position is outside."""
    if t_s.size == 0:
        return
    tm = master.t_s
    j = np.searchsorted(tm, t_s)
    jj = np.clip(j, 1, tm.size - 1)
    ok = (t_s >= tm[0]) & (t_s <= tm[-1]) & ((tm[jj] - tm[jj - 1]) <= MASTER_GAP_S) if tm.size > 1 else t_s == tm[0]
    if not ok.any():
        return
    i = np.flatnonzero(ok)
    ref = np.column_stack([np.interp(t_s[i], tm, master.llh[:, c]) for c in range(3)])
    d = earth.dllh_to_enu(np.asarray(llh[i], dtype=float) - ref, ref)
    dist = np.linalg.norm(d, axis=1)
    bound = position_bound_m(install)
    bad = ~(dist <= bound)  # (NaN: outside)
    if bad.any():
        r = i[int(np.argmax(bad))]
        raise AlignmentDiverged(f"{what}: position {dist[int(np.argmax(bad))]:.3g} m from the main POS at t = {t_s[r]:.3f} s, "
                                f"beyond the lever arm's reach ({bound:.3g} m)", reason="position_bound", what=what, t_s=float(t_s[r]))
