"""Deterministic point sets for Gaussian filters.

* :class:`UnscentedPoints`: the scaled unscented transform ([Gong2018] eq. 2-3; Julier 2002,
  van der Merwe 2004): ``2n + 1`` points ``x +- sqrt((n + lambda) P)_j`` with
  ``lambda = alpha^2 (n + kappa) - n``, mean weights ``W0m = lambda / (n + lambda)``,
  ``W0c = W0m + 1 - alpha^2 + beta``, ``Wj = 1 / (2 (n + lambda))``.
* :class:`CentralDifferencePoints`: Stirling's interpolation (Norgaard, Poulsen, Ravn 2000;
  [Fang2012] eq. 2-14): points ``x +- h s_j`` of a square root ``S``, step ``h = sqrt(3)`` for a
  Gaussian prior; mean weights ``(h^2 - n)/h^2`` and ``1/(2 h^2)``.  Used by the CDKF / CDVF
  (:func:`~.gaussian.cd_predict`, :mod:`.variational`) and DD2.

Both are :func:`symmetric_points` of a square root of the covariance, with different scales.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dpos_core.units import FloatArray

from . import _points_kernel as _pk
from .linalg import chol

#: the central-difference step ``h = sqrt(3)`` (``h^2`` = 3, the kurtosis of a Gaussian prior; Norgaard 2000)
CENTRAL_DIFFERENCE_STEP: float = float(np.sqrt(3.0))


def symmetric_points(x: FloatArray, S: FloatArray, scale: float) -> FloatArray:
    """``[x, x + scale s_1 .. x + scale s_n, x - scale s_1 .. x - scale s_n]``, shape (..., 2n + 1, n).

    Args:
        x: mean (..., n).
        S: a square root (..., n, n) of the covariance, ``P = S S^T``; ``s_j`` its columns.
        scale: ``sqrt(n + lambda)`` for the unscented transform ([Gong2018] eq. 2), the step
            ``h`` for central differences ([Fang2012] eq. 2-14, Norgaard 2000).
    """
    n = x.shape[-1]
    lead = x.shape[:-1]
    if S.shape[:-2] == lead:  # one square root per mean: the kernel (the same sums)
        fx = np.ascontiguousarray(x, dtype=float).reshape(-1, n)
        out = np.empty((fx.shape[0], 2 * n + 1, n))
        _pk.symmetric_points(fx, np.ascontiguousarray(S, dtype=float).reshape(-1, n, n), float(scale), out)
        return out.reshape(lead + (2 * n + 1, n))
    d = scale * np.swapaxes(S, -1, -2)  # rows = scaled columns of S
    return np.concatenate([x[..., None, :], x[..., None, :] + d, x[..., None, :] - d], axis=-2)


def _required_cov(P: FloatArray | None) -> FloatArray:
    """``P`` of a ``points(x, P)`` call given no square root ``S``: it must be given then."""
    if P is None:
        raise ValueError("points() needs the covariance P or its square root S")
    return P


@lru_cache(maxsize=256)
def _unscented_weights(alpha: float, beta: float, kappa: float, n: int) -> tuple[FloatArray, FloatArray]:
    """The weights of :meth:`UnscentedPoints.weights`, computed once per (alpha, beta, kappa, n),
    read-only (2n + 1,) each."""
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha**2 + beta
    wm.flags.writeable = False
    wc.flags.writeable = False
    return wm, wc


@lru_cache(maxsize=256)
def _central_difference_weights(h: float, n: int) -> FloatArray:
    """The mean weights of :meth:`CentralDifferencePoints.weights`, computed once per (h, n), read-only (2n + 1,)."""
    h2 = h**2
    wm = np.full(2 * n + 1, 0.5 / h2)
    wm[0] = (h2 - n) / h2
    wm.flags.writeable = False
    return wm


@dataclass(frozen=True)
class UnscentedPoints:
    alpha: float = 1e-1
    beta: float = 2.0
    kappa: float = 0.0

    def lam(self, n: int) -> float:
        return self.alpha**2 * (n + self.kappa) - n

    def weights(self, n: int) -> tuple[FloatArray, FloatArray]:
        """Mean and covariance weights, each (2n + 1,) (read-only, computed once per n)."""
        return _unscented_weights(float(self.alpha), float(self.beta), float(self.kappa), int(n))

    def points(self, x: FloatArray, P: FloatArray | None = None, *, S: FloatArray | None = None) -> FloatArray:
        """Sigma points (..., 2n + 1, n) of mean x (..., n) and covariance P (or square root S)."""
        n = x.shape[-1]
        if S is None:
            S = chol(_required_cov(P))
        return symmetric_points(x, S, np.sqrt(n + self.lam(n)))


@dataclass(frozen=True)
class CentralDifferencePoints:
    h: float = CENTRAL_DIFFERENCE_STEP

    def weights(self, n: int) -> tuple[FloatArray, FloatArray]:
        """Mean weights (2n + 1,), twice (as covariance weights of the unscented rule).  The CDKF's
        covariance is not a weighted sum over these points: :func:`~.gaussian.cd_predict` forms it
        from the first- and second-order divided differences (Stirling; gaussian.py docstring)."""
        wm = _central_difference_weights(float(self.h), int(n))
        return wm, wm

    def points(self, x: FloatArray, P: FloatArray | None = None, *, S: FloatArray | None = None) -> FloatArray:
        """Points (..., 2n + 1, n) of mean x (..., n) and covariance P (or square root S)."""
        if S is None:
            S = chol(_required_cov(P))
        return symmetric_points(x, S, self.h)


#: the default central-difference point set (``h = sqrt(3)``), a default argument of the CDKF / CDVF
CENTRAL_DIFFERENCE_POINTS = CentralDifferencePoints()
