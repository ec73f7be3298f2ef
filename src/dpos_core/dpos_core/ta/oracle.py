"""The oracle (evaluation only): the transfer-alignment model linearized about the *true* error
state, filtered and smoothed by the linear Kalman filter / RTS smoother with the true noise
statistics.  It knows what no real filter can (the true biases, misalignment and flexure at
every epoch), so its accuracy is the practical bound the real smoothers are compared with.

Implementation: the model's ``f`` and ``h`` are replaced by their first-order expansions about
the true state (Jacobians by central differences), so the generic sigma-point runner computes
the exact linear KF and its RTS smoother (the unscented transform is exact for linear maps).

The closed loop needs care.  After epoch k's correction ``c_k`` the runner moves the filtered
mean with ``shift`` and keeps the covariance, which is exact only for a shift with a unit
Jacobian.  The model's shift of the attitude error, ``log(expm(phi) expm(-c))``, is not one: it
turns and scales the attitude block by about ``|c| / 2`` (0.50 at the first epoch of [Gong2018]'s
40 deg initial errors, a 59 deg correction), and a linear KF that skips that Jacobian is no
longer the bound (measured on paper_su, 200 s from 40 deg, seeds 1-8: mean NEES of its 24
filtered states 100-280 and of the smoothed ones 180-1450 instead of about 24; heading RMSE 1.2x
the URTSS's).  So after epoch k the oracle's state is ``u = x - c_k`` (x: the model's error state of
the nominal before the correction), a pure translation; the model's error state of the corrected
nominal is :meth:`LinearizedAboutTruth.after_feedback` ``(k, u)``, and ``f`` is linearized as a
function of u.  :meth:`LinearizedAboutTruth.to_model` maps the estimates back to the model's
coordinates (those of pipeline.TAResult).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dpos_core.units import FloatArray

from .. import earth
from ..attitude import attitude_error
from ..filters.jacobian import central_difference_jacobian
from .model import DP, DV, PHI, TransferAlignmentModel


class LinearizedAboutTruth:
    """Wraps a TransferAlignmentModel; ``truth_state(t) -> (nav truth, static/flexure truth)``.

    ``truth_nav(t) -> (C_nb (3,3), vel_n (3,), llh (3,))`` of the sub-IMU at the main system's time
    t and ``truth_other(t) -> (15,)`` = [eps, nabla, rho, theta, theta_dot] in state units.
    ``installation`` (optional): the true values of the model's installation states (.model
    docstring) by name (``lever_arm`` (3,) [m], the true arm minus the model's; ``time_offset``
    [s]; ``gyro_axes``, ``accel_axes`` (9,); ``master_error``: ``t -> (6,)``, the main POS's ENU
    position and velocity errors at t), absent ones 0.  With a time-offset state the navigation truth of the nominal at stamp t is the truth at
    ``t - tau``.
    """

    def __init__(self, model: TransferAlignmentModel, truth_nav, truth_other, installation: dict | None = None) -> None:
        self.m = model
        self.n = model.n
        self.n_epochs = model.n_epochs
        self._truth_nav = truth_nav
        self._truth_other = truth_other
        inst = installation or {}
        self._extra = np.zeros(model.n - 24)
        self._extra_t: list[tuple[slice, Callable[[float], FloatArray]]] = []  # time-varying ones: (slice, t -> values)
        for name, sl in model.extra.items():
            v = inst.get(name, 0.0)
            if callable(v):
                self._extra_t.append((sl, v))
            else:
                self._extra[sl.start - 24:sl.stop - 24] = np.asarray(v, dtype=float)
        self._tau = float(inst.get("time_offset", 0.0)) if "time_offset" in model.extra else 0.0
        self._lin_h: dict[int, FloatArray] = {}
        self._lin_f: dict[int, FloatArray] = {}  # the truth after epoch k's correction, in u = x - c_k
        self._c: dict[int, FloatArray] = {}  # the corrections c_k
        self._F: dict[int, FloatArray] = {}  # Jacobians, cached per epoch
        self._H: dict[int, FloatArray] = {}
        self._step = np.array([1e-6] * 3 + [1e-4] * 3 + [1e-3] * 3 + [1e-9] * 3 + [1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3
                              + [1e-4] * (model.n - 24))

    def _true_error(self, nominal, t: float) -> FloatArray:
        C, v, llh = self._truth_nav(t - self._tau)
        x = np.empty(self.n)
        x[PHI] = attitude_error(nominal.C_nb, C)
        x[DV] = nominal.vel_n_mps - v
        x[DP] = earth.dllh_to_enu(nominal.llh - llh, llh)
        x[9:24] = self._truth_other(t - self._tau)
        x[24:] = self._extra
        for sl, fn in self._extra_t:
            x[sl] = fn(t)
        return x

    def lin_h(self, k: int) -> FloatArray:
        """The true error state (24,) of the nominal at epoch k before its correction."""
        if k not in self._lin_h:
            self._lin_h[k] = self._true_error(self.m.nominal_at_epochs()[k], float(self.m.epochs_s[k]))
        return self._lin_h[k]

    def after_feedback(self, k: int, u: FloatArray) -> FloatArray:
        """The model's error state (..., 24) of the nominal corrected at epoch k, from the oracle's
        state ``u = x - c_k`` after that epoch (module docstring)."""
        c = self._c[k]
        return self.m.shift(k, np.asarray(u, dtype=float) + c, c)

    def to_model(self, x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Estimates after each epoch's correction, x (K, 24) and P (K, 24, 24), from the oracle's
        coordinates to the model's (``after_feedback``, its Jacobian taken at the truth)."""
        xm, Pm = np.empty_like(x), np.empty_like(P)
        for k in range(x.shape[0]):
            S = central_difference_jacobian(lambda U: self.after_feedback(k, U), self._lin_f[k], self._step)
            xm[k] = self.after_feedback(k, x[k])
            Pm[k] = S @ P[k] @ S.T
        return xm, Pm

    # StateSpaceModel
    def f(self, k: int, x: FloatArray) -> FloatArray:
        ul = self._lin_f[k]
        F = self._F.get(k)
        if F is None:
            F = central_difference_jacobian(lambda U: self.m.f(k, self.after_feedback(k, U)), ul, self._step)
            self._F[k] = F
        return self.m.f(k, self.after_feedback(k, ul[None]))[0] + (x - ul) @ F.T

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
            H = central_difference_jacobian(lambda X: self.m.h(k, X), xl, self._step)
            self._H[k] = H
        return self.m.h(k, xl[None])[0] + (x - xl) @ H.T

    def residual(self, a: FloatArray, b: FloatArray) -> FloatArray:
        return a - b

    def feedback(self, k: int, mean: FloatArray) -> FloatArray:
        xl = self.lin_h(k)
        c = self.m.feedback(k, mean)  # corrects the nominal and integrates to the next epoch
        self._c[k] = c
        self._lin_f[k] = xl - c
        return c

    def shift(self, k: int, x: FloatArray, c: FloatArray) -> FloatArray:
        """A pure translation, so that the runner's unchanged covariance is exact (module docstring)."""
        return np.asarray(x, dtype=float) - c

    def prior(self) -> tuple[FloatArray, FloatArray]:
        return self.m.prior()
