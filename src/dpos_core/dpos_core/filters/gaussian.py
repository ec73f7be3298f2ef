"""Gaussian filters and the Rauch-Tung-Striebel smoother, shared by KF, UKF and (via the same
cross-covariance) URTSS.

* Linear Kalman filter: ``kf_predict`` / ``kf_update``.
* Unscented Kalman filter ([Gong2018] eq. 2-5): ``ut_predict`` / ``ut_update`` propagate any point
  set (:mod:`.points`) through the model, batched over leading axes (particles).
* Central-difference Kalman filter (CDKF; Stirling's second-order interpolation, Norgaard,
  Poulsen, Ravn 2000; [Ye2024] sec. 2.2 eq. 14-28): ``cd_predict`` / ``cd_update``.  The points
  ``x +- h s_j`` (``h^2 = 3``) of :class:`~.points.CentralDifferencePoints`, the mean with its mean
  weights, and the covariance from the first- and second-order divided differences of
  :func:`~.dd2.divided_differences` (the DD2's square-root factors, squared)::

      P_pred = S_x1 S_x1^T + S_x2 S_x2^T + Q,  C = S S_x1^T,
      P_y = S_y1 S_y1^T + S_y2 S_y2^T + R,  P_xy = S S_y1^T,  K = P_xy P_y^-1,  P+ = P - K P_y K^T

  i.e. [Ye2024] eq. 15-16 and 22-28 with ``w1 = 1/(4 h^2)`` and ``w2 = (h^2 - 1)/(4 h^4)``: the
  same filter as the square-root DD2 of :mod:`.dd2`, in covariance form (a process noise with
  zero blocks, as the transfer alignment's constant states have, needs no factor).  The
  unscented rule with the central-difference points and their weights (``ut_predict(...,
  CentralDifferencePoints())``, covariance weights = mean weights) is not this filter: its
  covariance differs by ``- sum_{j != k} m_j m_k^T``, ``m_j = (f_j^+ + f_j^- - 2 f_0) / (2 h^2)``
  (cross products of the second-order terms of different directions): the same on a linear
  model, not on a nonlinear one (``Cov(x_1^2, x_2^2)`` of independent ``x_1, x_2``: 0 here,
  ``-s_1^2 s_2^2`` there; test_cdkf_cdvf.py).
* ``rts_smooth``: the RTS recursion written with the cross-covariance ``C_k = Cov(x_k, x_{k+1} | y_1:k)``,
  which is ``P_k F^T`` for the linear filter and the sigma-point cross-covariance for the
  unscented one, so the same code is the RTS smoother and the URTSS (Sarkka 2008, eq. 12-14):
  ``G_k = C_k P_{k+1|k}^-1``, ``x_k^s = x_k + G_k (x_{k+1}^s - x_{k+1|k})``,
  ``P_k^s = P_k + G_k (P_{k+1}^s - P_{k+1|k}) G_k^T``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dpos_core.units import FloatArray

from . import _ut_kernel as _utk
from .dd2 import divided_differences
from .linalg import chol, gain, symmetrize
from .points import CENTRAL_DIFFERENCE_POINTS, CentralDifferencePoints, UnscentedPoints
from .store import EpochStore, PerEpoch, blocks

Fn = Callable[[FloatArray], FloatArray]


@dataclass(frozen=True)
class Prediction:
    """``x_{k+1|k}`` (..., n), ``P_{k+1|k}`` (..., n, n) and the cross-covariance ``C_k`` (..., n, n)."""

    x: FloatArray
    P: FloatArray
    C: FloatArray


@dataclass(frozen=True)
class Update:
    """Posterior ``x``, ``P``; innovation ``nu`` (..., p) and its covariance ``S`` (..., p, p); gain ``K``."""

    x: FloatArray
    P: FloatArray
    nu: FloatArray
    S: FloatArray
    K: FloatArray


def kf_predict(x: FloatArray, P: FloatArray, F: FloatArray, Q: FloatArray) -> Prediction:
    xp = np.einsum("...ij,...j->...i", F, x)
    C = P @ np.swapaxes(F, -1, -2)
    return Prediction(xp, symmetrize(F @ C + Q), C)


def kf_update(x: FloatArray, P: FloatArray, y: FloatArray, H: FloatArray, R: FloatArray) -> Update:
    Pxy = P @ np.swapaxes(H, -1, -2)
    S = symmetrize(H @ Pxy + R)
    K = gain(Pxy, S)
    nu = y - np.einsum("...ij,...j->...i", H, x)
    xn = x + np.einsum("...ij,...j->...i", K, nu)
    Pn = P - K @ S @ np.swapaxes(K, -1, -2)
    return Update(xn, symmetrize(Pn), nu, S, K)


def ut_predict(x: FloatArray, P: FloatArray, f: Fn, Q: FloatArray, points=UnscentedPoints()) -> Prediction:
    """Unscented time update with additive process noise ([Gong2018] eq. 4)."""
    n = x.shape[-1]
    wm, wc = points.weights(n)
    X = points.points(x, P)
    Y = f(X)
    xp = wm @ Y
    dY = Y - xp[..., None, :]
    dX = X - x[..., None, :]
    Pp, C = _ut_moments(dX, dY, wc, Q)
    return Prediction(xp, Pp, C)


def _ut_moments(dX: FloatArray, dY: FloatArray, wc: FloatArray, noise: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``sym(sum_l wc_l dY_l dY_l^T + noise)`` (..., q, q) and ``sum_l wc_l dX_l dY_l^T`` (..., a, q) of
    the deviations dX (..., L, a), dY (..., L, q) of L points from their means, covariance weights
    wc (L,), an additive noise (q, q) ([Gong2018] eq. 4-5's covariances; numba kernel)."""
    lead = dY.shape[:-2]
    L, q, a = dY.shape[-2], dY.shape[-1], dX.shape[-1]
    fX = np.ascontiguousarray(dX, dtype=float).reshape(-1, L, a)
    fY = np.ascontiguousarray(dY, dtype=float).reshape(-1, L, q)
    cov, cross = np.empty((fY.shape[0], q, q)), np.empty((fY.shape[0], a, q))
    _utk.moments(fX, fY, np.ascontiguousarray(wc, dtype=float), np.ascontiguousarray(noise, dtype=float), cov, cross)
    return cov.reshape(lead + (q, q)), cross.reshape(lead + (a, q))


