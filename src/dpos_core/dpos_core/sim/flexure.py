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

The modal wing (``flexure: {model: modal}``, :class:`ModalRealization`) replaces that scaled
process by the structure of a real wing, a uniform cantilever of length ``L`` per side
(Euler-Bernoulli; root clamped at the fuselage), ``x = |s| / L``:

* vertical / in-plane bending modes ``phi_n(x) = cosh(b x) - cos(b x) - sigma_n (sinh(b x) - sin(b x))``,
  ``b = b_n L`` = 1.8751, 4.6941, 7.8548, ``sigma_n = (cosh b + cos b) / (sinh b + sin b)``
  (``phi(0) = phi'(0) = 0``, free tip); deflection ``w(s) = q L phi(x) / phi'(x_ref)`` and slope
  ``dw/ds = q phi'(x) / phi'(x_ref)``, so the modal coordinate ``q`` is the slope at the reference span;
* torsion modes ``sin((2n - 1) pi x / 2)``, twist ``q sin(.. x) / sin(.. x_ref)`` (no deflection);
* each ``q`` a damped oscillator driven by white noise (turbulence), :class:`WingMode`;
* quasi-static bending under the load factor ``n`` (vertical specific force in body axes / g):
  ``w(s) = (n - 1) w_tip,g S(x)``, ``S(x) = x^2 (6 - 4 x + x^2) / 3`` (uniformly loaded cantilever,
  ``S(1) = 1``), slope ``(n - 1) w_tip,g S'(x) / L``.

Rotations, in master body axes (FLU) with the wing direction ``e = [0, -side, 0]`` (side +1
right, -1 left): bending slope about ``e x z``, twist about ``e``, in-plane slope about ``e x x``;
displacements: vertical ``w z``, in-plane ``u x``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from dpos_core.units import FloatArray

from .. import earth
from .._strapdown_kernel import linear_recursion
from ..config.flexure import FlexureModel, ModalWing, WingMode


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


#: ``b_n L`` of the uniform cantilever's bending modes (roots of ``1 + cos b cosh b = 0``).
BENDING_BL = (1.8751040687, 4.6940911330, 7.8547574382)


def bending_shape(x: ArrayLike, order: int = 1) -> tuple[FloatArray, FloatArray]:
    """Cantilever bending mode ``phi_n(x)`` and ``d phi / dx`` at ``x = s / L`` (any shape), ``phi(1) = +-2``."""
    b = BENDING_BL[order - 1]
    x = np.asarray(x, dtype=float)
    sig = (np.cosh(b) + np.cos(b)) / (np.sinh(b) + np.sin(b))
    bx = b * x
    phi = np.cosh(bx) - np.cos(bx) - sig * (np.sinh(bx) - np.sin(bx))
    dphi = b * (np.sinh(bx) + np.sin(bx) - sig * (np.cosh(bx) - np.cos(bx)))
    return phi, dphi


def torsion_shape(x: ArrayLike, order: int = 1) -> FloatArray:
    """Cantilever torsion mode ``sin((2n - 1) pi x / 2)`` at ``x = s / L`` (zero twist at the root)."""
    return np.sin((2 * order - 1) * np.pi * np.asarray(x, dtype=float) / 2.0)


def static_shape(x: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Uniformly loaded cantilever ``S(x) = x^2 (6 - 4 x + x^2) / 3`` (``S(1) = 1``) and ``dS/dx``."""
    x = np.asarray(x, dtype=float)
    return x * x * (6.0 - 4.0 * x + x * x) / 3.0, (12.0 * x - 12.0 * x * x + 4.0 * x**3) / 3.0


def load_factor(flight, grid_hz: float = 20.0) -> Callable[[FloatArray], tuple[FloatArray, FloatArray]]:
    """``t -> (n - 1 (M,), dn/dt (M,))`` of a :class:`~dpos_core.sim.flight.Flight`.

    ``n = f_z^b / g``: the body-up component of the specific force ``f^n = dv^n/dt + [0, 0, g]``
    (ENU) of the flight's closed-form velocity, over the local normal gravity (1 in level flight,
    ``1 / cos(bank)`` in a coordinated turn).  Coriolis and transport-rate terms (2 Omega v / g ~
    1.5e-3 at 100 m/s) are left out: they are no aerodynamic load.  Sampled at ``grid_hz`` and
    interpolated by a cubic spline, so the rate is the exact derivative of the interpolant.
    """
    t = np.linspace(0.0, flight.duration_s, int(np.ceil(flight.duration_s * grid_hz)) + 1)
    p = flight.profiles(t)
    cg, sg, sp, cp = np.cos(p.gamma), np.sin(p.gamma), np.sin(p.heading), np.cos(p.heading)
    a = (p.speed_rate[:, None] * np.stack([cg * sp, cg * cp, sg], -1)
         + (p.speed * p.gamma_rate)[:, None] * np.stack([-sg * sp, -sg * cp, cg], -1)
         + (p.speed * p.heading_rate * cg)[:, None] * np.stack([cp, -sp, np.zeros_like(cp)], -1))
    llh = flight.llh(t)
    g = earth.normal_gravity(llh[:, 0], llh[:, 2])
    a[:, 2] += g
    C_nb, _ = flight.attitude(t)
    n = np.einsum("ni,ni->n", C_nb[:, :, 2], a) / g
    cs = CubicSpline(t, n - 1.0) if t.size > 1 else None

    def f(tq: FloatArray) -> tuple[FloatArray, FloatArray]:
        tq = np.clip(np.asarray(tq, dtype=float).reshape(-1), 0.0, flight.duration_s)
        if cs is None:
            return np.full(tq.shape, n[0] - 1.0), np.zeros(tq.shape)
        return cs(tq), cs(tq, 1)

    return f


def _mode_shape(mode: WingMode, x: float, x_ref: float, L: float) -> tuple[float, float]:
    """(angle factor, displacement factor [m]) of a mode at ``x`` per unit modal coordinate."""
    if mode.kind == "torsion":
        return float(torsion_shape(x, mode.order) / torsion_shape(x_ref, mode.order)), 0.0
    phi, dphi = bending_shape(x, mode.order)
    _, dphi_ref = bending_shape(x_ref, mode.order)
    return float(dphi / dphi_ref), float(L * phi / dphi_ref)


@dataclass(frozen=True)
class ModalRealization:
    """One sampled realisation of a :class:`ModalWing` side (module docstring).

    Attributes:
        wing: the configuration; side: +1 right wing, -1 left wing.
        t0_s, dt_s: grid start and step.
        q: (N, K) modal coordinates (the modes' angles at the reference span) [rad]; q_dot: (N, K) [rad/s].
        load: ``t -> (n - 1, dn/dt)`` of the flight, or None (no quasi-static bending).
    """

    wing: ModalWing
    side: int
    t0_s: float
    dt_s: float
    q: FloatArray
    q_dot: FloatArray
    load: Callable[[FloatArray], tuple[FloatArray, FloatArray]] | None = None

    @classmethod
    def sample(cls, wing: ModalWing, side: int, duration_s: float, dt_s: float, rng: np.random.Generator,
               load: Callable[[FloatArray], tuple[FloatArray, FloatArray]] | None = None, t0_s: float = 0.0) -> ModalRealization:
        """Exact discrete oscillators from their stationary distribution, one per mode (independent)."""
        n = int(np.ceil(duration_s / dt_s)) + 2
        k = len(wing.modes)
        q = np.zeros((n, k))
        qd = np.zeros((n, k))
        w = rng.standard_normal((n - 1, k, 2))
        x0n = rng.standard_normal((k, 2))
        for i, m in enumerate(wing.modes):
            if m.sigma_deg == 0.0:
                continue
            Phi, Q = m.discrete(dt_s)
            x0 = np.linalg.cholesky(m.stationary_cov()) @ x0n[i]
            x = linear_recursion(np.ascontiguousarray(Phi), np.linalg.cholesky(Q), x0, np.ascontiguousarray(w[:, i, :]))
            q[:, i], qd[:, i] = x[:, 0], x[:, 1]
        return cls(wing, 1 if side > 0 else -1, t0_s, dt_s, q, qd, load)

    def modal(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Modal coordinates and rates (M, K) at times t (cubic Hermite with the rate as slope)."""
        return _hermite(t_s, self.t0_s, self.dt_s, self.q, self.q_dot)

    def _shapes(self, span_m: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Per mode (K,): angle factor, displacement factor, rotation axis (K, 3), displacement axis (K, 3)."""
        L = self.wing.semi_span_m
        x, x_ref = min(abs(span_m) / L, 1.0), self.wing.reference_span_m / L
        e = np.array([0.0, -float(self.side), 0.0])
        ax = {"bending": np.cross(e, [0.0, 0.0, 1.0]), "torsion": e, "inplane": np.cross(e, [1.0, 0.0, 0.0])}
        dx = {"bending": np.array([0.0, 0.0, 1.0]), "torsion": np.zeros(3), "inplane": np.array([1.0, 0.0, 0.0])}
        f = np.array([_mode_shape(m, x, x_ref, L) for m in self.wing.modes]).reshape(-1, 2)
        return (f[:, 0], f[:, 1], np.array([ax[m.kind] for m in self.wing.modes]).reshape(-1, 3),
                np.array([dx[m.kind] for m in self.wing.modes]).reshape(-1, 3))

    def deformation(self, t_s: ArrayLike, span_m: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Flexure at span ``span_m`` and times t, in master body axes (FLU):
        rotation vector ``theta`` (M, 3) [rad] and its rate (M, 3), displacement ``d`` (M, 3) [m]
        of the wing's elastic axis and its rate (M, 3) [m/s]."""
        q, qd = self.modal(t_s)
        ang, dis, ax, dx = self._shapes(span_m)
        th, thd = (q * ang) @ ax, (qd * ang) @ ax
        d, dd = (q * dis) @ dx, (qd * dis) @ dx
        if self.load is not None and self.wing.tip_deflection_per_g_m != 0.0:
            L = self.wing.semi_span_m
            S, dS = static_shape(min(abs(span_m) / L, 1.0))
            n1, n1d = self.load(np.asarray(t_s, dtype=float).reshape(-1))
            k = self.wing.tip_deflection_per_g_m
            axis = np.cross([0.0, -float(self.side), 0.0], [0.0, 0.0, 1.0])
            th = th + (k * dS / L * n1)[:, None] * axis
            thd = thd + (k * dS / L * n1d)[:, None] * axis
            d = d + np.outer(k * S * n1, [0.0, 0.0, 1.0])
            dd = dd + np.outer(k * S * n1d, [0.0, 0.0, 1.0])
        return th, thd, d, dd

    def at(self, t_s: ArrayLike, span_m: float | None = None) -> tuple[FloatArray, FloatArray]:
        """Rotation vector and rate (M, 3) at span (default: the reference span), master body axes
        (what :meth:`FlexureRealization.at` gives, for the oracle's truth)."""
        th, thd, _, _ = self.deformation(t_s, self.side * self.wing.reference_span_m if span_m is None else span_m)
        return th, thd


def _hermite(t_s: ArrayLike, t0_s: float, dt_s: float, y: FloatArray, yd: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Cubic Hermite interpolation of nodes ``y`` (N, K) with slopes ``yd`` (N, K): values and derivatives (M, K)."""
    t = np.asarray(t_s, dtype=float).reshape(-1)
    u = (t - t0_s) / dt_s
    k = np.clip(np.floor(u).astype(int), 0, y.shape[0] - 2)
    s = (u - k)[:, None]
    h = dt_s
    y0, y1, d0, d1 = y[k], y[k + 1], yd[k], yd[k + 1]
    s2, s3 = s * s, s * s * s
    v = (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * d0 + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * d1
    dv = ((6 * s2 - 6 * s) * y0 + (3 * s2 - 4 * s + 1) * h * d0 + (-6 * s2 + 6 * s) * y1 + (3 * s2 - 2 * s) * h * d1) / h
    return v, dv
