"""Square-root second-order divided-difference filter (DD2), its innovation-adaptive variant
(ADD2) and the innovation-adaptive EKF (AEKF) of the in-flight alignment ([Fang2012]).

DD2 (Norgaard, Poulsen, Ravn 2000; [Fang2012] eq. 2-14), additive noise, ``h = sqrt(3)``.
With the columns ``s_j`` of the lower-triangular factor ``S`` (``P = S S^T``) and
``f_j^+- = f(x +- h s_j)``, ``f_0 = f(x)``:

* time update (eq. 3-5)::

      x_pred = (h^2 - n)/h^2 f_0 + 1/(2 h^2) sum_j (f_j^+ + f_j^-)
      S_x1[:, j] = (f_j^+ - f_j^-) / (2 h)
      S_x2[:, j] = sqrt(h^2 - 1) / (2 h^2) (f_j^+ + f_j^- - 2 f_0)
      S_pred = tria([S_x1, S_Q, S_x2])

  With additive process noise ``w ~ N(0, S_Q S_Q^T)`` the noise columns of eq. 4 reduce to
  ``S_xw1 = S_Q`` and ``S_xw2 = 0`` (``f`` is linear in ``w``), and ``n_w`` drops out of the
  mean weights.  Eq. 5 of the paper prints ``f(+) + f(-)`` in ``S_x1``; Norgaard's first-order
  term is the difference ``f(+) - f(-)`` (used here, and the only choice that reproduces the
  Kalman filter on a linear model).

* measurement update (eq. 6-14), ``y_j^+- = h(x +- h s_j)``::

      y_pred = (h^2 - n)/h^2 y_0 + 1/(2 h^2) sum_j (y_j^+ + y_j^-)
      S_y1[:, j] = (y_j^+ - y_j^-) / (2 h),  S_y2[:, j] = sqrt(h^2 - 1)/(2 h^2) (y_j^+ + y_j^- - 2 y_0)
      S_y = tria([S_y1, S_R, S_y2]),  P_xy = S S_y1^T,  K = P_xy (S_y S_y^T)^-1
      x+ = x + K (y - y_pred),  S+ = tria([S - K S_y1, K S_R, K S_y2])

  ``tria`` is :func:`~.linalg.householder_tria`.  On a linear-Gaussian model every second-order
  column vanishes and DD2 is the Kalman filter (``S+`` is the Joseph form).

ADD2 ([Fang2012] eq. 18-23).  The innovation ``z_k = y_k - y_pred`` enters a moving window of the
last ``N`` innovations and ``D_k = 1/N sum z_i z_i^T`` (eq. 22) replaces ``S_y S_y^T`` in the gain
(eq. 23).  Taken literally this is ill-defined: for ``k < N`` (or ``N < p``) ``D_k`` is singular,
and a window of 10 small innovations can fall below the part of the innovation covariance that
the state uncertainty alone explains, which over-weights the measurement and collapses ``P``.
:func:`guard_innovation_cov` therefore splits ``D_k`` as the filter's own
``P_yx = S_y1 S_y1^T + S_y2 S_y2^T`` plus an implied measurement-noise covariance
``R_hat = D_k - P_yx``, whitens ``R_hat`` by the nominal ``R`` and floors its eigenvalues at
``r_floor`` (a fraction of the nominal ``R``; 1e-2 by default), so the gain covariance is

    P_gain = P_yx + R_eff,   R_eff = L_R  max(L_R^-1 R_hat L_R^-T, r_floor)  L_R^T  >= r_floor R > 0,

never below ``P_yx`` and always positive definite; until ``N`` innovations have been seen the
nominal ``S_y S_y^T`` is used.  The posterior factor is the Joseph form of eq. 14 with ``R_eff``
in place of ``R`` (``S+ = tria([S - K S_y1, K chol(R_eff), K S_y2])``), the covariance of the
estimate for that gain if ``R_eff`` is the true noise covariance.

Options of the adaptation (both ADD2 and AEKF): ``diagonal`` adapts only the variances (a
10-sample window's cross-correlations are mostly sampling noise); ``debias`` estimates the noise
as ``1/N sum (z_i z_i^T - P_yx,i)`` with each innovation's own state part
(:meth:`InnovationWindow.noise_cov`) instead of ``D_k - P_yx,k``; ``r_ceiling`` caps ``R_eff``
at ``r_ceiling R`` so that state errors the filter does not know about cannot inflate R without
bound (which would freeze the gain).

AEKF (Mohamed & Schwarz 1999, innovation-based adaptive estimation; [Fang2012]'s baseline): the
EKF whose measurement noise is ``R_hat = C_v - H P^- H^T`` from the same windowed innovation
covariance ``C_v``, guarded the same way.  Jacobians are central differences of ``f`` and
``h`` at the current estimate (:mod:`.jacobian`, step ``1e-6`` relative to the state's sigma).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_solve, solve_triangular

from dpos_core.errors import NumericalFailure
from dpos_core.units import FloatArray

from .jacobian import central_difference_jacobian, steps_from_cov
from .linalg import chol, gain, householder_tria, symmetrize
from .points import CENTRAL_DIFFERENCE_STEP, symmetric_points

Fn = Callable[[FloatArray], FloatArray]
Residual = Callable[[FloatArray, FloatArray], FloatArray]
H_STEP = CENTRAL_DIFFERENCE_STEP


class DD2Prediction(NamedTuple):
    """``x_pred`` (..., n), lower factor ``S_pred`` (..., n, n) and ``C = Cov(x_k, x_{k+1})`` (..., n, n)."""

    x: FloatArray
    S: FloatArray
    C: FloatArray


class DD2Update(NamedTuple):
    """Posterior ``x`` (..., n) and factor ``S`` (..., n, n); innovation ``nu`` (..., p); factor
    ``S_y`` (..., p, p) of the innovation covariance the gain used; gain ``K`` (..., n, p)."""

    x: FloatArray
    S: FloatArray
    nu: FloatArray
    S_y: FloatArray
    K: FloatArray


class DD2Factors(NamedTuple):
    """Predicted measurement ``y_pred`` (..., p) and the divided-difference matrices
    ``S_y1``, ``S_y2`` (..., p, n) of eq. 11."""

    y: FloatArray
    S1: FloatArray
    S2: FloatArray


def divided_differences(x: FloatArray, S: FloatArray, fn: Fn, h: float = H_STEP,
                        residual: Residual | None = None) -> DD2Factors:
    """Mean and the first/second-order divided-difference matrices of ``fn`` (eq. 3, 5, 7, 11).

    Args:
        x: mean (..., n); S: lower factor (..., n, n); fn: (..., m, n) -> (..., m, p).
        residual: difference ``a - b`` of two outputs (default subtraction).
    Returns:
        ``(mean (..., p), S1 (..., p, n), S2 (..., p, n))``.
    """
    n = x.shape[-1]
    Y = fn(symmetric_points(x, S, h))
    y0, yp, ym = Y[..., 0, :], Y[..., 1:n + 1, :], Y[..., n + 1:, :]
    h2 = h * h
    res = residual or (lambda a, b: a - b)
    # the mean as a correction of y0 (residuals keep angle-like outputs continuous)
    dp, dm = res(yp, y0[..., None, :]), res(ym, y0[..., None, :])
    mean = y0 + np.sum(dp + dm, axis=-2) / (2.0 * h2)
    S1 = np.swapaxes(res(yp, ym), -1, -2) / (2.0 * h)
    S2 = np.swapaxes(dp + dm, -1, -2) * (np.sqrt(h2 - 1.0) / (2.0 * h2))
    return DD2Factors(mean, S1, S2)


def dd2_predict(x: FloatArray, S: FloatArray, f: Fn, SQ: FloatArray, h: float = H_STEP) -> DD2Prediction:
    """DD2 time update (eq. 3-5) with additive process noise of factor ``SQ`` (..., n, n).

    Returns ``x_pred``, the lower factor ``S_pred = tria([S_x1, SQ, S_x2])`` and the
    cross-covariance ``C = S S_x1^T`` of the smoother (``Cov(x_k, x_{k+1})``)."""
    x = np.asarray(x, dtype=float)
    S = np.asarray(S, dtype=float)
    m, S1, S2 = divided_differences(x, S, f, h)
    SQ = np.broadcast_to(SQ, S1.shape[:-2] + SQ.shape[-2:])
    Sp = householder_tria(np.concatenate([S1, SQ, S2], axis=-1))
    return DD2Prediction(m, Sp, S @ np.swapaxes(S1, -1, -2))


def _posterior(x: FloatArray, S: FloatArray, nu: FloatArray, fac: DD2Factors, SR: FloatArray,
               K: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``x + K nu`` and ``tria([S - K S_y1, K S_R, K S_y2])`` (eq. 6, 14)."""
    xn = x + np.einsum("...ij,...j->...i", K, nu)
    SR = np.broadcast_to(SR, fac.S1.shape[:-2] + SR.shape[-2:])
    A = np.concatenate([S - K @ fac.S1, K @ SR, K @ fac.S2], axis=-1)
    return xn, householder_tria(A)


