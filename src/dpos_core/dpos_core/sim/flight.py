"""Truth flight trajectories on the WGS-84 ellipsoid from a list of flight segments.

A flight is a start state and a list of segments; each segment lasts ``duration_s`` and may
change the heading (coordinated turn), the speed (acceleration) and the flight-path angle
(climb).  Every change is applied through a quintic smoothstep ramp of ``ramp_s`` seconds at the
start and end of the segment, so that turn rate, bank, flight-path angle, acceleration and body
rate are continuous (C^2 profiles): no step in attitude or acceleration at the joins.

Per segment with ``D = duration_s``, ``tau = ramp_s`` and the window ``w(t)`` (0 -> 1 over the
first ``tau``, 1, 1 -> 0 over the last ``tau``; ``int w = D - tau``):

* turn rate ``psi_dot = dpsi / (D - tau) w(t)``; speed rate ``V_dot = dV / (D - tau) w(t)``;
* flight-path angle ``gamma = gamma_max w(t)`` with ``sin(gamma_max) = climb_rate / V``;
* coordinated bank ``phi = atan(V psi_dot / g0)``, pitch = ``gamma`` + trim, no sideslip.

Heading, speed, angles and all their first derivatives are closed-form in time; the position is
integrated with RK4 on a fixed grid (error < 1e-9 m per 1000 s at 100 Hz for these profiles) and
interpolated with cubic Hermite polynomials.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import DEG, G0_MPS2, FloatArray

from .. import earth
from .._strapdown_kernel import rk4_llh
from ..frames import C_nb_from_hpr


@dataclass(frozen=True)
class Segment:
    """One flight segment.

    Attributes:
        duration_s: length of the segment.
        heading_change_deg: heading change by a coordinated turn (positive = right / clockwise).
        speed_change_mps: speed change (acceleration segment).
        climb_rate_mps: peak vertical speed (positive = climb); level at both ends.
        ramp_s: smoothstep ramp at each end (default: min(10 s, D / 4)).
        name: optional label (e.g. imaging segment ``AB``).
    """

    duration_s: float
    heading_change_deg: float = 0.0
    speed_change_mps: float = 0.0
    climb_rate_mps: float = 0.0
    ramp_s: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if not np.isfinite(self.duration_s) or self.duration_s <= 0.0:
            raise ValueError(f"segment {self.name!r}: duration_s must be > 0, got {self.duration_s}")
        for k in ("heading_change_deg", "speed_change_mps", "climb_rate_mps"):
            if not np.isfinite(getattr(self, k)):
                raise ValueError(f"segment {self.name!r}: {k} is not finite")
        if self.ramp_s is not None and not (0.0 < self.ramp_s <= 0.5 * self.duration_s):
            raise ValueError(f"segment {self.name!r}: ramp_s must be in (0, duration_s / 2], got {self.ramp_s}")

    @property
    def ramp(self) -> float:
        return self.ramp_s if self.ramp_s is not None else min(10.0, 0.25 * self.duration_s)


@dataclass(frozen=True)
class FlightStart:
    """Initial state (and constant trims) of a flight."""

    lat_deg: float
    lon_deg: float
    h_m: float
    speed_mps: float
    heading_deg: float
    pitch_trim_deg: float = 0.0
    roll_trim_deg: float = 0.0

    def __post_init__(self) -> None:
        if not -90.0 < self.lat_deg < 90.0:
            raise ValueError(f"start lat_deg must be in (-90, 90), got {self.lat_deg}")
        if not (np.isfinite(self.speed_mps) and self.speed_mps >= 0.0):
            raise ValueError(f"start speed_mps must be >= 0 (0: a standstill, e.g. a vehicle before it moves), got {self.speed_mps}")


# quintic smoothstep S(u) on [0, 1]: S, S', S'', and its integral
def _S(u: FloatArray) -> FloatArray:
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def _dS(u: FloatArray) -> FloatArray:
    return 30.0 * u * u * (1.0 - u) ** 2


def _iS(u: FloatArray) -> FloatArray:
    return u**4 * (2.5 - 3.0 * u + u * u)


@dataclass(frozen=True)
class Profiles:
    """Closed-form profiles at times t (shape (N,)): heading, speed, flight path, bank and rates [rad, m/s]."""

    heading: FloatArray
    heading_rate: FloatArray
    speed: FloatArray
    speed_rate: FloatArray
    gamma: FloatArray
    gamma_rate: FloatArray
    bank: FloatArray
    bank_rate: FloatArray


@dataclass
class Flight:
    """A truth trajectory from segments (see module docstring).

    Args:
        start: initial state.
        segments: the flight plan.
        grid_hz: rate of the RK4 position grid (the interpolation nodes).
    """

    start: FlightStart
    segments: list[Segment]
    grid_hz: float = 100.0
    _t_grid: FloatArray = field(init=False, repr=False)
    _llh_grid: FloatArray = field(init=False, repr=False)
    _llh_rate_grid: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError("a flight needs at least one segment")
        self._t0 = np.concatenate([[0.0], np.cumsum([s.duration_s for s in self.segments])])
        dpsi = np.array([s.heading_change_deg * DEG for s in self.segments])
        dv = np.array([s.speed_change_mps for s in self.segments])
        self._psi0 = self.start.heading_deg * DEG + np.concatenate([[0.0], np.cumsum(dpsi)])
        self._v0 = self.start.speed_mps + np.concatenate([[0.0], np.cumsum(dv)])
        if np.any(self._v0 < 0.0):
            raise ValueError("the speed changes make the speed negative")
        eff = np.array([s.duration_s - s.ramp for s in self.segments])
        self._rpsi = dpsi / eff
        self._rv = dv / eff
        climb = np.array([s.climb_rate_mps for s in self.segments])
        vmax = np.maximum(self._v0[:-1], self._v0[1:])
        if np.any((climb != 0.0) & (vmax == 0.0)):
            raise ValueError("climb_rate_mps needs a speed > 0 in the segment")
        sg = np.divide(climb, vmax, out=np.zeros_like(climb), where=vmax > 0.0)
        if np.any(np.abs(sg) >= 0.5):
            raise ValueError("climb_rate_mps gives a flight-path angle above 30 deg")
        self._gmax = np.arcsin(sg)
        self._integrate_position()

    @property
    def duration_s(self) -> float:
        return float(self._t0[-1])

    def segment_bounds(self, name: str) -> tuple[float, float]:
        """Start and end time [s] of the named segment."""
        for i, s in enumerate(self.segments):
            if s.name == name:
                return float(self._t0[i]), float(self._t0[i + 1])
        raise KeyError(f"no segment named {name!r}")

    def profiles(self, t_s: ArrayLike) -> Profiles:
        """Closed-form heading / speed / flight-path / bank profiles at times t (clamped to the flight)."""
        t = np.clip(np.asarray(t_s, dtype=float).reshape(-1), 0.0, self.duration_s)
        i = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self.segments) - 1)
        D = np.array([s.duration_s for s in self.segments])[i]
        tau = np.array([s.ramp for s in self.segments])[i]
        x = t - self._t0[i]
        # window per sample with its own segment's D and tau
        up = np.clip(x / tau, 0.0, 1.0)
        down = np.clip((x - (D - tau)) / tau, 0.0, 1.0)
        w = _S(up) - _S(down)
        dw = (_dS(up) - _dS(down)) / tau
        iw = tau * _iS(up) + np.clip(x - tau, 0.0, D - 2.0 * tau) + tau * (down - _iS(down))
        psi = self._psi0[i] + self._rpsi[i] * iw
        psi_dot = self._rpsi[i] * w
        psi_ddot = self._rpsi[i] * dw
        V = self._v0[i] + self._rv[i] * iw
        V_dot = self._rv[i] * w
        gamma = self._gmax[i] * w
        gamma_dot = self._gmax[i] * dw
        u = V * psi_dot / G0_MPS2
        bank = np.arctan(u)
        bank_dot = (V_dot * psi_dot + V * psi_ddot) / G0_MPS2 / (1.0 + u * u)
        return Profiles(psi, psi_dot, V, V_dot, gamma, gamma_dot, bank, bank_dot)

    def velocity_n(self, t_s: ArrayLike) -> FloatArray:
        """Velocity over the Earth in local ENU, shape (N, 3)."""
        p = self.profiles(t_s)
        cg = np.cos(p.gamma)
        return p.speed[:, None] * np.stack([cg * np.sin(p.heading), cg * np.cos(p.heading), np.sin(p.gamma)], axis=-1)

    def _integrate_position(self) -> None:
        n = int(np.ceil(self.duration_s * self.grid_hz))
        t = np.linspace(0.0, self.duration_s, n + 1)
        h = t[1] - t[0]
        v_nodes = self.velocity_n(t)
        v_mid = self.velocity_n(t[:-1] + 0.5 * h)
        llh0 = np.array([self.start.lat_deg * DEG, self.start.lon_deg * DEG, self.start.h_m])
        # RK4 (numba kernel); the velocity is closed-form, only its llh dependence is integrated
        llh = rk4_llh(v_nodes, v_mid, h, llh0)
        f = earth.llh_rate
        self._t_grid = t
        self._llh_grid = llh
        self._llh_rate_grid = f(llh[:, 0], llh[:, 2], v_nodes)

    def llh(self, t_s: ArrayLike) -> FloatArray:
        """Geodetic position ``[lat_rad, lon_rad, h_m]`` at times t, shape (N, 3) (cubic Hermite)."""
        t = np.clip(np.asarray(t_s, dtype=float).reshape(-1), 0.0, self.duration_s)
        tg = self._t_grid
        k = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, len(tg) - 2)
        h = tg[k + 1] - tg[k]
        s = ((t - tg[k]) / h)[:, None]
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2
        return (h00 * self._llh_grid[k] + h10 * h[:, None] * self._llh_rate_grid[k]
                + h01 * self._llh_grid[k + 1] + h11 * h[:, None] * self._llh_rate_grid[k + 1])

    def attitude(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(C_nb (N, 3, 3) of the FLU body, omega_nb_b_radps (N, 3))`` from the Euler profiles."""
        p = self.profiles(t_s)
        pitch = p.gamma + self.start.pitch_trim_deg * DEG
        roll = p.bank + self.start.roll_trim_deg * DEG
        C_nb = C_nb_from_hpr(p.heading, pitch, roll)
        # 3-2-1 Euler kinematics in FRD, then FRD -> FLU
        sp, cp = np.sin(pitch), np.cos(pitch)
        sr, cr = np.sin(roll), np.cos(roll)
        wx = p.bank_rate - p.heading_rate * sp
        wy = p.gamma_rate * cr + p.heading_rate * cp * sr
        wz = -p.gamma_rate * sr + p.heading_rate * cp * cr
        return C_nb, np.stack([wx, -wy, -wz], axis=-1)

    def ecef_motion(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(p_e (N,3), v_e (N,3), C_eb (N,3,3), omega_eb_b (N,3))`` of the master body frame."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        llh = self.llh(t)
        v_n = self.velocity_n(t)
        C_nb, w_nb = self.attitude(t)
        C_en = earth.C_en(llh[:, 0], llh[:, 1])
        w_en = earth.transport_rate_n(llh[:, 0], llh[:, 2], v_n)
        w_eb = w_nb + np.einsum("nji,nj->ni", C_nb, w_en)
        p_e = earth.geodetic_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2])
        return p_e, np.einsum("nij,nj->ni", C_en, v_n), C_en @ C_nb, w_eb
