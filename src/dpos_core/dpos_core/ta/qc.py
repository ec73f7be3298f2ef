"""Quality control of a transfer alignment without truth (docs/qc.md).

What a user can check about a session's poses before handing them on, from the solution itself:

* **NIS** (normalized innovation squared) at every filter epoch, ``nu^T S^-1 nu`` with ``dof`` = the
  number of measured components at that epoch: chi^2(dof) when the filter's model (its noises,
  its initial covariance, the main POS's covariance) describes the data.  Per epoch it is compared
  with its two-sided 99 % bounds; an epoch outside them happens 1 % of the time by chance, so
  isolated exceedances are counted, not flagged.  The flag is on the **windowed** NIS: over a
  centered window of ``window_s`` (60 s: 60 epochs at 1 Hz, 360 degrees of freedom for the
  6-component velocity and position match) the sum of the NIS over the sum of their dofs, which
  is chi^2(sum dof) / sum dof for a consistent filter (the innovations of a consistent filter are
  white, so the epochs' NIS are independent).  Above its two-sided 99 % bounds the innovations
  are *systematically* larger than the filter says (its covariances are optimistic: an
  unmodelled error, a noise too small, a mis-scaled main-POS covariance): the flag
  :data:`.flags.INCONSISTENT_INNOVATIONS` goes on every output row of an interval whose end epochs
  carry it.  Below the lower bound the filter is pessimistic: reported (``qc.md``), not flagged -
  the sigmas then overstate the errors, and the transfer alignment's own noise floors make it
  the normal case where the main POS is better than them (paper_su: the 1 cm position-match noise
  against a noise-free simulated main-POS position, mean NIS per dof 0.6; the per-match ratios
  ``nz2`` show which match).  The window trades detection delay for power: 60 s (540 dof with the
  9 matches) catches a covariance 1.3x too small (the 99.5 % point of the mean is 1.17) and is short
  against a session's manoeuvres, while an epoch's own bound (chi^2_9 99.5 % = 23.6, 2.6x its
  mean) misses a factor of 2 and fires by chance on 0.5 % of the epochs.
* **Forward/backward separation**: for a smoother, the difference between the filtered and the
  smoothed estimate at each epoch, per group (attitude, velocity, position), normalized by the
  covariance of that difference.  For the Gaussian (RTS) smoother ``x_s = E[x | all data]`` and
  ``x_f = E[x | data up to k]``, so the smoothed error is orthogonal to ``x_s - x_f`` and
  ``Cov(x_f - x_s) = P_f - P_s``: ``d^T (P_f - P_s)^+ d`` is chi^2 with the rank of ``P_f - P_s``
  as dof when the data agree with the model forward and backward.  The rank is what is left
  after dropping the eigenvalues below ``1e-6`` of ``trace(P_f)`` (the group's): at the last epoch
  (smoothed = filtered) and wherever the later data add nothing the difference is zero and has
  no dof.  The filtered sigma would be the other choice; it does not know how much the later data
  may move the estimate (a separation of 3 filtered sigmas can be expected after a manoeuvre
  resolves the heading) and tests nothing.  Also reported in physical units (deg, m/s, m): what
  the smoother moved the estimate by.  Forward-only methods (``ukf``, ``upf``) have none.
* **Master unaligned**: rows where the main POS's attitude 1-sigma (its ``/master/nav``
  covariance) is at or above the aligned threshold (:data:`.flags.MASTER_UNALIGNED`).

:func:`summarize` gathers, per antenna, the sigmas' percentiles, the NIS fractions, the
separation and the flagged time, and a verdict line; ``dpos_ros.products.write`` writes them as
``qc.md``, ``status.json`` ``qc`` and ``qc/<antenna>_qc.png``, for every session, without truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import DEG, FloatArray

from ..chi2 import chi2_ppf
from ..correlation import correlation_factor
from ..filters.store import PerEpoch, blocks, in_memory
from . import flags as F

#: the state groups of the separation: the first 9 error states (attitude rad, velocity m/s, position m)
GROUPS = (("attitude", slice(0, 3)), ("velocity", slice(3, 6)), ("position", slice(6, 9)))
#: window of the averaged NIS [s] and the two-sided probability of its bounds
WINDOW_S = 60.0
PROB = 0.99
#: an eigenvalue of P_f - P_s below this fraction of trace(P_f) (per group) carries no dof
REL_TOL = 1e-6
#: a verdict says "check" when a cause holds for more than this fraction of the rows (or epochs)
CHECK_FRACTION = 0.05
#: the wing fit's a posteriori variance factor or its cross-validation score above this: "check"
#: (its residuals twice their sigma)
FIT_SCORE_LIMIT = 4.0

#: the sigma columns (AntennaSolution.sigma (N, 9): phi E, N, U [rad]; dv E, N, U; dp E, N, U),
#: the names and scales of the report (the CSV's, deg for attitude)
SIGMA_COMPONENTS = (("rot_e_deg", 0, 1 / DEG), ("rot_n_deg", 1, 1 / DEG), ("heading_deg", 2, 1 / DEG),
                    ("vel_e_mps", 3, 1.0), ("vel_n_mps", 4, 1.0), ("vel_u_mps", 5, 1.0),
                    ("east_m", 6, 1.0), ("north_m", 7, 1.0), ("h_m", 8, 1.0))
#: the names of the transfer alignment's matches by the measurement size (ta.model: attitude,
#: velocity and, with ``use_position``, position, each E, N, U)
MATCHES = {9: tuple(f"{g}_{a}" for g in ("att", "vel", "pos") for a in "enu"), 6: tuple(f"{g}_{a}" for g in ("att", "vel") for a in "enu")}
#: the separation's unit per group (the attitude difference in deg)
SEP_UNITS = (("deg", 1 / DEG), ("m/s", 1.0), ("m", 1.0))


@dataclass
class EpochQC:
    """The consistency measures at the filter epochs ``epochs_s`` (K,): ``nis`` (K,) (NaN without a
    measurement) with ``dof`` (K,) the measurement size; ``sep`` (K, 3) the normalized
    forward/backward separation ``d^T (P_f - P_s)^+ d`` per :data:`GROUPS` with ``sep_dof`` (K, 3)
    (NaN / 0 where there is none) and ``sep_norm`` (K, 3) ``|x_f - x_s|`` per group (rad, m/s, m);
    ``smoothed``: a backward pass exists (else the separation is all NaN); ``nz2`` (K, p): each
    innovation component's ``nu_i^2 / S_ii`` (1 on average when consistent; NaN unmeasured);
    ``att_change`` (K,): the main POS's attitude change [rad] since the segment's first epoch
    (:func:`attitude_change`; None when not given): how much the data can show of a lever-arm error;
    ``nz`` (K, p): each innovation component's ``nu_i / sqrt(S_ii)``, signed (None when not kept):
    its correlation in time (:func:`correlation_factors`)."""

    epochs_s: FloatArray
    nis: FloatArray
    dof: NDArray[np.int_]
    sep: FloatArray
    sep_dof: NDArray[np.int_]
    sep_norm: FloatArray
    smoothed: bool
    nz2: FloatArray
    att_change: FloatArray | None = None
    nz: FloatArray | None = None

    @staticmethod
    def concat(parts: list[EpochQC]) -> EpochQC:
        """The segments' measures one after the other (``smoothed`` when all are)."""
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return EpochQC(cat("epochs_s"), cat("nis"), cat("dof"), cat("sep"), cat("sep_dof"), cat("sep_norm"),
                       all(p.smoothed for p in parts), cat("nz2"),
                       cat("att_change") if all(p.att_change is not None for p in parts) else None,
                       cat("nz") if all(p.nz is not None for p in parts) else None)


