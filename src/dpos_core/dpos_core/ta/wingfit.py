"""Least-squares wing fit: the motion of antennas without a sub-IMU ([LSFit] sec. 2).

[LSFit] sec. 2 fits, at each epoch, a polynomial of order k along the wing to the latitudes (and
the other motion parameters) that transfer alignment gives at the n' sub-IMUs, and evaluates it at
the spans of the antennas without an IMU; it sets k = n' = 6 (its eq. 13-15; the equations were
lost in our copy, the text around them survives).  Six coefficients through six points interpolate
exactly, with no redundancy to average the sub-IMUs' errors and a polynomial that swings outside
the outermost IMU (its antenna No. 12).  Here instead:

* What is fitted is the wing's *deformation relative to the rigid aircraft*, not the raw
  positions: per sub-IMU ``i`` at span ``s_i`` and epoch ``t`` (body axes ``b`` of the main POS)

  - flexure angles ``theta_i`` (3, rad): ``expm([theta_i x]) = C_nb^T C_ns,i (C_mount,i expm([rho_i x]))^T``
    with the sub-IMU's smoothed attitude ``C_ns,i``, the main POS attitude ``C_nb``, the nominal
    mount and the rigid misalignment ``rho_i`` (:func:`rigid_misalignment`);
  - deflection ``d_i`` (3, m): ``C_nb^T (p_i - p_m) - r0_i`` (``r0_i`` the nominal lever arm);
  - deflection rate ``d_dot_i`` (3, m/s): ``C_nb^T (v_i - v_m) - omega_eb^b x (r0_i + d_i)``,

  each with the variance from the sub-IMU's smoothed 1-sigma.  The rigid part (the lever arm,
  12 m at the tip) is then exact, and what is fitted is centimetres and tenths of a degree that
  vanish at the wing root.
* The rigid misalignment ``rho_i``: the total rotation ``Theta_i = log(C_nb^T C_ns,i C_mount,i^T)``
  is what the sub-IMU measures (its attitude error is 0.001-0.005 deg); splitting it into a
  constant and the flexure needs a convention, and the one that holds for a wing is that the
  elastic deformation is the departure from the 1 g flight shape: zero mean at a load factor of 1,
  plus the quasi-static bending proportional to ``n - 1``.  So ``rho_i`` is the intercept of the
  regression of ``Theta_i(t)`` on ``[1, n(t) - 1]`` over the session (``n`` from the main POS's
  specific force; the slope only where the load factor varies, std(n - 1) > 0.01), its variance
  from batch means of the residuals (the residual is the wing's vibration, correlated over
  seconds).  Its error is the session mean of the flexure, smooth along the span: the fit absorbs
  it like a deformation, so it is no point noise of the fit; it is added to the fitted antenna's
  attitude variance (the sub-IMUs' values interpolated along the span) instead.  Not the
  transfer alignment's rho state (15:18): its Gauss-Markov flexure prior ([Gong2018] eq. 13: tau 5 s, a low-pass process with most of its power near 0 Hz) cannot tell a
  lightly damped 1 Hz bending mode, whose power at 0 Hz is ~1e-4 of its variance, from a constant,
  and on paper_wing's modal wing its rho_x erred by 0.94 deg at 11 m (4.6 of its sigmas) where the
  session mean of ``Theta`` erred by 0.012 deg (120 s, seed 1).  A constant attitude error of the
  sub-IMU (its heading, which straight flight does not observe) enters ``Theta`` and ``rho_i``
  alike and cancels in ``theta_i``.
* Basis: a clamped cantilever's deflection and slope vanish at the root ``s = 0`` (span measured
  from the main POS; ``root_span_m`` moves it), so the candidates are ``sum_{j=1..k} a_j s^j`` for
  the angles and ``sum_{j=2..k} a_j s^j`` for the deflection and its rate, k = 0..``max_degree``
  (k = 0: no deformation of that component).  Each of the 9 components (3 angles, 3 deflections,
  3 rates) gets its k by leave-one-out cross-validation over the sub-IMUs computed on the whole
  session (one choice per component, stable in time): every sub-IMU in turn is left out of each
  epoch's fit, predicted from the others, and its residual scaled by its own 1-sigma; the
  candidate with the smallest mean squared scaled residual wins (too few terms: the residuals
  hold the unmodelled shape; too many: the prediction's variance grows, most at the ends).
  Extrapolation (antenna 12 beyond the sub-IMU at 11 m) enters the score for the outermost IMU, so
  a basis that swings outside the IMUs loses.
* The main POS's error at an epoch (paper_wing's reference: white, 5 cm, 0.005 m/s, 0.002-0.005
  deg) is in every sub-IMU's deflection, rate and angle alike; with 4 or more sub-IMUs each
  component gets a constant term that estimates it (:func:`powers`), so the antennas carry the fit's
  error instead of the raw main POS's (on paper_wing, 120 s: ant02's position error 3.9 cm with the
  raw main POS beside 1.3 cm at its IMU-carrying neighbours).
* Fit: per epoch and component, weighted least squares with the sub-IMUs' variances (Cholesky
  solves of the normal equations, vectorised over epochs); the parameter covariance is scaled by
  the a posteriori variance factor of the session (chi^2 / degrees of freedom, at least 1: the
  fit's residuals, when larger than the sigmas say, widen the covariance).
* Antenna at span ``s_a``, lever arm ``r_a`` (master axes):
  ``theta_a = b(s_a)^T a_theta``, ``d_a = b(s_a)^T a_d + (expm([theta_a x]) - I) o_a``
  (``o_a``: the antenna's offset across the wing, x and z, from the sub-IMUs' lever arms
  interpolated to ``s_a``: the section is rigid), position ``p_m + C_nb (r_a + d_a)``, velocity
  ``v_m + C_nb (omega x (r_a + d_a) + d_dot_a + theta_dot_a x o_a)``, attitude
  ``C_nb expm([theta_a x])`` (the antenna's axes are the main POS's: ``fit`` antennas have no mount).
  Covariance: ``b^T P_a b`` per component (grows beyond the outermost IMU through the basis) rotated
  to ENU, plus the main POS's attitude, velocity and position covariances and the attitude's
  effect through the lever arm.
* Flags (:mod:`dpos_core.ta.flags`) per antenna row: ``WING_FIT`` always; ``EXTRAPOLATED`` where
  the antenna's span is outside those of the sub-IMUs used at the epoch; ``FEWER_SUB_IMUS`` where a
  sub-IMU has no row at the epoch (a gap); and the OR of the used sub-IMUs' own
  ``RESTARTED_AFTER_GAP`` / ``BRIDGED_GAP`` (``SubImuTrack.flags``).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .. import earth
from ..attitude import cross, dcm_to_rotvec, rotvec_to_dcm, skew
from ..series import NavSeries
from ..units import FloatArray
from . import _wls_kernel
from . import flags as ta_flags

#: the 9 fitted components: flexure angles about x, y, z (rad), deflection, deflection rate (body axes)
COMPONENTS = ("theta_x", "theta_y", "theta_z", "d_x", "d_y", "d_z", "ddot_x", "ddot_y", "ddot_z")


@dataclass(frozen=True)
class SubImuTrack:
    """A sub-IMU's smoothed solution on one wing, the input of the fit.

    t_s (N,); C_nb (N, 3, 3) sub-IMU axes -> ENU; vel_n_mps (N, 3); llh (N, 3); sigma (N, 9):
    1-sigma [attitude (3, rad, ENU), velocity (3, m/s, ENU), position (3, m, ENU)]; span_m and
    lever_arm_m (3,) (master axes) and C_b_s0 (3, 3) (nominal mount, sub-IMU -> master axes) from
    the aircraft configuration."""

    name: str
    span_m: float
    lever_arm_m: FloatArray
    C_b_s0: FloatArray
    t_s: FloatArray
    C_nb: FloatArray
    vel_n_mps: FloatArray
    llh: FloatArray
    sigma: FloatArray
    #: (N,) the rows' quality bits (:mod:`dpos_core.ta.flags`); None: none set.  The fit's rows
    #: carry those of the sub-IMUs used (:data:`~dpos_core.ta.flags.CARRIER_BITS`)
    flags: ta_flags.FlagArray | None = None


@dataclass
class FittedAntenna:
    """An antenna from the fit: ``traj`` at the fit epochs, ``sigma`` (N, 9) as :class:`SubImuTrack`
    and ``flags`` (N,) (:mod:`dpos_core.ta.flags`: ``WING_FIT`` on every row, ``EXTRAPOLATED``,
    ``FEWER_SUB_IMUS`` and the used sub-IMUs' own bits)."""

    name: str
    traj: NavSeries
    sigma: FloatArray
    flags: ta_flags.FlagArray | None = None


@dataclass
class WingFit:
    """The fit of one wing: the epochs ``t_s`` (T,), the chosen degree per component
    (:data:`COMPONENTS` -> k, the basis ``s^1..s^k`` for angles, ``s^2..s^k`` otherwise), the
    cross-validation per component and candidate k (``{"score": mean squared scaled residual,
    "rms": RMS residual in the component's unit}``), the a posteriori variance factors, and the
    antennas."""

    t_s: FloatArray
    degree: dict[str, int]
    cv: dict[str, dict[int, dict[str, float]]]
    variance_factor: dict[str, float]
    #: the basis has the constant (common) term: the main POS's epoch error (:func:`powers`)
    common: bool = False
    #: per sub-IMU: the rigid misalignment (3,) and its 1-sigma (3,) [rad, master axes] the fit used
    rigid_misalignment: dict[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)
    antennas: dict[str, FittedAntenna] = field(default_factory=dict)

    def basis_text(self) -> str:
        """``angles k=(2, 1, 1), deflection k=(2, 3, 2), rate k=(...)`` for status lines."""
        k = [self.degree[c] for c in COMPONENTS]
        c = " with a common term" if self.common else ""
        return (f"polynomial in span{c}, degree: angles {tuple(k[0:3])}, deflection {tuple(k[3:6])}, "
                f"deflection rate {tuple(k[6:9])}")


def powers(component: str, degree: int, common: bool = False) -> list[int]:
    """The exponents of the basis of ``component`` at ``degree``: clamped root, so angles start at
    s^1 and deflections (and rates) at s^2; empty for degree 0 (or 1 for a deflection).  With
    ``common``, the constant ``s^0`` first: no deformation (a clamped wing has none at the root) but
    the main POS's own error at the epoch, which every sub-IMU sees alike (:func:`fit_wing`)."""
    lo = 1 if component.startswith("theta") else 2
    return ([0] if common else []) + list(range(lo, degree + 1))


def candidates(component: str, max_degree: int) -> list[int]:
    """The candidate degrees: 0 (no deformation) and each degree that adds a term."""
    lo = 1 if component.startswith("theta") else 2
    return [0] + list(range(lo, max_degree + 1))


def design(s: FloatArray, pw: list[int]) -> FloatArray:
    """(S, p) basis matrix ``s^j`` for the exponents ``pw``."""
    s = np.asarray(s, dtype=float)
    return s[:, None] ** np.asarray(pw, dtype=float)[None, :] if pw else np.zeros((s.size, 0))


def wls(B: FloatArray, y: FloatArray, var: FloatArray, cov: bool = True) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Weighted least squares per epoch: ``B`` (S, p), ``y`` (T, S), ``var`` (T, S) (``inf`` or
    NaN: the point is missing).  Returns the coefficients (T, p), their covariance (T, p, p)
    (unscaled: ``(B^T W B)^-1``; NaN everywhere without ``cov``) and a mask (T,) of the epochs
    with enough points (rank p); invalid epochs have NaN."""
    T, p = y.shape[0], B.shape[1]
    w = np.where(np.isfinite(var) & np.isfinite(y), 1.0 / np.where(np.isfinite(var), var, 1.0), 0.0)
    yz = np.where(w > 0, y, 0.0)
    n_pts = np.sum(w > 0, axis=1)
    if p == 0:
        return np.zeros((T, 0)), np.zeros((T, 0, 0)), n_pts >= 1
    ok = n_pts >= p
    # the normal equations, Cholesky, (B^T W B)^-1 and the coefficients per epoch (numba kernel)
    a = np.full((T, p), np.nan)
    P = np.full((T, p, p), np.nan)
    bound = np.full(T, np.inf)
    _wls_kernel.normal_solve(np.ascontiguousarray(B, dtype=float), w, yz, ok, a, P, bound, cov)
    # rank p: the smallest eigenvalue of B^T W B above 1e-12 of the largest; trace(N) trace(N^-1)
    # bounds their ratio, so only epochs whose bound exceeds 1e12 need their eigenvalues
    check = ok & ~(bound < 1e12)
    if check.any():
        Nc = np.einsum("si,ts,sj->tij", B, w[check], B)
        ev = np.linalg.eigvalsh(Nc)  # symmetric: eigenvalues, not an SVD per epoch
        good = ev[:, 0] > 1e-12 * ev[:, -1]
        idx = np.flatnonzero(check)
        ok[idx[~good]] = False
        redo = idx[good & ~np.isfinite(bound[idx])]  # full rank, but the kernel's factorization failed to rounding
        if redo.size:
            L = np.linalg.cholesky(Nc[good & ~np.isfinite(bound[idx])])
            Linv = np.linalg.solve(L, np.broadcast_to(np.eye(p), L.shape))
            P[redo] = np.swapaxes(Linv, 1, 2) @ Linv
            a[redo] = np.einsum("tij,tj->ti", P[redo], np.einsum("si,ts->ti", B, w[redo] * yz[redo]))
    a[~ok] = np.nan
    P[~ok] = np.nan
    return a, P, ok


def _times_t(a: FloatArray, M: FloatArray) -> FloatArray:
    """``a @ M.T`` for ``a`` (T, p) and a small ``M`` (A, p) by einsum: no BLAS call, whose threads
    only contend on these shapes (2x faster than the matmul on the 2-core machine)."""
    return np.einsum("tp,ap->ta", a, M)


def cross_validate(s: FloatArray, y: FloatArray, var: FloatArray, pw: list[int]) -> tuple[float, float]:
    """Leave-one-out over the S points, every epoch: ``(mean of r^2 / var_i, RMS of r)`` with
    ``r`` the left-out point's residual and ``var_i`` its variance (the weighted mean squared
    prediction error: for a basis that holds the field it is ``1 + var_pred / var_i``, so a
    basis with more terms than the field needs pays for its larger prediction variance);
    ``s`` (S,), ``y``/``var`` (T, S)."""
    S, T = s.size, y.shape[0]
    B = design(s, pw)
    # every leave-one-out fit in one call: block i of the stacked epochs leaves point i out
    v = np.tile(var, (S, 1))
    for i in range(S):
        v[i * T:(i + 1) * T, i] = np.inf
    a_all, _, ok_all = wls(B, np.tile(y, (S, 1)), v, cov=False)
    num, sq, n = 0.0, 0.0, 0
    for i in range(S):
        a, ok = a_all[i * T:(i + 1) * T], ok_all[i * T:(i + 1) * T]
        ok &= np.isfinite(var[:, i]) & np.isfinite(y[:, i])
        b = design(s[i : i + 1], pw)[0]
        pred = a[ok] @ b
        r = y[ok, i] - pred
        num += float(np.sum(r * r / var[ok, i]))
        sq += float(np.sum(r * r))
        n += int(ok.sum())
    return (num / n, float(np.sqrt(sq / n))) if n else (float("inf"), float("nan"))


#: threads of :func:`fit_wing` over its components (independent): it runs after
#: the last sub-IMU's transfer alignment, when the cores the workers used are free
FIT_THREADS = min(4, os.cpu_count() or 1)

#: the cross-validation scores at most this many epochs (evenly spaced; 3000 = 10 Hz over 300 s):
#: the score is a session mean, and the 200 Hz rows of a session are far from independent
CV_MAX_EPOCHS = 3000


def choose_degree(component: str, s: FloatArray, y: FloatArray, var: FloatArray,
                  max_degree: int = 4, common: bool = False) -> tuple[int, dict[int, dict[str, float]]]:
    """The degree of ``component`` with the smallest leave-one-out score (:func:`cross_validate`)
    among :func:`candidates` that leave at least one redundant point (p <= S - 2); returns it and
    every candidate's ``{"score", "rms"}``."""
    cv: dict[int, dict[str, float]] = {}
    if y.shape[0] > CV_MAX_EPOCHS:  # one choice per session: a regular subset of the epochs scores it as well
        step = int(np.ceil(y.shape[0] / CV_MAX_EPOCHS))
        y, var = y[::step], var[::step]
    for k in candidates(component, max_degree):
        pw = powers(component, k, common)
        if len(pw) > s.size - 2:
            continue
        score, rms = cross_validate(s, y, var, pw)
        cv[k] = {"score": score, "rms": rms}
    best = min(cv, key=lambda k: (cv[k]["score"], k))
    return best, cv