def dd2_update(x: FloatArray, S: FloatArray, y: FloatArray, h: Fn, SR: FloatArray,
               residual: Residual | None = None, step: float = H_STEP) -> DD2Update:
    """DD2 measurement update (eq. 6-14) with additive noise of factor ``SR`` (..., p, p).

    Args:
        x (..., n), S (..., n, n) lower factor; y (..., p); h: (..., m, n) -> (..., m, p).
        residual: measurement difference ``a - b`` (default subtraction).
    Returns:
        :class:`DD2Update` ``(x, S, nu, S_y, K)``.
    """
    x = np.asarray(x, dtype=float)
    S = np.asarray(S, dtype=float)
    res = residual or (lambda a, b: a - b)
    fac = divided_differences(x, S, h, step, residual)
    SRb = np.broadcast_to(SR, fac.S1.shape[:-2] + np.shape(SR)[-2:])
    Sy = householder_tria(np.concatenate([fac.S1, SRb, fac.S2], axis=-1))
    Pxy = S @ np.swapaxes(fac.S1, -1, -2)
    K = _gain_from_factor(Pxy, Sy)
    nu = res(np.asarray(y, dtype=float), fac.y)
    xn, Sn = _posterior(x, S, nu, fac, SR, K)
    return DD2Update(xn, Sn, nu, Sy, K)


