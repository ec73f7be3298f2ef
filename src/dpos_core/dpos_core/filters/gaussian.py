"""Gaussian filters and the Rauch-Tung-Striebel smoother, shared by KF, UKF and (via the same
cross-covariance) URTSS.

* Linear Kalman filter: ``kf_predict`` / ``kf_update``.
* Unscented Kalman filter ([Gong2018] eq. 2-5): ``ut_predict`` / ``ut_update`` propagate any point
  set (:mod:`.points`) through the model, batched over leading axes (particles).
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

from .linalg import gain, symmetrize
from .points import UnscentedPoints

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
    dYw = np.swapaxes(dY * wc[:, None], -1, -2)  # weighted outer products as batched matmuls
    Pp = dYw @ dY + Q
    C = np.swapaxes(dX * wc[:, None], -1, -2) @ dY
    return Prediction(xp, symmetrize(Pp), C)


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
    dZw = np.swapaxes(dZ * wc[:, None], -1, -2)
    S = symmetrize(dZw @ dZ + R)
    Pxz = np.swapaxes(dX * wc[:, None], -1, -2) @ dZ
    K = gain(Pxz, S)
    nu = res(y, zp)
    xn = x + np.einsum("...ij,...j->...i", K, nu)
    Pn = P - K @ S @ np.swapaxes(K, -1, -2)
    return Update(xn, symmetrize(Pn), nu, S, K)


def rts_smooth(
    x_f: FloatArray, P_f: FloatArray, x_p: FloatArray, P_p: FloatArray, C: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Fixed-interval smoother over K epochs.

    Args:
        x_f, P_f: filtered ``x_{k|k}`` (K, n), ``P_{k|k}`` (K, n, n).
        x_p, P_p: predictions ``x_{k+1|k}`` (K-1, n), ``P_{k+1|k}`` (K-1, n, n).
        C: cross-covariances ``C_k`` (K-1, n, n).

    Returns:
        Smoothed ``x_{k|K}`` (K, n), ``P_{k|K}`` (K, n, n).
    """
    xs = x_f.copy()
    Ps = P_f.copy()
    for k in range(x_f.shape[0] - 2, -1, -1):
        G = gain(C[k], P_p[k])  # C_k P_{k+1|k}^-1 (P_p is SPD)
        xs[k] = x_f[k] + G @ (xs[k + 1] - x_p[k])
        Ps[k] = symmetrize(P_f[k] + G @ (Ps[k + 1] - P_p[k]) @ G.T)
    return xs, Ps
