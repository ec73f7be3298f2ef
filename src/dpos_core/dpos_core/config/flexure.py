"""Wing flexure model: a second-order Gauss-Markov process per axis ([Gong2018] eq. 13).

``theta_ddot + 2 beta theta_dot + beta^2 theta = eta`` with ``beta = 2.146 / tau`` and white
``eta`` of spectral density ``q = 4 beta^3 sigma^2``, whose stationary variance is ``sigma^2`` for the
angle and ``beta^2 sigma^2`` for its rate; discretized exactly (``Phi = expm(F T)``, ``Q`` by Van
Loan's method).  Along the wing the angle's standard deviation scales as
``(|s| / s_ref)^p`` ([LSFit]: variance growing along the wing).  The simulator samples it
(:mod:`dpos_core.sim.flexure`); the transfer alignment uses it as its model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..units import DEG, FloatArray

#: The bending lever arm: a uniformly curved wing whose section at ``r0`` has turned by ``theta``
#: has moved by half the arc, ``r(t) = r0 + K_BEND (C theta) x r0`` with ``K_BEND = 1/2``.
K_BEND = 0.5


@dataclass(frozen=True)
class FlexureModel:
    """Flexure statistics per body axis (x, y, z of the sub-IMU frame).

    Attributes:
        tau_s: correlation times (3,) [s].
        variance_deg2: angle variances (3,) at the reference span [deg^2].
        reference_span_m: span at which the variances apply.
        span_exponent: the angle's standard deviation scales as ``(|span| / reference)^exponent``.
    """

    tau_s: tuple[float, float, float]
    variance_deg2: tuple[float, float, float]
    reference_span_m: float = 5.0
    span_exponent: float = 1.0

    def __post_init__(self) -> None:
        if len(self.tau_s) != 3 or len(self.variance_deg2) != 3:
            raise ValueError("flexure tau_s and variance_deg2 need 3 values (x, y, z)")
        if any(not np.isfinite(t) or t <= 0 for t in self.tau_s):
            raise ValueError(f"flexure tau_s must be > 0, got {self.tau_s}")
        if any(not np.isfinite(v) or v < 0 for v in self.variance_deg2):
            raise ValueError(f"flexure variance_deg2 must be >= 0, got {self.variance_deg2}")
        if self.reference_span_m <= 0:
            raise ValueError(f"flexure reference_span_m must be > 0, got {self.reference_span_m}")

    @property
    def beta(self) -> FloatArray:
        """``2.146 / tau`` (3,) [1/s]."""
        return 2.146 / np.asarray(self.tau_s, dtype=float)

    @property
    def sigma_rad(self) -> FloatArray:
        """Angle standard deviation at the reference span (3,) [rad]."""
        return np.sqrt(np.asarray(self.variance_deg2, dtype=float)) * DEG

    @property
    def q(self) -> FloatArray:
        """Driving-noise spectral density ``4 beta^3 sigma^2`` (3,) [rad^2/s^3]."""
        return 4.0 * self.beta**3 * self.sigma_rad**2

    def span_scale(self, span_m: float) -> float:
        return float((abs(span_m) / self.reference_span_m) ** self.span_exponent)

    def discrete(self, dt_s: float) -> tuple[FloatArray, FloatArray]:
        """Exact transition ``Phi`` (3, 2, 2) and process noise ``Q`` (3, 2, 2) over ``dt_s`` per axis."""
        Phi = np.empty((3, 2, 2))
        Q = np.empty((3, 2, 2))
        for i, (b, q) in enumerate(zip(self.beta, self.q)):
            F = np.array([[0.0, 1.0], [-b * b, -2.0 * b]])
            G = np.array([[0.0], [1.0]])
            M = np.zeros((4, 4))  # Van Loan (1978)
            M[:2, :2] = -F
            M[:2, 2:] = G @ G.T * q
            M[2:, 2:] = F.T
            E = expm(M * dt_s)
            Phi[i] = E[2:, 2:].T
            Qi = Phi[i] @ E[:2, 2:]
            Q[i] = 0.5 * (Qi + Qi.T)
        return Phi, Q

    def stationary_cov(self) -> FloatArray:
        """Stationary covariance of ``[theta, theta_dot]`` per axis (3, 2, 2)."""
        s2 = self.sigma_rad**2
        return np.stack([np.diag([v, b * b * v]) for v, b in zip(s2, self.beta)])