def _gain_from_factor(Pxy: FloatArray, Sy: FloatArray) -> FloatArray:
    """``Pxy (Sy Sy^T)^-1`` by two triangular solves (..., n, p)."""
    if Sy.ndim == 2:
        Pyx = Pxy.T
        return cho_solve((Sy, True), Pyx, check_finite=False).T
    a = np.linalg.solve(Sy, np.swapaxes(Pxy, -1, -2))
    return np.swapaxes(np.linalg.solve(np.swapaxes(Sy, -1, -2), a), -1, -2)


# ------------------------------------------------------------------------------ adaptation


class InnovationWindow:
    """Moving window of the last ``N`` innovations ([Fang2012] eq. 15-16, 22).

    ``cov()`` is ``1/n sum_{i in window} z_i z_i^T`` (n = number held, at most ``N``), i.e. the
    moving average of the outer products (eq. 22, innovations assumed zero-mean); with
    ``centered=True`` the window mean is removed first (the biased sample covariance).
    Innovations may carry leading batch axes (..., p).
    """

    def __init__(self, N: int = 10, centered: bool = False) -> None:
        if int(N) < 1:
            raise ValueError(f"window size must be >= 1, got {N}")
        self.N = int(N)
        self.centered = bool(centered)
        self._buf: list[FloatArray] = []
        self._pst: list[FloatArray | None] = []

    def __len__(self) -> int:
        return len(self._buf)

    @property
    def full(self) -> bool:
        return len(self._buf) >= self.N

    def push(self, nu: FloatArray, P_state: FloatArray | None = None) -> None:
        """Add an innovation (..., p) and, optionally, the part ``H P H^T`` (..., p, p) of its
        covariance that the state uncertainty explains (for :meth:`noise_cov`).  A non-finite
        innovation (the measurements are checked before, so the prediction diverged) raises
        :class:`~dpos_core.errors.NumericalFailure`."""
        nu = np.asarray(nu, dtype=float)
        if not np.all(np.isfinite(nu)):
            raise NumericalFailure("innovation is not finite (the prediction diverged)", what="innovation window")
        self._buf.append(nu.copy())
        self._pst.append(None if P_state is None else np.asarray(P_state, dtype=float).copy())
        if len(self._buf) > self.N:
            self._buf.pop(0)
            self._pst.pop(0)

    def values(self) -> FloatArray:
        """The innovations held, oldest first, (n, ..., p)."""
        return np.stack(self._buf)

    def cov(self) -> FloatArray:
        """Windowed innovation covariance (..., p, p)."""
        if not self._buf:
            raise ValueError("empty innovation window")
        Z = self.values()
        if self.centered:
            Z = Z - Z.mean(axis=0)
        return symmetrize(np.einsum("k...i,k...j->...ij", Z, Z) / Z.shape[0])

    def noise_cov(self) -> FloatArray:
        """Debiased measurement-noise estimate ``1/n sum_i (z_i z_i^T - H P_i H^T)`` (..., p, p):
        each innovation's outer product minus the state part of *its own* predicted covariance
        (pushed with it).  Equals ``cov() - H P H^T`` when that part is constant over the window;
        unlike it, an innovation that was large because the state was uncertain then (the first
        turn of a 180 deg heading error) is not mistaken for measurement noise later."""
        pst = [p for p in self._pst if p is not None]
        if not self._buf or len(pst) != len(self._pst):
            raise ValueError("noise_cov needs every innovation pushed with its P_state")
        Z = self.values()
        return symmetrize((np.einsum("k...i,k...j->...ij", Z, Z) - np.sum(pst, axis=0)) / Z.shape[0])

    def copy(self) -> InnovationWindow:
        w = InnovationWindow(self.N, self.centered)
        w._buf = [b.copy() for b in self._buf]
        w._pst = [None if p is None else p.copy() for p in self._pst]
        return w


