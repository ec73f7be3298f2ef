"""The oracle (evaluation only): the transfer-alignment model linearized about the *true* error
state, filtered and smoothed by the linear Kalman filter / RTS smoother with the true noise
statistics.  It knows what no real filter can (the true biases, misalignment and flexure at
every epoch), so its accuracy is the practical bound the real smoothers are compared with.

Implementation: the model's ``f`` and ``h`` are replaced by their first-order expansions about
the true state (Jacobians by central differences), so the generic sigma-point runner computes
the exact linear KF and its RTS smoother (the unscented transform is exact for linear maps).
"""

from __future__ import annotations

from dpos_core.units import FloatArray

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from .. import earth
from ..attitude import attitude_error
from .model import DP, DV, PHI, TransferAlignmentModel



def _jacobian(fn: Callable[[FloatArray], FloatArray], x: FloatArray, scale: FloatArray) -> FloatArray:
    """Central-difference Jacobian (m, n) of fn at x, steps ``scale`` per state."""
    n = x.size
    X = np.concatenate([x + np.diag(scale), x - np.diag(scale)])
    Y = fn(X)
    return ((Y[:n] - Y[n:]) / (2.0 * scale[:, None])).T


class LinearizedAboutTruth:
    """Wraps a TransferAlignmentModel; ``truth_state(t) -> (nav truth, static/flexure truth)``.

    ``truth_nav(t) -> (C_nb (3,3), vel_n (3,), llh (3,))`` of the sub-IMU and
    ``truth_other(t) -> (15,)`` = [eps, nabla, rho, theta, theta_dot] in state units.
    """

    def __init__(self, model: TransferAlignmentModel, truth_nav, truth_other) -> None:
        self.m = model
        self.n = model.n
        self.n_epochs = model.n_epochs
        self._truth_nav = truth_nav
        self._truth_other = truth_other
        self._lin_h: dict[int, FloatArray] = {}
        self._lin_f: dict[int, FloatArray] = {}
        self._F: dict[int, FloatArray] = {}  # Jacobians, cached per epoch
        self._H: dict[int, FloatArray] = {}
        self._step = np.array([1e-6] * 3 + [1e-4] * 3 + [1e-3] * 3 + [1e-9] * 3 + [1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3)

    def _true_error(self, nominal, t: float) -> FloatArray:
        C, v, llh = self._truth_nav(t)
        x = np.empty(self.n)
        x[PHI] = attitude_error(nominal.C_nb, C)
        x[DV] = nominal.vel_n_mps - v
        r_m, r_n = earth.radii_of_curvature(llh[0])
        d = nominal.llh - llh
        x[DP] = [d[1] * (r_n + llh[2]) * np.cos(llh[0]), d[0] * (r_m + llh[2]), d[2]]
        x[9:] = self._truth_other(t)
        return x

    def lin_h(self, k: int) -> FloatArray:
        if k not in self._lin_h:
            self._lin_h[k] = self._true_error(self.m.nominal_at_epochs()[k], float(self.m.epochs_s[k]))
        return self._lin_h[k]

    # StateSpaceModel
    def f(self, k: int, x: FloatArray) -> FloatArray:
        xl = self._lin_f[k]
        F = self._F.get(k)
        if F is None:
            F = _jacobian(lambda X: self.m.f(k, X), xl, self._step)
            self._F[k] = F
        return self.m.f(k, xl[None])[0] + (x - xl) @ F.T

    def Q(self, k: int) -> FloatArray:
        return self.m.Q(k)

    def y(self, k: int):
        return self.m.y(k)

    def R(self, k: int) -> FloatArray:
        return self.m.R(k)

    def h(self, k: int, x: FloatArray) -> FloatArray:
        xl = self.lin_h(k)
        H = self._H.get(k)
        if H is None:
            H = _jacobian(lambda X: self.m.h(k, X), xl, self._step)
            self._H[k] = H
        return self.m.h(k, xl[None])[0] + (x - xl) @ H.T

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        return a - b

    def feedback(self, k: int, mean: FloatArray) -> FloatArray:
        xl = self.lin_h(k)
        c = self.m.feedback(k, mean)  # corrects the nominal and integrates to the next epoch
        self._lin_f[k] = self.m.shift(k, xl, c)
        return c

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        return self.m.shift(k, x, c)

    def prior(self) -> tuple[FloatArray, FloatArray]:
        return self.m.prior()