def _on_grid(tr: SubImuTrack, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """The track at the epochs ``t`` (T,): C_nb (T, 3, 3) (geodesic interpolation), vel, llh,
    sigma (linear) and a mask (T,) of epochs bracketed by rows at most 3 nominal
    steps apart (or matching a row)."""
    ts = tr.t_s
    i0 = int(np.searchsorted(ts, t[0])) if t.size else 0
    if t.size and i0 + t.size <= ts.size and np.array_equal(ts[i0:i0 + t.size], t):
        # the epochs are the track's own rows (the interpolation below would return them exactly)
        rows = slice(i0, i0 + t.size)
        return tr.C_nb[rows], tr.vel_n_mps[rows], tr.llh[rows], tr.sigma[rows], np.ones(t.size, dtype=bool)
    dt = float(np.median(np.diff(ts))) if ts.size > 1 else 1.0
    j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, max(ts.size - 2, 0))
    k = np.minimum(j + 1, ts.size - 1)
    span = ts[k] - ts[j]
    f = np.clip(np.where(span > 0, (t - ts[j]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
    exact = (np.abs(ts[j] - t) < 1e-6) | (np.abs(ts[k] - t) < 1e-6)
    ok = exact | ((ts[j] <= t) & (t <= ts[k]) & (span <= 3.0 * dt + 1e-9))

    def lin(x: FloatArray) -> FloatArray:
        return x[j] + f[:, None] * (x[k] - x[j])

    dC = dcm_to_rotvec(np.swapaxes(tr.C_nb[j], 1, 2) @ tr.C_nb[k])
    C = tr.C_nb[j] @ rotvec_to_dcm(f[:, None] * dC)
    return C, lin(tr.vel_n_mps), lin(tr.llh), lin(tr.sigma), ok


def _flags_on_grid(tr: SubImuTrack, t: FloatArray) -> ta_flags.FlagArray:
    """The track's own flags (:data:`~dpos_core.ta.flags.CARRIER_BITS`) at the epochs ``t`` (T,): the
    row's at a row's stamp, the OR of the two bracketing rows' between them (as :func:`_on_grid`)."""
    ts = tr.t_s
    if tr.flags is None or ts.size == 0:
        return ta_flags.none(t.size)
    fl = np.asarray(tr.flags, dtype=np.uint32) & np.uint32(ta_flags.CARRIER_BITS)
    j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 1)
    k = np.minimum(j + 1, ts.size - 1)
    at_j, at_k = np.abs(ts[j] - t) < 1e-6, np.abs(ts[k] - t) < 1e-6
    return np.where(at_j, fl[j], np.where(at_k, fl[k], fl[j] | fl[k])).astype(np.uint32)


def _master_at(m: NavSeries, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Main POS at ``t`` (T,): C_nb, vel, llh, omega_eb_b (finite differences of the attitude when
    the series has none), att_cov, vel_cov, pos_cov (zeros when absent), interpolated."""
    ts = m.t_s
    j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    k = j + 1
    f = np.clip((t - ts[j]) / (ts[k] - ts[j]), 0.0, 1.0)
    Cm = m.C_nb
    dC = dcm_to_rotvec(np.swapaxes(Cm[j], 1, 2) @ Cm[k])
    C = Cm[j] @ rotvec_to_dcm(f[:, None] * dC)

    def lin(x: FloatArray | None, shape: tuple[int, ...]) -> FloatArray:
        if x is None:
            return np.zeros((t.size, *shape))
        fx = f.reshape((-1,) + (1,) * len(shape))
        return x[j] + fx * (x[k] - x[j])

    if m.omega_eb_b_radps is not None:
        w = lin(m.omega_eb_b_radps, (3,))
    else:  # body rate over the Earth from the attitude's change (the Earth and transport rates neglected: < 1e-4 rad/s)
        w = dC / (ts[k] - ts[j])[:, None]
    return C, lin(m.vel_n_mps, (3,)), lin(m.llh, (3,)), w, lin(m.att_cov, (3, 3)), lin(m.vel_cov, (3, 3)), lin(m.pos_cov, (3, 3))


def _enu_from(llh: FloatArray, llh_ref: FloatArray) -> FloatArray:
    """(T, 3) vectors from ``llh_ref`` to ``llh`` (each (T, 3)) in the local ENU frame at ``llh_ref``, exactly."""
    d_e = earth.geodetic_to_ecef(*llh.T) - earth.geodetic_to_ecef(*llh_ref.T)
    return np.einsum("tji,tj->ti", earth.C_en(llh_ref[:, 0], llh_ref[:, 1]), d_e)


def _body_var(C_nb: FloatArray, sig_n: FloatArray) -> FloatArray:
    """Diagonal (T, 3) of ``C_nb^T diag(sig_n^2) C_nb``: ENU 1-sigma (T, 3) to body-axis variances."""
    return np.einsum("tij,ti->tj", C_nb**2, sig_n**2)


#: the load-factor regressor is used when std(n - 1) over the session exceeds this (0.01 g: a 8 deg bank)
MIN_LOAD_STD = 0.01
#: batches for the variance of the session mean of the flexure (batch means)
N_BATCHES = 10


#: half width [s] of the central difference of the main POS velocity for the load factor
LOAD_DIFF_HALF_S = 0.5


def load_factor_minus_1(master_vel_n_mps: FloatArray, C_nb: FloatArray, t_s: FloatArray, llh: FloatArray) -> FloatArray:
    """``n - 1`` (T,) of the main POS: the body-up component of ``f^n = dv^n/dt + [0, 0, g]`` (ENU)
    over the normal gravity, ``dv/dt`` by central differences of the velocity over
    +-``LOAD_DIFF_HALF_S`` around the epochs ``t_s`` (T,) (one-sided at the ends); Coriolis and
    transport terms (~1e-3 g) are left out, as in the simulator's load.  Not sample to sample: the
    main POS's white velocity noise (5 mm/s on paper_wing) differentiated over 5 ms reads as
    0.014 g of load in steady flight, above ``MIN_LOAD_STD``; over 1 s it is 7e-4 g, while a turn
    entry (seconds) keeps its shape."""
    if t_s.size < 3:
        return np.zeros(t_s.size)
    lo = np.clip(t_s - LOAD_DIFF_HALF_S, t_s[0], t_s[-1])
    hi = np.clip(t_s + LOAD_DIFF_HALF_S, t_s[0], t_s[-1])
    span = np.maximum(hi - lo, 1e-9)[:, None]
    a = np.stack([np.interp(hi, t_s, master_vel_n_mps[:, i]) - np.interp(lo, t_s, master_vel_n_mps[:, i]) for i in range(3)], -1) / span
    g = earth.normal_gravity(llh[:, 0], llh[:, 2])
    a[:, 2] += g
    return np.einsum("ti,ti->t", C_nb[:, :, 2], a) / g - 1.0


def rigid_misalignment(Theta: FloatArray, n1: FloatArray, ok: NDArray[np.bool_]) -> tuple[FloatArray, FloatArray]:
    """The rigid misalignment of a sub-IMU from its total rotation (module docstring).

    Args:
        Theta: (T, 3) total rotation master -> sub-IMU section [rad], master axes.
        n1: (T,) load factor minus 1.
        ok: (T,) epochs with data.

    Returns:
        ``rho_b`` (3,) [rad, master axes] and its variance (3,) [rad^2] (batch means of the
        regression residuals; ``inf`` with fewer than ``2 N_BATCHES`` epochs).
    """
    y, x = Theta[ok], n1[ok]
    if y.shape[0] == 0:
        return np.zeros(3), np.full(3, np.inf)
    X = np.ones((x.size, 1))
    if x.size > 2 and float(np.std(x)) > MIN_LOAD_STD:
        X = np.column_stack([X, x - x.mean()])  # centred: the intercept is the mean at the session's mean load
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    rho = coef[0]
    if X.shape[1] == 2:
        rho = rho - coef[1] * x.mean()  # back to n = 1
    res = y - X @ coef
    if x.size < 2 * N_BATCHES:
        return rho, np.full(3, np.inf)
    means = np.array([b.mean(axis=0) for b in np.array_split(res, N_BATCHES)])
    var = np.sum(means**2, axis=0) / ((N_BATCHES - 1) * N_BATCHES)  # variance of the mean of the batch means
    return rho, np.maximum(var, 1e-16)


def _along_span(ss: FloatArray, v: FloatArray, sq: float) -> FloatArray:
    """``v`` (T, S, m) given at the sorted spans ``ss`` (S,), linearly interpolated at ``sq``
    (held at the end values outside), ignoring NaN points per epoch; (T, m), NaN where none."""
    T, S, m = v.shape
    out = np.full((T, m), np.nan)
    for j in range(m):
        vj = v[:, :, j]
        fin = np.isfinite(vj)
        if fin.all():
            out[:, j] = _interp_rows(ss, vj, sq)
        else:
            out[:, j] = [np.interp(sq, ss[f], row[f]) if f.any() else np.nan for row, f in zip(vj, fin)]
    return out


def _interp_rows(ss: FloatArray, v: FloatArray, sq: float, extrapolate: bool = False) -> FloatArray:
    """Vectorised ``np.interp(sq, ss, v[t])`` over the rows of ``v`` (T, S) (no NaN); with
    ``extrapolate`` the end segments continue beyond ``ss`` instead of holding the end values."""
    if not extrapolate and sq <= ss[0]:
        return v[:, 0]
    if not extrapolate and sq >= ss[-1]:
        return v[:, -1]
    j = int(np.clip(np.searchsorted(ss, sq) - 1, 0, ss.size - 2))
    f = (sq - ss[j]) / (ss[j + 1] - ss[j])
    return v[:, j] + f * (v[:, j + 1] - v[:, j])


def fit_wing(master: NavSeries, subs: list[SubImuTrack], antennas: list[tuple[str, float, FloatArray]],
             max_degree: int = 4, root_span_m: float = 0.0) -> WingFit:
    """Fit the deformation of one wing along the span (module docstring) and derive its antennas.

    Args:
        master: the main POS navigation (with ``att_cov``/``vel_cov``/``pos_cov`` when known;
            ``omega_eb_b_radps`` used for the lever-arm velocity when present).
        subs: the wing's sub-IMU solutions (at least 2).  The fit epochs are those of ``subs[0]``
            within the span covered by every sub-IMU and the main POS; at an epoch where a
            sub-IMU has no row (a gap) it is left out, and an epoch with fewer sub-IMUs than a
            basis needs has no row.
        antennas: ``(name, span_m, lever_arm_m (3,) from the master IMU, master axes)``.
        max_degree: highest candidate degree (4: up to 3-4 coefficients from 6 sub-IMUs).
        root_span_m: where the cantilever is clamped (|span| measured from the main POS).

    Returns:
        :class:`WingFit`; antennas' ``sigma`` (T, 9) as :class:`SubImuTrack`, their ``flags`` (T,)
        (module docstring).
    """
    if len(subs) < 2:
        raise ValueError(f"the wing fit needs at least 2 sub-IMUs, got {len(subs)}")
    t = subs[0].t_s
    lo = max(max(x.t_s[0] for x in subs), master.t_s[0])
    hi = min(min(x.t_s[-1] for x in subs), master.t_s[-1])
    t = t[(t >= lo - 1e-9) & (t <= hi + 1e-9)]
    C, vm, pm, w, Patt, Pvel, Ppos = _master_at(master, t)
    Cbn = np.swapaxes(C, 1, 2)
    S, T = len(subs), t.size
    s = np.array([abs(x.span_m) - root_span_m for x in subs])
    y = np.full((T, S, 9), np.nan)
    var = np.full((T, S, 9), np.inf)
    rho_by_sub: dict[str, tuple[FloatArray, FloatArray]] = {}
    sub_sigma = np.full((T, S, 9), np.nan)  # the sub-IMUs' own 1-sigma on the fit epochs
    used = np.zeros((T, S), dtype=bool)  # the sub-IMUs with a row at each epoch (the flags)
    sub_flags = np.zeros((T, S), dtype=np.uint32)
    n1 = load_factor_minus_1(vm, C, t, pm)
    for i, tr in enumerate(subs):
        Cs, vs, ps, sg, ok = _on_grid(tr, t)
        sub_sigma[:, i] = np.where(ok[:, None], sg, np.nan)
        used[:, i], sub_flags[:, i] = ok, np.where(ok, _flags_on_grid(tr, t), 0)
        r0 = np.asarray(tr.lever_arm_m, dtype=float)
        M = np.asarray(tr.C_b_s0, dtype=float)
        R_tot = Cbn @ Cs @ M.T  # rigid misalignment and flexure of the section, master axes
        rho_b, rho_var = rigid_misalignment(dcm_to_rotvec(R_tot), n1, ok)
        th = dcm_to_rotvec(R_tot @ rotvec_to_dcm(-rho_b)[None])
        d = np.einsum("tji,tj->ti", C, _enu_from(ps, pm)) - r0
        dd = np.einsum("tji,tj->ti", C, vs - vm) - cross(w, r0 + d)
        v_th = _body_var(C, sg[:, 0:3])
        rho_by_sub[tr.name] = (rho_b, np.sqrt(rho_var))
        y[:, i] = np.where(ok[:, None], np.concatenate([th, d, dd], axis=1), np.nan)
        var[:, i] = np.where(ok[:, None], np.concatenate([v_th, _body_var(C, sg[:, 6:9]), _body_var(C, sg[:, 3:6])], axis=1), np.inf)
    # with 4 or more sub-IMUs every component also gets a constant (common) term: the main POS's error at
    # the epoch (paper_wing's reference: 5 cm, 0.005 m/s, 0.002-0.005 deg white) enters every sub-IMU's
    # deflection, rate and angle alike, and the sub-IMUs' smoothed solutions, which average it out,
    # estimate it; the antennas then carry the fit's error instead of the raw main POS's.
    common = S >= 4
    degree: dict[str, int] = {}
    cvs: dict[str, dict[int, dict[str, float]]] = {}
    s0: dict[str, float] = {}
    sa = np.array([abs(sp) - root_span_m for _, sp, _ in antennas])
    val = np.zeros((T, len(antennas), 9))
    pvar = np.zeros((T, len(antennas), 9))
    valid = np.ones(T, dtype=bool)
    def fit_component(c: int) -> tuple[int, dict[int, dict[str, float]], float, NDArray[np.bool_]]:
        """Component ``c``: its degree by cross-validation, the WLS per epoch, its variance
        factor; its values and variances at the antennas into ``val`` / ``pvar`` (column c)."""
        comp = COMPONENTS[c]
        k, cv = choose_degree(comp, s, y[:, :, c], var[:, :, c], max_degree, common)
        pw = powers(comp, k, common)
        B = design(s, pw)
        a, P, ok = wls(B, y[:, :, c], var[:, :, c])
        fin = np.isfinite(var[:, :, c]) & ok[:, None]
        a0 = np.nan_to_num(a)
        res = y[:, :, c] - np.where(ok[:, None], _times_t(a0, B), 0.0)
        chi2 = float(np.sum(np.where(fin, res**2 / np.where(fin, var[:, :, c], 1.0), 0.0)))
        dof = float(np.sum(fin) - len(pw) * np.sum(ok))
        f = max(1.0, chi2 / dof) if dof > 0 else 1.0
        Ba = design(sa, pw)
        val[:, :, c] = _times_t(a0, Ba)
        # b_a^T P b_a = sum_ij P_ij b_ai b_aj: one product (T, p^2) x (p^2, A)
        pvar[:, :, c] = f * _times_t(np.nan_to_num(P).reshape(T, -1), (Ba[:, :, None] * Ba[:, None, :]).reshape(len(antennas), -1))
        return k, cv, f, ok

    # the components are independent: on threads (the WLS kernel and numpy's array loops release the GIL)
    with ThreadPoolExecutor(max_workers=FIT_THREADS) as ex:
        for c, (k, cv, f, ok) in enumerate(ex.map(fit_component, range(len(COMPONENTS)))):
            degree[COMPONENTS[c]], cvs[COMPONENTS[c]], s0[COMPONENTS[c]] = k, cv, f
            valid &= ok
    out = WingFit(t[valid], degree, cvs, s0, common=common, rigid_misalignment=rho_by_sub)
    # the antennas' offset across the wing from the sub-IMUs' section points (x and z interpolated along the span)
    order = np.argsort(s)
    r0s = np.array([np.asarray(x.lever_arm_m, dtype=float) for x in subs])[order]
    tv = t[valid]
    rho_sd = np.array([rho_by_sub[x.name][1] for x in subs])[order]  # (S, 3) by span

    def rho_var_at(sq: float) -> FloatArray:
        """Variance (3,) of the rigid-misalignment split at span ``sq``: the sub-IMUs' (the error of
        the session mean of the flexure, smooth along the span: not a point noise of the fit but
        common to the whole field) linearly interpolated, extrapolated by the outermost segment."""
        if s.size == 1 or not np.all(np.isfinite(rho_sd)):
            return np.max(rho_sd, axis=0) ** 2
        return np.maximum(_interp_rows(s[order], rho_sd.T, sq, extrapolate=True), 0.0) ** 2

    sel = slice(None) if valid.all() else valid  # views, not copies, when every epoch is valid
    Cv = C[sel]
    Cv2 = Cv**2  # C_nb diag(v) C_bn has the diagonal C_nb**2 v
    val_v, pvar_v, w_v, vm_v, pm_v, Patt_v = val[sel], pvar[sel], w[sel], vm[sel], pm[sel], Patt[sel]
    d_att, d_vel, d_pos = (np.diagonal(X[sel], axis1=1, axis2=2) for X in (Patt, Pvel, Ppos))
    floor_sig = sub_sigma[sel][:, order, 3:9]
    # the rows' flags (dpos_core.ta.flags): the used sub-IMUs' own bits, fewer sub-IMUs than given, and
    # (per antenna, below) an antenna outside the spans of the sub-IMUs used at the epoch
    uv = used[valid]
    row_flags = np.bitwise_or.reduce(sub_flags[valid], axis=1) | np.uint32(ta_flags.WING_FIT)
    row_flags |= np.where(uv.sum(axis=1) < S, np.uint32(ta_flags.FEWER_SUB_IMUS), np.uint32(0))
    s_in = np.min(np.where(uv, s[None, :], np.inf), axis=1)
    s_out = np.max(np.where(uv, s[None, :], -np.inf), axis=1)
    dt = np.gradient(tv) if tv.size > 1 else np.ones(1)
    for n, (name, _, ra) in enumerate(antennas):
        ra = np.asarray(ra, dtype=float)
        o = ra - np.array([np.interp(sa[n], s[order], r0s[:, 0]), ra[1], np.interp(sa[n], s[order], r0s[:, 2])])
        th = val_v[:, n, 0:3]
        R = rotvec_to_dcm(th)
        d = val_v[:, n, 3:6] + R @ o - o
        r = ra + d
        th_dot = np.gradient(th, axis=0) / dt[:, None] if tv.size > 1 else np.zeros_like(th)
        rel_v = cross(w_v, r) + val_v[:, n, 6:9] + cross(th_dot, o)
        vel = vm_v + np.einsum("tij,tj->ti", Cv, rel_v)
        r_n = np.einsum("tij,tj->ti", Cv, r)
        llh = earth.offset_llh(pm_v, r_n)
        C_na = Cv @ R

        def to_n(v_b: FloatArray) -> FloatArray:
            return np.einsum("tij,tj->ti", Cv2, v_b)  # the diagonal of C_nb diag(v) C_bn: (T, 3)

        Sk = skew(r_n)
        # the main POS's covariance: replaced by the common term's (in pvar) when it is fitted; its
        # attitude error turning the lever arm is linear in the span, which the basis does not hold
        # (only the diagonals of the ENU covariances are needed: the 1-sigma)
        keep_m = 0.0 if common else 1.0
        var_att = to_n(pvar_v[:, n, 0:3] + rho_var_at(sa[n])) + keep_m * d_att
        var_pos = to_n(pvar_v[:, n, 3:6]) + keep_m * d_pos + np.sum((Sk @ Patt_v) * Sk, axis=2)  # diag(Sk P_att Sk^T)
        var_vel = to_n(pvar_v[:, n, 6:9]) + keep_m * d_vel
        sigma = np.sqrt(np.concatenate([var_att, var_vel, var_pos], axis=1))
        # velocity and position: never below the sub-IMUs' own sigma at this span (interpolated; the
        # outermost beyond the last).  Their errors share the main POS reference of the transfer
        # alignment, so the fit through them averages nothing of it, although its weights (independent
        # points) say so: on paper_wing 120 s the fit antennas' position sigma was sqrt(6) below their
        # neighbours' for the same error (63-78 % within 2 sigma at ant02 / ant04).  The attitude is
        # exempt: a sub-IMU's own heading error is in its rigid misalignment and cancels in the fit
        floor = _along_span(s[order], floor_sig, sa[n])
        sigma[:, 3:9] = np.fmax(sigma[:, 3:9], floor)
        outside = (sa[n] < s_in - 1e-9) | (sa[n] > s_out + 1e-9)
        fl = (row_flags | np.where(outside, np.uint32(ta_flags.EXTRAPOLATED), np.uint32(0))).astype(np.uint32)
        out.antennas[name] = FittedAntenna(name, NavSeries.from_C_nb(tv, C_na, vel, llh), sigma, fl)
    return out
