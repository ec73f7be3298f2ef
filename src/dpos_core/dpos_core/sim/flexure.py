"""Wing flexure: a second-order Gauss-Markov process per axis ([Gong2018] eq. 13).

``theta_ddot + 2 beta theta_dot + beta^2 theta = eta`` with ``beta = 2.146 / tau`` and white
``eta`` of spectral density ``q = 4 beta^3 sigma^2``, whose stationary variance is ``sigma^2`` for the
angle and ``beta^2 sigma^2`` for its rate.  The state ``[theta, theta_dot]`` is discretized exactly
(``Phi = expm(F T)``, ``Q`` by Van Loan's method), started from the stationary distribution, and
interpolated between the grid nodes with cubic Hermite polynomials that use ``theta_dot`` as the
slope, so the flexure rate seen by a gyro is the derivative of the flexure angle.

Along the wing the flexure of one wing side is one modal process scaled by the span:
``theta(s, t) = (|s| / s_ref)^p q(t)``, so the variance at the reference span is the configured one
and grows with the span ([LSFit]: variance growing along the wing); left and right wings have
independent realisations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from .._strapdown_kernel import linear_recursion
from ..config.flexure import FlexureModel


@dataclass(frozen=True)
class FlexureRealization:
    """One sampled realisation of the modal flexure process of a wing side.

    Attributes:
        model: the statistics.
        t0_s, dt_s: grid start and step.
        theta: (N, 3) modal angle at the reference span [rad]; theta_dot: (N, 3) [rad/s].
    """

    model: FlexureModel
    t0_s: float
    dt_s: float
    theta: FloatArray
    theta_dot: FloatArray

    @classmethod
    def sample(cls, model: FlexureModel, duration_s: float, dt_s: float, rng: np.random.Generator, t0_s: float = 0.0) -> FlexureRealization:
        n = int(np.ceil(duration_s / dt_s)) + 2
        Phi, Q = model.discrete(dt_s)
        P0 = model.stationary_cov()
        theta = np.empty((n, 3))
        theta_dot = np.empty((n, 3))
        w = rng.standard_normal((n - 1, 3, 2))
        x0n = rng.standard_normal((3, 2))
        for i in range(3):
            if model.sigma_rad[i] == 0.0:
                theta[:, i] = theta_dot[:, i] = 0.0
                continue
            L = np.linalg.cholesky(Q[i])
            x0 = np.linalg.cholesky(P0[i]) @ x0n[i]
            x = linear_recursion(np.ascontiguousarray(Phi[i]), L, x0, np.ascontiguousarray(w[:, i, :]))
            theta[:, i], theta_dot[:, i] = x[:, 0], x[:, 1]
        return cls(model, t0_s, dt_s, theta, theta_dot)

    def at(self, t_s: ArrayLike, span_m: float | None = None) -> tuple[FloatArray, FloatArray]:
        """Angle and rate (M, 3) at times t, scaled to the span (cubic Hermite between nodes)."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        u = (t - self.t0_s) / self.dt_s
        k = np.clip(np.floor(u).astype(int), 0, self.theta.shape[0] - 2)
        s = (u - k)[:, None]
        h = self.dt_s
        y0, y1 = self.theta[k], self.theta[k + 1]
        d0, d1 = self.theta_dot[k], self.theta_dot[k + 1]
        s2, s3 = s * s, s * s * s
        th = (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * d0 + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * d1
        thd = ((6 * s2 - 6 * s) * y0 + (3 * s2 - 4 * s + 1) * h * d0 + (-6 * s2 + 6 * s) * y1 + (3 * s2 - 2 * s) * h * d1) / h
        scale = 1.0 if span_m is None else self.model.span_scale(span_m)
        return scale * th, scale * thd