def nis(nu: FloatArray, S: FloatArray) -> tuple[FloatArray, NDArray[np.int_]]:
    """NIS ``nu^T S^-1 nu`` (K,) and its dof (K,) of innovations ``nu`` (K, p) with covariances
    ``S`` (K, p, p); a NaN component is not measured (its rows and columns of S are dropped), an
    epoch without any gives NaN and dof 0."""
    nu = np.asarray(nu, dtype=float)
    S = np.asarray(S, dtype=float)
    K = nu.shape[0]
    out = np.full(K, np.nan)
    meas = np.isfinite(nu)
    dof = meas.sum(axis=1).astype(int)
    p = nu.shape[1] if nu.ndim == 2 else 0
    full = (dof == p) & (p > 0)
    full &= np.all(np.isfinite(S.reshape(K, -1)), axis=1)
    if np.any(full):
        z = np.linalg.solve(S[full], nu[full][..., None])[..., 0]
        out[full] = np.einsum("ki,ki->k", nu[full], z)
    for k in np.flatnonzero(~full & (dof > 0)):
        m = meas[k]
        Sk = S[k][np.ix_(m, m)]
        if np.all(np.isfinite(Sk)):
            out[k] = float(nu[k, m] @ np.linalg.solve(Sk, nu[k, m]))
        else:
            dof[k] = 0
    dof[~np.isfinite(out)] = 0
    return out, dof