def ut_update(
    x: FloatArray,
    P: FloatArray,
    y: FloatArray,
    h: Fn,
    R: FloatArray,
    points=UnscentedPoints(),
    residual: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
) -> Update:
    """Unscented measurement update with additive noise ([Gong2018] eq. 5).

    ``residual(a, b)`` (default ``a - b``) forms measurement differences (e.g. for angles)."""
    n = x.shape[-1]
    wm, wc = points.weights(n)
    X = points.points(x, P)
    Z = h(X)
    zp = wm @ Z
    res = residual or (lambda a, b: a - b)
    dZ = res(Z, zp[..., None, :])
    dX = X - x[..., None, :]
    S, Pxz = _ut_moments(dX, dZ, wc, R)
    nu = res(y, zp)
    return _correct(x, P, Pxz, S, nu)


def _correct(x: FloatArray, P: FloatArray, Pxz: FloatArray, S: FloatArray, nu: FloatArray) -> Update:
    """The Kalman correction with gain ``K = Pxz S^-1`` (..., n, p) ([Gong2018] eq. 5): ``x + K nu``,
    ``sym(P - K S K^T)``; x (..., n), P (..., n, n), S (..., p, p), nu (..., p), batched together
    (numba kernel; an S not positive definite to rounding goes through :func:`~.linalg.gain`, which
    repairs or raises)."""
    n, p = Pxz.shape[-2], Pxz.shape[-1]
    lead = x.shape[:-1]
    if P.shape[:-2] == lead and Pxz.shape[:-2] == lead and S.shape[:-2] == lead and nu.shape[:-1] == lead:  # (else broadcast below)
        args = [np.ascontiguousarray(a, dtype=float).reshape((-1,) + a.shape[a.ndim - k:]) for a, k in ((x, 1), (P, 2), (Pxz, 2), (S, 2), (nu, 1))]
        B = args[0].shape[0]
        xn, Pn, K = np.empty((B, n)), np.empty((B, n, n)), np.empty((B, n, p))
        if _utk.correct(*args, xn, Pn, K):
            return Update(xn.reshape(lead + (n,)), Pn.reshape(lead + (n, n)), nu, S, K.reshape(lead + (n, p)))
    K = gain(Pxz, S)
    xn = x + np.einsum("...ij,...j->...i", K, nu)
    return Update(xn, symmetrize(P - K @ S @ np.swapaxes(K, -1, -2)), nu, S, K)


