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

ADD2 against AEKF on the in-flight alignment (docs/ifa.md, "ADD2 against AEKF"): with a linear
measurement ([Fang2012] eq. 25) the DD2 update (eq. 6-14) is the Kalman update, and with the same
Q and R the two filters end within 0.15 heading sigma of each other on paper_ifa; [Fang2012]'s
advantage of DD2 (eq. 31-34, the EKF's second-order error at a large heading error) does not
arise once the fine phase starts within 1 deg.  What separates the adaptive filters is the R
sequence their innovation windows choose.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve, solve_triangular

from dpos_core.chi2 import chi2_quantile
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




class ChangePointWindow:
    """Innovation window of adaptive length with a pooled, debiased noise estimate: ADD2's R
    estimate ([Fang2012] eq. 21-22) for a measurement noise that is piecewise constant with jumps.

    The noise model is ``R_k = diag(s_g,k^2 R_nom,i)`` with one scale per channel group ``g``
    (``groups``; default one per channel): each group's scale is estimated by pooling the
    whitened, debiased outer products of its channels over the epochs since the last detected
    change (at most ``N_max``)::

        s_g^2 = 1/(n |g|) sum_{k in window} sum_{i in g} (z_k,i^2 - (H P_k H^T)_ii) / R_nom,i

    (the diagonal of eq. 22 minus each innovation's own state part, :meth:`InnovationWindow.noise_cov`).
    Pooling ``|g|`` channels and a window longer than eq. 22's N = 10 lower the estimate's
    relative variance from ``2/N`` (one channel, N epochs) to ``2/(n |g|)``.  A longer window alone
    would lag a jump; so each epoch tests the last ``m`` epochs' normalized innovations against
    the scale estimated from the epochs before them::

        T = sum_{last m epochs} sum_{i in g} z_k,i^2 / ((H P_k H^T)_ii + s_g^2 R_nom,i)  ~  chi^2(m |g|)

    and a ``T`` beyond the two-sided ``quantile`` (upper ``quantile``, lower ``1 - quantile``)
    is a change: the group's window restarts from those ``m`` epochs.  An estimate is available
    once ``n_min`` epochs are held (:attr:`full`).

    Args:
        N_max: longest window [epochs] (>= n_min).
        n_min: epochs before the estimate is used (>= 1), also the test length ``m``.
        groups: channel index groups sharing one scale, e.g. ``((0, 1, 2), (3, 4, 5))`` for GNSS
            position and velocity; ``None``: each channel its own.
        quantile: chi-square quantile of the change test, in (0.5, 1).
    """

    def __init__(self, N_max: int = 30, n_min: int = 3, groups: tuple[tuple[int, ...], ...] | None = None,
                 quantile: float = 0.999) -> None:
        if int(n_min) < 1 or int(N_max) < int(n_min):
            raise ValueError(f"need 1 <= n_min <= N_max, got n_min={n_min}, N_max={N_max}")
        if not 0.5 < float(quantile) < 1.0:
            raise ValueError(f"change-test quantile must be in (0.5, 1), got {quantile}")
        self.N = int(N_max)
        self.n_min = int(n_min)
        self.groups = None if groups is None else tuple(tuple(int(i) for i in g) for g in groups)
        self.quantile = float(quantile)
        self._z2: list[FloatArray] = []  # z_k,i^2 (p,)
        self._pst: list[FloatArray] = []  # (H P_k H^T)_ii (p,)
        self._start: FloatArray | None = None  # per channel: index in the buffer where its group's window starts
        self._tested = 0  # epochs of the buffer that went through the change test
        self._pushed = 0
        self.changes: list[int] = []  #: pushes (1-based count) whose test detected a change

    def __len__(self) -> int:
        return len(self._z2)

    @property
    def full(self) -> bool:
        """Every group's window holds at least ``n_min`` epochs."""
        if self._start is None:
            return False
        return bool(len(self._z2) - np.max(self._start) >= self.n_min)

    def _group_index(self, p: int) -> list[NDArray[np.int_]]:
        gs = [tuple(range(p))[i:i + 1] for i in range(p)] if self.groups is None else self.groups
        return [np.asarray(g, dtype=int) for g in gs]

    def push(self, nu: FloatArray, P_state: FloatArray | None = None) -> None:
        """Add an innovation (p,) and the state part ``H P H^T`` (p, p) of its covariance
        (required).  A non-finite innovation raises :class:`~dpos_core.errors.NumericalFailure`."""
        nu = np.asarray(nu, dtype=float)
        if nu.ndim != 1:
            raise ValueError(f"ChangePointWindow takes one innovation (p,), got shape {nu.shape}")
        if not np.all(np.isfinite(nu)):
            raise NumericalFailure("innovation is not finite (the prediction diverged)", what="innovation window")
        if P_state is None:
            raise ValueError("ChangePointWindow.push needs the state part H P H^T of the innovation covariance")
        if self._start is None:
            self._start = np.zeros(nu.size)
        self._z2.append(nu * nu)
        self._pst.append(np.diag(np.asarray(P_state, dtype=float)).copy())
        self._pushed += 1
        if len(self._z2) > self.N:
            self._z2.pop(0)
            self._pst.pop(0)
            self._start = np.maximum(self._start - 1, 0)
            self._tested = max(self._tested - 1, 0)

    def _scale(self, g: NDArray[np.int_], a: int, b: int, R: FloatArray) -> float:
        """Pooled debiased scale of group ``g`` over buffer epochs ``[a, b)`` (see class docstring)."""
        z2 = np.asarray(self._z2[a:b])[:, g]
        ps = np.asarray(self._pst[a:b])[:, g]
        return float(np.mean((z2 - ps) / R[g]))

    def noise_estimate(self, R: FloatArray, r_floor: float = 0.0) -> FloatArray:
        """Run the change test over the epochs not tested yet, then return the estimate
        ``diag(s_g^2 R_nom,i)`` (p, p) of the measurement noise (class docstring; ``R`` (p, p) is the
        nominal covariance, its diagonal is used).  The scale in the test is floored at ``r_floor``
        (the guard's floor), so that an estimate that fell below it does not raise false changes."""
        if self._start is None:
            raise ValueError("empty innovation window")
        Rd = np.diag(np.asarray(R, dtype=float))
        n, m = len(self._z2), self.n_min
        idx = self._group_index(Rd.size)
        hi = {g.size: chi2_quantile(self.quantile, m * g.size) for g in idx}
        lo = {g.size: chi2_quantile(1.0 - self.quantile, m * g.size) for g in idx}
        for k in range(max(self._tested, 0) + 1, n + 1):  # epoch k-1 is the newest of the test
            for g in idx:
                a = int(self._start[g[0]])
                if k - m - a < m:  # the reference part (before the last m) needs m epochs itself
                    continue
                s2 = max(self._scale(g, a, k - m, Rd), r_floor)
                z2 = np.asarray(self._z2[k - m:k])[:, g]
                ps = np.asarray(self._pst[k - m:k])[:, g]
                T = float(np.sum(z2 / (ps + s2 * Rd[g])))
                if T > hi[g.size] or T < lo[g.size]:
                    self._start[g] = k - m
                    self.changes.append(self._pushed - n + k)
        self._tested = n
        scale = np.empty(Rd.size)
        for g in idx:
            scale[g] = self._scale(g, int(self._start[g[0]]), n, Rd)
        return np.diag(scale * Rd)

    def copy(self) -> ChangePointWindow:
        w = ChangePointWindow(self.N, self.n_min, self.groups, self.quantile)
        w._z2 = [z.copy() for z in self._z2]
        w._pst = [p.copy() for p in self._pst]
        w._start = None if self._start is None else self._start.copy()
        w._tested, w._pushed = self._tested, self._pushed
        w.changes = list(self.changes)
        return w


#: the innovation windows the adaptive updates take
NoiseWindow = InnovationWindow | ChangePointWindow


def window_noise_estimate(window: NoiseWindow, P_state: FloatArray, R: FloatArray, debias: bool = False,
                          r_floor: float = 0.0) -> FloatArray:
    """The unguarded measurement-noise estimate (p, p) of a full window: ``D_k - H P H^T`` (eq. 22
    minus the current state part), ``debias``: :meth:`InnovationWindow.noise_cov`; a
    :class:`ChangePointWindow` gives its pooled estimate (``debias`` does not apply: it is debiased)."""
    if isinstance(window, ChangePointWindow):
        return window.noise_estimate(R, r_floor)
    return window.noise_cov() if debias else symmetrize(window.cov() - P_state)


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


def add2_update(x: FloatArray, S: FloatArray, y: FloatArray, h: Fn, SR: FloatArray, window: NoiseWindow,
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
        R_eff = guard_noise_cov(window_noise_estimate(window, P_state, R, debias, r_floor), R, r_floor, diagonal, r_ceiling)
        P_gain = symmetrize(P_state + R_eff)
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


def aekf_update(x: FloatArray, P: FloatArray, y: FloatArray, h: Fn, R: FloatArray, window: NoiseWindow,
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
    if window.full and adapt:
        R_used = guard_noise_cov(window_noise_estimate(window, HPH, R, debias, r_floor), R, r_floor, diagonal, r_ceiling)
        S_nu = symmetrize(HPH + R_used)
    else:
        R_used, S_nu = R, symmetrize(HPH + R)
    K = gain(P @ H.T, S_nu)
    I_KH = np.eye(x.shape[0]) - K @ H
    Pn = symmetrize(I_KH @ P @ I_KH.T + K @ R_used @ K.T)
    return x + K @ nu, Pn, nu, S_nu, K, R_used