def separation(x_f: FloatArray, P_f: FloatArray, x_s: FloatArray, P_s: FloatArray,
               rel_tol: float = REL_TOL) -> tuple[FloatArray, NDArray[np.int_], FloatArray]:
    """The forward/backward separation (module docstring) of filtered ``x_f`` (K, n), ``P_f`` and
    smoothed ``x_s``, ``P_s``: per :data:`GROUPS`, ``d^T (P_f - P_s)^+ d`` (K, 3) on the
    eigenvalues of ``P_f - P_s`` above ``rel_tol trace(P_f)``, their number (K, 3) (NaN where 0),
    and ``|d|`` (K, 3)."""
    K = x_f.shape[0]
    sep = np.full((K, len(GROUPS)), np.nan)
    dof = np.zeros((K, len(GROUPS)), dtype=int)
    norm = np.empty((K, len(GROUPS)))
    for j, (_, g) in enumerate(GROUPS):
        d = x_f[:, g] - x_s[:, g]
        norm[:, j] = np.linalg.norm(d, axis=1)
        D = P_f[:, g, g] - P_s[:, g, g]
        D = 0.5 * (D + np.swapaxes(D, 1, 2))
        lam, V = np.linalg.eigh(D)
        tol = rel_tol * np.trace(P_f[:, g, g], axis1=1, axis2=2)
        keep = lam > np.maximum(tol, 1e-300)[:, None]
        z = np.einsum("kij,ki->kj", V, d)  # V^T d
        m = np.sum(np.where(keep, z * z / np.where(keep, lam, 1.0), 0.0), axis=1)
        dof[:, j] = keep.sum(axis=1)
        sep[:, j] = np.where(dof[:, j] > 0, m, np.nan)
    return sep, dof, norm


#: below this attitude change over a session (the main POS's, from its first epoch) a note says how
#: large a lever-arm error the data could not show [rad] (docs/qc.md "Installation errors": at 30 deg
#: an error of 0.2 m gives ``check``)
LEVER_ARM_ATTITUDE_CHANGE = 30.0 * DEG
#: the displacement ``|C_m(t) dr - C_m(t0) dr| = 2 |dr| sin(angle / 2)`` a lever-arm error must reach
#: to turn the verdict [m] (measured, docs/qc.md "Installation errors": paper_su's sub_r, turns of
#: 5-90 deg, seeds 1-5: from 0.087 m on ``check``, 0.044-0.07 m ``ok`` in all runs but one)
LEVER_ARM_VISIBLE_M = 0.1


def lever_arm_hidden_m(angle_rad: float) -> float:
    """The lever-arm error [m] below which a session whose main POS turned by at most ``angle_rad``
    cannot show it (:data:`LEVER_ARM_VISIBLE_M` over ``2 sin(angle / 2)``; inf without a turn)."""
    chord = 2.0 * math.sin(min(abs(angle_rad), math.pi) / 2.0)
    return LEVER_ARM_VISIBLE_M / chord if chord > 0.0 else math.inf


def attitude_change(t_master_s: FloatArray, q_nb: FloatArray, epochs_s: FloatArray) -> FloatArray:
    """The rotation angle [rad] (K,) of the main POS's attitude at each epoch ``epochs_s`` (K,) from its
    attitude at the first epoch (``q_nb`` (M, 4) scalar first, body to ENU, at ``t_master_s`` (M,);
    the sample at or before each epoch).  A lever-arm error ``dr`` enters the position match as
    ``C_m(t) dr - C_m(t0) dr`` once the sub-IMU has started at the configured arm (module
    docstring of :mod:`.model`): it shows only through this change."""
    t = np.asarray(t_master_s, dtype=float)
    e = np.asarray(epochs_s, dtype=float)
    if e.size == 0 or t.size == 0:
        return np.zeros(e.size)
    q = np.asarray(q_nb, dtype=float)[np.clip(np.searchsorted(t, e, side="right") - 1, 0, t.size - 1)]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return np.asarray(2.0 * np.arccos(np.clip(np.abs(q @ q[0]), 0.0, 1.0)), dtype=float)


#: epochs whose measures :func:`epoch_qc` computes at once
QC_BLOCK = 256