def guard_innovation_cov(D: FloatArray, P_state: FloatArray, R: FloatArray, r_floor: float = 1e-2,
                         diagonal: bool = False, r_ceiling: float = np.inf) -> tuple[FloatArray, FloatArray]:
    """Implied measurement noise of a windowed innovation covariance, guarded (module docstring).

    Args:
        D: windowed innovation covariance (p, p) (eq. 22).
        P_state: the part of the innovation covariance due to the state, ``H P H^T`` (p, p).
        R: nominal measurement-noise covariance (p, p), SPD.
        r_floor: eigenvalue floor of ``R_hat`` whitened by ``R``.
        diagonal: adapt only the variances: ``R_eff = diag(max(diag(R_hat), r_floor diag(R)))``
            (for a diagonal nominal R).  With N = 10 and p = 6 the window's sample
            correlations scatter by about 1/sqrt(N) = 0.3 and, taken into the gain, couple
            e.g. position innovations into velocity corrections; the diagonal estimate has no
            such spurious terms.
    Returns:
        ``(R_eff (p, p), P_gain = P_state + R_eff (p, p))``, both symmetric positive definite.
    """
    R_eff = guard_noise_cov(symmetrize(D - P_state), R, r_floor, diagonal, r_ceiling)
    return R_eff, symmetrize(P_state + R_eff)


def guard_noise_cov(R_hat: FloatArray, R: FloatArray, r_floor: float = 1e-2, diagonal: bool = False,
                    r_ceiling: float = np.inf) -> FloatArray:
    """An estimated measurement-noise covariance (p, p) made SPD and ``>= r_floor R``: the
    eigenvalues of ``L_R^-1 R_hat L_R^-T`` floored at ``r_floor`` (or, ``diagonal``, the
    variances floored at ``r_floor diag(R)``), see :func:`guard_innovation_cov`; optionally also
    capped at ``r_ceiling`` (``R_eff <= r_ceiling R``)."""
    R_hat = symmetrize(np.asarray(R_hat, dtype=float))
    if diagonal:
        return np.diag(np.clip(np.diag(R_hat), r_floor * np.diag(R), r_ceiling * np.diag(R)))
    L = chol(R)
    W = solve_triangular(L, solve_triangular(L, R_hat, lower=True).T, lower=True)  # L^-1 R_hat L^-T
    w, V = np.linalg.eigh(symmetrize(W))
    Wc = (V * np.clip(w, r_floor, r_ceiling)) @ V.T
    return symmetrize(L @ Wc @ L.T)