def _outer(A: FloatArray) -> FloatArray:
    """``A A^T`` over the last two axes."""
    return A @ np.swapaxes(A, -1, -2)


def cd_predict(x: FloatArray, P: FloatArray, f: Fn, Q: FloatArray, points: CentralDifferencePoints = CENTRAL_DIFFERENCE_POINTS) -> Prediction:
    """CDKF time update with additive process noise ([Ye2024] eq. 14-16, Algorithm 2 steps 1-6;
    module docstring): x (..., n), P (..., n, n), Q (n, n) -> ``x_pred``, ``P_pred`` and
    ``C = Cov(x_k, x_{k+1}) = S S_x1^T`` (the smoother's cross-covariance)."""
    S = chol(P)
    m, S1, S2 = divided_differences(x, S, f, points.h)
    return Prediction(m, symmetrize(_outer(S1) + _outer(S2) + Q), S @ np.swapaxes(S1, -1, -2))


def cd_update(
    x: FloatArray,
    P: FloatArray,
    y: FloatArray,
    h: Fn,
    R: FloatArray,
    points: CentralDifferencePoints = CENTRAL_DIFFERENCE_POINTS,
    residual: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
) -> Update:
    """CDKF measurement update with additive noise ([Ye2024] eq. 17-23; module docstring).

    ``residual(a, b)`` (default ``a - b``) forms measurement differences."""
    S = chol(P)
    y_pred, S1, S2 = divided_differences(x, S, h, points.h, residual)
    Py = symmetrize(_outer(S1) + _outer(S2) + R)
    K = gain(S @ np.swapaxes(S1, -1, -2), Py)
    res = residual or (lambda a, b: a - b)
    nu = res(np.asarray(y, dtype=float), y_pred)
    xn = x + np.einsum("...ij,...j->...i", K, nu)
    return Update(xn, symmetrize(P - K @ Py @ np.swapaxes(K, -1, -2)), nu, Py, K)


#: epochs the RTS recursion reads and writes at once (:func:`rts_smooth`)
RTS_BLOCK = 256


def rts_smooth(
    x_f: PerEpoch, P_f: PerEpoch, x_p: PerEpoch, P_p: PerEpoch, C: PerEpoch, store: EpochStore | None = None,
    block: int | None = None,
) -> tuple[PerEpoch, PerEpoch]:
    """Fixed-interval smoother over K epochs.

    Args:
        x_f, P_f: filtered ``x_{k|k}`` (K, n), ``P_{k|k}`` (K, n, n).
        x_p, P_p: predictions ``x_{k+1|k}`` (K-1, n), ``P_{k+1|k}`` (K-1, n, n).
        C: cross-covariances ``C_k`` (K-1, n, n).
        store: where the result goes (:class:`~.store.EpochStore`; default in memory).  The inputs
            (numpy arrays or :class:`~.store.EpochArray` files) are read and the result written
            ``block`` epochs at a time (default :data:`RTS_BLOCK`), last to first: the same numbers
            whatever the block.

    Returns:
        Smoothed ``x_{k|K}`` (K, n), ``P_{k|K}`` (K, n, n).
    """
    st = EpochStore() if store is None else store
    block = RTS_BLOCK if block is None else max(int(block), 1)
    K = len(x_f)
    n = x_f.shape[1]
    xs, Ps = st.array("x_s", K, (n,)), st.array("P_s", K, (n, n))
    if K == 0:
        return xs, Ps
    x_next, P_next = np.array(x_f[K - 1]), np.array(P_f[K - 1])  # x_{k+1|K}, P_{k+1|K}
    xs[K - 1], Ps[K - 1] = x_next, P_next
    for b0, b1 in blocks(K - 1, block, reverse=True):
        xf, Pf, xp, Pp, Cb = x_f[b0:b1], P_f[b0:b1], x_p[b0:b1], P_p[b0:b1], C[b0:b1]
        xs_b, Ps_b = np.empty_like(xf), np.empty_like(Pf)
        for i in range(b1 - b0 - 1, -1, -1):
            G = gain(Cb[i], Pp[i])  # C_k P_{k+1|k}^-1 (P_p is SPD)
            xs_b[i] = x_next = xf[i] + G @ (x_next - xp[i])
            Ps_b[i] = P_next = symmetrize(Pf[i] + G @ (P_next - Pp[i]) @ G.T)
        xs[b0:b1], Ps[b0:b1] = xs_b, Ps_b
    return xs, Ps
