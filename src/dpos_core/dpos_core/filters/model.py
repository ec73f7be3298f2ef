"""The state-space model interface every filter and smoother runs on ([Gong2018] eq. 1).

``x_{k+1} = f_k(x_k) + w_k``, ``w_k ~ N(0, Q_k)``;  ``y_k = h_k(x_k) + v_k``, ``v_k ~ N(0, R_k)``,
for epochs ``k = 0 .. K-1``.  ``f``/``h`` take states with any leading axes (particles, sigma
points) and are vectorized over them.

Closed-loop error-state filters (the transfer alignment) feed the estimate back into the
navigation at each epoch and reset the error state: after the update at epoch ``k`` the filter
asks ``feedback(k, mean)`` for the correction ``c_k`` it applies, and re-expresses every state
with ``shift(k, x, c_k)`` (the particles move by the applied correction, [Gong2018] sec. 3.3).
Open-loop models return ``None`` from ``feedback``.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from dpos_core.units import FloatArray


class StateSpaceModel(Protocol):
    n: int  #: state dimension
    n_epochs: int  #: K

    def f(self, k: int, x: FloatArray) -> FloatArray:
        """Deterministic transition from epoch k to k + 1, x (..., n) -> (..., n)."""

    def Q(self, k: int) -> FloatArray:
        """Process-noise covariance of the step k -> k + 1, (n, n)."""

    def y(self, k: int) -> FloatArray | None:
        """Measurement at epoch k (p,), or None when there is none."""

    def h(self, k: int, x: FloatArray) -> FloatArray:
        """Measurement function at epoch k, x (..., n) -> (..., p)."""

    def R(self, k: int) -> FloatArray:
        """Measurement-noise covariance at epoch k, (p, p)."""

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """Measurement difference a - b (angles may need care)."""

    def feedback(self, k: int, mean: FloatArray) -> FloatArray | None:
        """Correction applied to the navigation after the update at epoch k, or None."""

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        """States (..., n) re-expressed after the correction c."""


class OpenLoopModel:
    """Mixin: no feedback, plain subtraction residuals."""

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        return a - b

    def feedback(self, k: int, mean: FloatArray) -> FloatArray | None:
        return None

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        return x


class LinearGaussianModel(OpenLoopModel):
    """``x_{k+1} = F x_k + w``, ``y_k = H x_k + v`` with fixed matrices (tests, oracles)."""

    def __init__(self, F: FloatArray, Q: FloatArray, H: FloatArray, R: FloatArray, ys: FloatArray) -> None:
        self.F, self._Q, self.H, self._R = (np.asarray(a, dtype=float) for a in (F, Q, H, R))
        self.ys = np.asarray(ys, dtype=float)
        self.n = self.F.shape[0]
        self.n_epochs = self.ys.shape[0]

    def f(self, k: int, x: FloatArray) -> FloatArray:
        return x @ self.F.T

    def Q(self, k: int) -> FloatArray:
        return self._Q

    def y(self, k: int) -> FloatArray | None:
        return self.ys[k]

    def h(self, k: int, x: FloatArray) -> FloatArray:
        return x @ self.H.T

    def R(self, k: int) -> FloatArray:
        return self._R