def add2_update(x: FloatArray, S: FloatArray, y: FloatArray, h: Fn, SR: FloatArray, window: InnovationWindow,
                residual: Residual | None = None, r_floor: float = 1e-2, step: float = H_STEP,
                diagonal: bool = False, debias: bool = False, r_ceiling: float = np.inf,
                adapt: bool = True) -> tuple[DD2Update, FloatArray]:
    """ADD2 measurement update (eq. 20-23) for one (unbatched) state.

    The innovation is pushed into ``window`` (mutated); once it holds ``N`` innovations (and
    ``adapt``) the gain uses the guarded windowed covariance; ``adapt=False`` is the DD2 update
    with the nominal R (the window still records the innovation).  Returns ``(DD2Update, R_eff)`` where ``R_eff`` (p, p)
    is the measurement-noise covariance the gain implies (the nominal ``SR SR^T`` before the
    window is full) and ``DD2Update.S_y`` the factor of ``P_gain``.
    """
    x = np.asarray(x, dtype=float)
    S = np.asarray(S, dtype=float)
    res = residual or (lambda a, b: a - b)
    fac = divided_differences(x, S, h, step, residual)
    nu = res(np.asarray(y, dtype=float), fac.y)
    R = symmetrize(SR @ SR.T)
    P_state = symmetrize(fac.S1 @ fac.S1.T + fac.S2 @ fac.S2.T)
    window.push(nu, P_state)
    if window.full and adapt:
        if debias:
            R_eff = guard_noise_cov(window.noise_cov(), R, r_floor, diagonal, r_ceiling)
            P_gain = symmetrize(P_state + R_eff)
        else:
            R_eff, P_gain = guard_innovation_cov(window.cov(), P_state, R, r_floor, diagonal, r_ceiling)
        SR_eff = chol(R_eff)
    else:
        R_eff, P_gain, SR_eff = R, P_state + R, SR
    Sy = chol(P_gain)
    K = _gain_from_factor(S @ fac.S1.T, Sy)
    xn, Sn = _posterior(x, S, nu, fac, SR_eff, K)
    return DD2Update(xn, Sn, nu, Sy, K), R_eff


def aekf_predict(x: FloatArray, P: FloatArray, f: Fn, Q: FloatArray, rel_step: float = 1e-6) -> tuple[FloatArray, FloatArray, FloatArray]:
    """EKF time update: ``x_pred = f(x)``, ``P_pred = F P F^T + Q`` with the central-difference
    Jacobian ``F`` at x.  Returns ``(x_pred (n,), P_pred (n, n), F (n, n))``."""
    step = steps_from_cov(P, rel_step)
    F = central_difference_jacobian(f, x, step)
    xp = f(x[None])[0]
    return xp, symmetrize(F @ P @ F.T + Q), F


def aekf_update(x: FloatArray, P: FloatArray, y: FloatArray, h: Fn, R: FloatArray, window: InnovationWindow,
                residual: Residual | None = None, r_floor: float = 1e-2, rel_step: float = 1e-6,
                diagonal: bool = False, debias: bool = False, r_ceiling: float = np.inf, adapt: bool = True
                ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Innovation-adaptive EKF measurement update (Mohamed & Schwarz 1999).

    ``nu = y - h(x)`` enters ``window``; once full (and ``adapt``), ``R_hat = C_v - H P H^T``
    (guarded, see :func:`guard_innovation_cov`) replaces ``R``.  Joseph-form covariance update.
    Returns ``(x (n,), P (n, n), nu (p,), S_nu (p, p), K (n, p), R_used (p, p))``.
    """
    res = residual or (lambda a, b: a - b)
    step = steps_from_cov(P, rel_step)
    H = central_difference_jacobian(h, x, step)
    nu = res(np.asarray(y, dtype=float), h(x[None])[0])
    HPH = symmetrize(H @ P @ H.T)
    window.push(nu, HPH)
    if window.full and adapt and debias:
        R_used = guard_noise_cov(window.noise_cov(), R, r_floor, diagonal, r_ceiling)
        S_nu = symmetrize(HPH + R_used)
    elif window.full and adapt:
        R_used, S_nu = guard_innovation_cov(window.cov(), HPH, R, r_floor, diagonal, r_ceiling)
    else:
        R_used, S_nu = R, symmetrize(HPH + R)
    K = gain(P @ H.T, S_nu)
    I_KH = np.eye(x.shape[0]) - K @ H
    Pn = symmetrize(I_KH @ P @ I_KH.T + K @ R_used @ K.T)
    return x + K @ nu, Pn, nu, S_nu, K, R_used