def epoch_qc(epochs_s: FloatArray, nu: PerEpoch, S: PerEpoch, x_f: PerEpoch, P_f: PerEpoch,
             x_s: PerEpoch | None = None, P_s: PerEpoch | None = None, block: int | None = None) -> EpochQC:
    """The :class:`EpochQC` of a filter's innovations ``nu`` (K, p), ``S`` (K, p, p) and its filtered
    ``x_f`` (K, n), ``P_f`` (K, n, n) and (if any) smoothed ``x_s``, ``P_s`` estimates: numpy arrays or
    :class:`~dpos_core.filters.store.EpochArray` files, read ``block`` epochs at a time (default
    :data:`QC_BLOCK`; every measure is per epoch: the same numbers whatever the block)."""
    K = np.asarray(epochs_s).size
    block = QC_BLOCK if block is None else max(int(block), 1)
    if K <= block:
        return _epoch_qc(epochs_s, in_memory(nu), in_memory(S), in_memory(x_f), in_memory(P_f),
                         None if x_s is None else in_memory(x_s), None if P_s is None else in_memory(P_s))
    sl = lambda a, k0, k1: np.asarray(a[k0:k1])  # noqa: E731
    return EpochQC.concat([_epoch_qc(np.asarray(epochs_s)[k0:k1], sl(nu, k0, k1), sl(S, k0, k1), sl(x_f, k0, k1), sl(P_f, k0, k1),
                                     None if x_s is None else sl(x_s, k0, k1), None if P_s is None else sl(P_s, k0, k1))
                           for k0, k1 in blocks(K, block)])


def _epoch_qc(epochs_s: FloatArray, nu: FloatArray, S: FloatArray, x_f: FloatArray, P_f: FloatArray,
              x_s: FloatArray | None = None, P_s: FloatArray | None = None) -> EpochQC:
    """:func:`epoch_qc` of arrays in memory at once."""
    v, dof = nis(nu, S)
    K = np.asarray(epochs_s).size
    with np.errstate(invalid="ignore", divide="ignore"):
        nz = np.asarray(nu, dtype=float) / np.sqrt(np.diagonal(np.asarray(S, dtype=float), axis1=1, axis2=2))
    nz2 = nz**2
    if x_s is None or P_s is None:
        return EpochQC(np.asarray(epochs_s, dtype=float), v, dof, np.full((K, 3), np.nan), np.zeros((K, 3), dtype=int),
                       np.full((K, 3), np.nan), False, nz2, nz=nz)
    sep, sdof, norm = separation(x_f, P_f, x_s, P_s)
    return EpochQC(np.asarray(epochs_s, dtype=float), v, dof, sep, sdof, norm, True, nz2, nz=nz)


def chi2_bounds(dof, prob: float = PROB) -> tuple[FloatArray, FloatArray]:
    """Two-sided ``prob`` bounds of chi^2(dof) (NaN for dof 0)."""
    d = np.asarray(dof, dtype=float)
    ok = d > 0
    lo = np.where(ok, chi2_ppf((1.0 - prob) / 2, np.where(ok, d, 1.0)), np.nan)
    hi = np.where(ok, chi2_ppf((1.0 + prob) / 2, np.where(ok, d, 1.0)), np.nan)
    return lo, hi


