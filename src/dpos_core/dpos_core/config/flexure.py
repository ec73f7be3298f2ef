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


#: Mode kinds of the modal wing and the body axis (FLU, wing along y) their rotation turns about:
#: vertical bending (slope = roll-like, about x), torsion (twist about the wing axis y), in-plane
#: (fore-aft) bending (about z).  The index is the axis of :attr:`FlexureModel.variance_deg2`.
MODE_AXIS = {"bending": 0, "torsion": 1, "inplane": 2}


@dataclass(frozen=True)
class WingMode:
    """One structural mode of the cantilever wing, excited by turbulence (white noise).

    The modal coordinate ``q`` is a damped oscillator ``q'' + 2 zeta omega q' + omega^2 q = eta``
    (``omega = 2 pi frequency_hz``) with white ``eta`` of spectral density ``4 zeta omega^3 sigma^2``,
    whose stationary variance is ``sigma^2``: ``q`` is the mode's angle (bending slope, twist) at
    the wing's reference span, so ``sigma_deg`` is the mode's angle 1 sigma there.  The
    envelope of its autocorrelation ``exp(-zeta omega tau) cos(omega_d tau)`` decays with the time
    constant ``1 / (zeta omega)`` (the correlation time compared with [Gong2018]'s tau).

    Attributes:
        kind: ``bending`` (vertical), ``torsion`` or ``inplane`` (fore-aft bending), see :data:`MODE_AXIS`.
        frequency_hz: undamped natural frequency.
        damping: damping ratio zeta in (0, 1].
        sigma_deg: 1 sigma of the mode's angle at the reference span [deg].
        order: mode number (1, 2, ..) of its kind: cantilever bending shape ``b_n L`` = 1.875,
            4.694, 7.855; torsion ``sin((2n - 1) pi x / 2 L)``.
    """

    kind: str
    frequency_hz: float
    damping: float
    sigma_deg: float
    order: int = 1

    def __post_init__(self) -> None:
        if self.kind not in MODE_AXIS:
            raise ValueError(f"mode kind must be one of {sorted(MODE_AXIS)}, got {self.kind!r}")
        if not (np.isfinite(self.frequency_hz) and self.frequency_hz > 0):
            raise ValueError(f"mode frequency_hz must be > 0, got {self.frequency_hz}")
        if not (0 < self.damping <= 1):
            raise ValueError(f"mode damping must be in (0, 1], got {self.damping}")
        if not (np.isfinite(self.sigma_deg) and self.sigma_deg >= 0):
            raise ValueError(f"mode sigma_deg must be >= 0, got {self.sigma_deg}")
        if self.order not in ((1, 2, 3) if self.kind != "torsion" else (1, 2, 3, 4, 5)):
            raise ValueError(f"mode order {self.order} not supported for {self.kind}")

    @property
    def omega(self) -> float:
        """Natural angular frequency [rad/s]."""
        return 2.0 * np.pi * self.frequency_hz

    @property
    def correlation_time_s(self) -> float:
        """Envelope time constant ``1 / (zeta omega)`` of the autocorrelation [s]."""
        return 1.0 / (self.damping * self.omega)

    def discrete(self, dt_s: float) -> tuple[FloatArray, FloatArray]:
        """Exact transition ``Phi`` (2, 2) and process noise ``Q`` (2, 2) of ``[q, q']`` over ``dt_s``."""
        w, z = self.omega, self.damping
        return _oscillator_discrete(w, z, 4.0 * z * w**3 * (self.sigma_deg * DEG) ** 2, dt_s)

    def stationary_cov(self) -> FloatArray:
        """Stationary covariance of ``[q, q']`` (2, 2): ``diag(sigma^2, omega^2 sigma^2)``."""
        s2 = (self.sigma_deg * DEG) ** 2
        return np.diag([s2, self.omega**2 * s2])


def _oscillator_discrete(w: float, z: float, q: float, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact discretization of ``x'' + 2 z w x' + w^2 x = eta`` (PSD q): Phi, Q (2, 2) by Van Loan (1978)."""
    F = np.array([[0.0, 1.0], [-w * w, -2.0 * z * w]])
    M = np.zeros((4, 4))
    M[:2, :2] = -F
    M[1, 3] = q
    M[2:, 2:] = F.T
    E = expm(M * dt_s)
    Phi = E[2:, 2:].T
    Qi = Phi @ E[:2, 2:]
    return Phi, 0.5 * (Qi + Qi.T)


@dataclass(frozen=True)
class ModalWing:
    """A wing that bends like a wing (simulator truth; ``flexure: {model: modal, ..}``).

    Each wing side is a uniform cantilever of length ``semi_span_m`` (root at span 0, the
    fuselage): the sum of its :class:`WingMode` (independent turbulence responses) plus the
    quasi-static bending under the load factor ``n``: ``w(s) = (n - 1) tip_deflection_per_g_m
    x^2 (6 - 4 x + x^2) / 3`` with ``x = |s| / L`` (uniformly loaded cantilever).  The shapes and
    their use live in :mod:`dpos_core.sim.flexure`.

    Attributes:
        semi_span_m: L, root to tip [m]; every sub-IMU and antenna span must be within it.
        reference_span_m: span at which the modes' ``sigma_deg`` apply.
        modes: the modes (at least one).
        tip_deflection_per_g_m: static tip deflection per g of load factor above 1 [m/g].
    """

    semi_span_m: float
    reference_span_m: float
    modes: tuple[WingMode, ...]
    tip_deflection_per_g_m: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.semi_span_m) and self.semi_span_m > 0):
            raise ValueError(f"semi_span_m must be > 0, got {self.semi_span_m}")
        if not (0 < self.reference_span_m <= self.semi_span_m):
            raise ValueError(f"reference_span_m must be in (0, semi_span_m], got {self.reference_span_m}")
        if not self.modes:
            raise ValueError("a modal wing needs at least one mode")
        if not np.isfinite(self.tip_deflection_per_g_m):
            raise ValueError("tip_deflection_per_g_m is not finite")

    def variance_deg2(self) -> tuple[float, float, float]:
        """Angle variance per body axis (x: bending slope, y: twist, z: in-plane) at the reference span
        [deg^2]: the sum over the modes of each kind (independent modes)."""
        v = [0.0, 0.0, 0.0]
        for m in self.modes:
            v[MODE_AXIS[m.kind]] += m.sigma_deg**2
        return v[0], v[1], v[2]