def windowed_nis(epochs_s: FloatArray, nis_k: FloatArray, dof: NDArray[np.int_], window_s: float = WINDOW_S,
                 prob: float = PROB) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per epoch, over the epochs within ``window_s / 2`` of it (centered): ``sum NIS / sum dof``
    (K,) and the two-sided ``prob`` bounds of that ratio, ``chi2.ppf(q, D) / D`` with D the sum
    of the dofs (NaN where the window has no measurement)."""
    t = np.asarray(epochs_s, dtype=float)
    ok = np.isfinite(nis_k) & (dof > 0)
    cs_n = np.concatenate([[0.0], np.cumsum(np.where(ok, nis_k, 0.0))])
    cs_d = np.concatenate([[0], np.cumsum(np.where(ok, dof, 0))])
    a = np.searchsorted(t, t - window_s / 2, side="left")
    b = np.searchsorted(t, t + window_s / 2, side="right")
    D = (cs_d[b] - cs_d[a]).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(D > 0, (cs_n[b] - cs_n[a]) / D, np.nan)
    lo, hi = chi2_bounds(D, prob)
    return ratio, lo / np.where(D > 0, D, 1.0), hi / np.where(D > 0, D, 1.0)


def inconsistent(epochs_s: FloatArray, nis_k: FloatArray, dof: NDArray[np.int_], window_s: float = WINDOW_S,
                 prob: float = PROB) -> NDArray[np.int8]:
    """Per epoch: +1 where the windowed NIS (:func:`windowed_nis`) is above its upper bound
    (innovations larger than the filter's covariance says: optimistic), -1 below the lower one
    (pessimistic), 0 consistent or not measured."""
    r, lo, hi = windowed_nis(epochs_s, nis_k, dof, window_s, prob)
    out = np.zeros(r.size, dtype=np.int8)
    out[np.isfinite(r) & (r > hi)] = 1
    out[np.isfinite(r) & (r < lo)] = -1
    return out


def rows_from_epochs(epochs_s: FloatArray, mask: NDArray[np.bool_], t_rows: FloatArray) -> NDArray[np.bool_]:
    """The output rows (stamps ``t_rows``) of a filter interval [t_k, t_k+1) one of whose end
    epochs has ``mask`` (the rows are interpolated from both); rows before the first or after
    the last epoch take that epoch's."""
    t = np.asarray(epochs_s, dtype=float)
    if t.size == 0:
        return np.zeros(np.asarray(t_rows).size, dtype=bool)
    k = np.clip(np.searchsorted(t, t_rows, side="right") - 1, 0, t.size - 1)
    k1 = np.minimum(k + 1, t.size - 1)
    at_end = np.asarray(t_rows) >= t[-1]
    return mask[k] | (mask[k1] & ~at_end)


def master_unaligned(t_master: FloatArray, att_sigma_rad: FloatArray, t_rows: FloatArray, threshold_rad: float) -> NDArray[np.bool_]:
    """Rows (stamps ``t_rows``) where the main POS's attitude 1-sigma ``att_sigma_rad`` (M,) (the
    largest axis, at ``t_master``) is at or above ``threshold_rad`` at the master epoch before or
    after the row."""
    t = np.asarray(t_master, dtype=float)
    bad = np.asarray(att_sigma_rad) >= threshold_rad
    if not np.any(bad):
        return np.zeros(np.asarray(t_rows).size, dtype=bool)
    i = np.clip(np.searchsorted(t, t_rows, side="right") - 1, 0, t.size - 1)
    return bad[i] | bad[np.minimum(i + 1, t.size - 1)]


def row_flags(t_rows: FloatArray, qc: EpochQC | None, master_t: FloatArray | None = None,
              master_att_sigma_rad: FloatArray | None = None, master_threshold_rad: float = 0.1 * DEG,
              window_s: float = WINDOW_S, prob: float = PROB) -> F.FlagArray:
    """The QC bits of a sub-IMU's rows: :data:`.flags.INCONSISTENT_INNOVATIONS` (from ``qc``,
    the windowed NIS above its bound: :func:`inconsistent` +1) and :data:`.flags.MASTER_UNALIGNED` (from the main POS's
    attitude sigma, when given)."""
    out = F.none(np.asarray(t_rows).size)
    if qc is not None and qc.epochs_s.size:
        bad = inconsistent(qc.epochs_s, qc.nis, qc.dof, window_s, prob) > 0
        out[rows_from_epochs(qc.epochs_s, bad, t_rows)] |= np.uint32(F.INCONSISTENT_INNOVATIONS)
    if master_t is not None and master_att_sigma_rad is not None:
        out[master_unaligned(master_t, master_att_sigma_rad, t_rows, master_threshold_rad)] |= np.uint32(F.MASTER_UNALIGNED)
    return out


def group_variance_factors(qc: EpochQC, window_s: float = WINDOW_S, prob: float = PROB) -> FloatArray:
    """Per epoch and match group (attitude, velocity, position: the :data:`MATCHES` triples), the
    factor by which the innovations say the filter's variances are too small (K, 3): the windowed
    mean of ``nu_i^2 / S_ii`` over the group's components (centered ``window_s``, as
    :func:`windowed_nis`) where it is above the upper two-sided ``prob`` bound of a consistent
    filter's (``chi2(D) / D``, D the samples in the window), else 1 (a consistent or pessimistic
    filter is left alone).  NaN where the group has no measurement in the window (the position
    without position matching)."""
    t = np.asarray(qc.epochs_s, dtype=float)
    K = t.size
    out = np.full((K, 3), np.nan)
    if K == 0 or qc.nz2.ndim != 2:
        return out
    a = np.searchsorted(t, t - window_s / 2, side="left")
    b = np.searchsorted(t, t + window_s / 2, side="right")
    for g in range(min(3, qc.nz2.shape[1] // 3)):
        z = qc.nz2[:, 3 * g:3 * g + 3]
        ok = np.isfinite(z)
        cs_z = np.concatenate([[0.0], np.cumsum(np.where(ok, z, 0.0).sum(axis=1))])
        cs_n = np.concatenate([[0], np.cumsum(ok.sum(axis=1))])
        D = (cs_n[b] - cs_n[a]).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(D > 0, (cs_z[b] - cs_z[a]) / D, np.nan)
        _, hi = chi2_bounds(D, prob)
        with np.errstate(invalid="ignore"):
            out[:, g] = np.where(np.isfinite(r), np.where(r > hi / np.where(D > 0, D, 1.0), r, 1.0), np.nan)
    return out


def sigma_scale(qc: EpochQC | None, t_rows: FloatArray, window_s: float = WINDOW_S, prob: float = PROB) -> FloatArray:
    """The multipliers (N, 9) of a sub-IMU's output 1-sigma (:class:`.pipeline.TAResult` ``sigma``
    columns: attitude, velocity, position, each E, N, U) that make it honest where the innovations
    say the filter is optimistic (docs/qc.md "Sigma inflation").

    The rule is the a posteriori variance factor of least squares, per match group: a linear
    filter whose process and measurement noises are all too small by a factor c has innovation
    covariances and posterior covariances too small by the same c, and the innovations measure c
    (:func:`group_variance_factors`).  The attitude sigma takes the attitude matches' factor, the
    velocity sigma the velocity matches', the position sigma the position matches' (the velocity
    matches' without position matching: the position is the integral of the velocity).  A group
    without a measurement in its window, or consistent, keeps 1.  Interpolated from the epochs to
    the rows ``t_rows`` (N,); the square root of the variance factor."""
    n = np.asarray(t_rows).size
    out = np.ones((n, 9))
    if qc is None or qc.epochs_s.size == 0:
        return out
    c = group_variance_factors(qc, window_s, prob)
    c[:, 2] = np.where(np.isfinite(c[:, 2]), c[:, 2], c[:, 1])
    c = np.where(np.isfinite(c), c, 1.0)
    for g in range(3):
        out[:, 3 * g:3 * g + 3] = np.sqrt(np.interp(t_rows, qc.epochs_s, c[:, g]))[:, None]
    return out


#: the largest lag [epochs] :func:`correlation_factors` sums the innovations' autocorrelation over
CORRELATION_MAX_LAG = 50


def correlation_factors(qc: EpochQC | None, max_lag: int = CORRELATION_MAX_LAG) -> FloatArray:
    """Per innovation component (p,), ``1 + 2 sum_j rho_j`` of its normalized innovations ``nz``
    over the session's measured epochs (``rho_j`` their autocorrelation at lag j epochs, summed up
    to the first lag where it is not positive, at most ``max_lag``; at least 1): the factor by
    which correlated innovations shrink the number of independent measurements.  The innovations
    of a filter whose measurement noise is what it assumes are white (factor 1); a main POS whose
    errors are correlated in time - an imported navigation solution, whose sigmas its producer
    states per epoch - gives factors of several, and the filter, taking every epoch as new
    information, averages its constants (the mounting above all) that many times too well.  The
    variance of a mean of N samples so correlated is the factor over N instead of 1 over N (the
    rule of ``dpos_core.imports.mounting``'s rate fit, for the same reason).  Empty without
    ``nz``."""
    if qc is None or qc.nz is None or qc.nz.ndim != 2:
        return np.ones(0)
    return np.array([correlation_factor(z[np.isfinite(z)], max_lag) for z in qc.nz.T])


def correlation_scale(qc: EpochQC | None, max_lag: int = CORRELATION_MAX_LAG) -> FloatArray:
    """The multipliers (9,) of a sub-IMU's output 1-sigma (attitude, velocity, position, each E, N,
    U: :class:`.pipeline.TAResult` ``sigma``) for innovations correlated in time: per column the
    square root of its match's :func:`correlation_factors` (the attitude sigma the attitude
    match's, and so on; the position the velocity match's without position matching, as
    :func:`sigma_scale`); 1 where there is no measure."""
    f = correlation_factors(qc, max_lag)
    out = np.ones(9)
    n = min(f.size, 9)
    out[:n] = np.sqrt(f[:n])
    if f.size == 6:
        out[6:9] = out[3:6]
    return out


# ----------------------------------------------------------------------------------- summary


def _row_durations(t: FloatArray) -> FloatArray:
    """Each row's share of the time: the step to the next row (the median step for the last one;
    steps longer than 5 median steps - gaps - count as one median step)."""
    if t.size < 2:
        return np.zeros(t.size)
    dt = np.diff(t)
    med = float(np.median(dt))
    dt = np.where(dt > 5 * med, med, dt)
    return np.append(dt, med)


def _pct(v: FloatArray) -> dict[str, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"p50": float("nan"), "p95": float("nan"), "max": float("nan")}
    p50, p95 = np.percentile(v, [50, 95])  # (one partition for both: the same values as one call each)
    return {"p50": float(p50), "p95": float(p95), "max": float(v.max())}


def summarize(t_rows: FloatArray, sigma: FloatArray | Callable[[int], FloatArray], flags: F.FlagArray | None, qc: EpochQC | None = None,
              wing_fit: dict | None = None, window_s: float = WINDOW_S, prob: float = PROB) -> dict:
    """The QC summary of one antenna (docs/qc.md; ``status.json`` ``qc``): rows and duration;
    ``sigma``: per component of :data:`SIGMA_COMPONENTS` the 50th / 95th percentile and the
    maximum; ``nis`` (with ``qc``): epochs, mean NIS per dof, the fractions of epochs outside the
    per-epoch two-sided ``prob`` bounds (chance: ``1 - prob``) and of the windowed NIS above / below
    its bounds; ``separation`` (with a smoother): per group the largest ``|x_f - x_s|`` (deg, m/s, m),
    the largest normalized separation as RMS sigmas ``sqrt(chi2 / dof)`` and the fraction of the
    epochs beyond the 99 % (one-sided) chi^2 bound; ``wing_fit`` (fit antennas): the fit's
    variance factors and its cross-validation scores at the chosen degree (and, without ``qc``, the
    :data:`.flags.INCONSISTENT_INNOVATIONS` its sub-IMUs carried in as a cause); ``flags``: per bit
    set on any row the flagged time [s] and fraction; ``verdict``: ``ok`` or ``check: ...``
    (the causes over :data:`CHECK_FRACTION` of the time), ``notes`` (causes below it).

    ``sigma``: the rows' 1-sigma (N, 9), or a function giving its column ``i`` (N,) (a long
    flight's rows read one column at a time)."""
    t = np.asarray(t_rows, dtype=float)
    dur = _row_durations(t)
    total = float(dur.sum())
    out: dict = {"rows": int(t.size), "duration_s": total}
    column = sigma if callable(sigma) else (lambda i: sigma[:, i])
    out["sigma"] = {name: _pct(column(i) * scale) for name, i, scale in SIGMA_COMPONENTS}
    checks: list[str] = []
    notes: list[str] = []
    if qc is not None and qc.epochs_s.size:
        ok = np.isfinite(qc.nis) & (qc.dof > 0)
        lo, hi = chi2_bounds(qc.dof, prob)
        n = int(ok.sum())
        side = inconsistent(qc.epochs_s, qc.nis, qc.dof, window_s, prob)
        frac = lambda m: float(np.sum(m & ok) / n) if n else float("nan")  # noqa: E731
        out["nis"] = {"epochs": n, "dof": int(np.median(qc.dof[ok])) if n else 0,
                      "mean_per_dof": float(np.sum(qc.nis[ok]) / np.sum(qc.dof[ok])) if n else float("nan"),
                      "above_bound_fraction": frac(qc.nis > hi), "below_bound_fraction": frac(qc.nis < lo),
                      "chance_fraction": (1.0 - prob) / 2, "window_s": window_s,
                      "windowed_above_fraction": frac(side > 0), "windowed_below_fraction": frac(side < 0)}
        nd = out["nis"]
        if qc.att_change is not None and qc.att_change.size:
            turn = float(np.nanmax(qc.att_change))
            out["attitude_change_deg"] = turn / DEG
            if turn < LEVER_ARM_ATTITUDE_CHANGE:
                hidden = lever_arm_hidden_m(turn)
                notes.append(f"lever arm not checked by the data: the main POS's attitude changed by at most {turn / DEG:.2g} deg; "
                             + ("no lever-arm error can show without a turn" if not math.isfinite(hidden) or hidden > 100.0
                                else f"a lever-arm error below about {hidden:.2g} m cannot show")
                             + " (it shows only through attitude changes: turns)")
        p = qc.nz2.shape[1] if qc.nz2.ndim == 2 else 0
        names = MATCHES.get(p, tuple(f"m{i}" for i in range(p)))
        nd["per_match"] = {nm: float(np.nanmean(qc.nz2[ok][:, i])) if n else float("nan") for i, nm in enumerate(names)}
        a = nd["windowed_above_fraction"]
        if n and a > 0:
            (checks if a > CHECK_FRACTION else notes).append(
                f"inconsistent innovations {100 * a:.0f} % of the time: larger than their covariance (sigmas optimistic)")
        b = nd["windowed_below_fraction"]
        if n and b > 0:
            low = ", ".join(f"{nm} {v:.2f}" for nm, v in nd["per_match"].items() if v < 0.5)
            notes.append(f"innovations smaller than their covariance {100 * b:.0f} % of the time (sigmas conservative"
                         + (f"; mean nu^2/S: {low})" if low else ")"))
        if qc.smoothed:
            sep: dict = {}
            for j, (g, _) in enumerate(GROUPS):
                unit, scale = SEP_UNITS[j]
                has = qc.sep_dof[:, j] > 0
                bound = np.where(has, chi2_ppf(prob, np.maximum(qc.sep_dof[:, j], 1)), np.nan)
                rms = np.sqrt(qc.sep[has, j] / qc.sep_dof[has, j]) if np.any(has) else np.array([])
                beyond = float(np.mean(qc.sep[has, j] > bound[has])) if np.any(has) else 0.0
                sep[g] = {"max_diff": float(np.nanmax(qc.sep_norm[:, j]) * scale) if qc.sep_norm.size else float("nan"),
                          "unit": unit, "max_sigmas": float(rms.max()) if rms.size else float("nan"),
                          "beyond_bound_fraction": beyond}
                if beyond > CHECK_FRACTION:
                    checks.append(f"forward/backward {g} separation beyond its 99 % bound at {100 * beyond:.0f} % of the epochs")
                elif beyond > 1.0 - prob:
                    notes.append(f"forward/backward {g} separation beyond its 99 % bound at {100 * beyond:.1f} % of the epochs")
            out["separation"] = sep
        else:
            out["separation"] = None
    if wing_fit is not None:
        deg = wing_fit.get("degree", {})
        score = {c: float(wing_fit["cv"][c][str(k)]["score"]) for c, k in deg.items()
                 if str(k) in wing_fit.get("cv", {}).get(c, {}) and "score" in wing_fit["cv"][c][str(k)]}
        vf = {c: float(v) for c, v in wing_fit.get("variance_factor", {}).items()}
        out["wing_fit"] = {"variance_factor": vf, "cv_score": score}
        worst = max(list(vf.values()) + list(score.values()), default=0.0)
        if worst > FIT_SCORE_LIMIT:
            checks.append(f"wing-fit residuals {np.sqrt(worst):.1f}x their sigma (variance factor / cross-validation score {worst:.1f})")
    fl = F.none(t.size) if flags is None else np.asarray(flags, dtype=np.uint32)
    per: dict[str, dict[str, float]] = {}
    for bit, name in F.NAMES.items():
        m = (fl & np.uint32(bit)) != 0
        if np.any(m):
            s = float(dur[m].sum())
            per[name] = {"time_s": s, "fraction": s / total if total > 0 else 0.0}
    out["flags"] = per
    causes = [(F.NAMES[F.MASTER_UNALIGNED], "main POS unaligned"), (F.NAMES[F.RESTARTED_AFTER_GAP], "restarted after a sub-IMU gap"),
              (F.NAMES[F.BRIDGED_GAP], "short sub-IMU gaps bridged"), (F.NAMES[F.EXTRAPOLATED], "wing fit extrapolated"),
              (F.NAMES[F.FEWER_SUB_IMUS], "fewer sub-IMUs in the wing fit")]
    if qc is None:  # a wing-fit antenna: the bit its sub-IMUs carried in (with qc, the NIS above says it)
        causes.append((F.NAMES[F.INCONSISTENT_INNOVATIONS], "sub-IMUs of the fit with inconsistent innovations"))
    for name, why in causes:
        if name in per:
            f = per[name]["fraction"]
            msg = f"{why} {per[name]['time_s']:.0f} s ({100 * f:.0f} %)"
            (checks if (f > CHECK_FRACTION or name == F.NAMES[F.MASTER_UNALIGNED]) and name != F.NAMES[F.EXTRAPOLATED] else notes).append(msg)
    out["verdict"] = "check: " + "; ".join(checks) if checks else "ok"
    out["notes"] = notes
    return out
