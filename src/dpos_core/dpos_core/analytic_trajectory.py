"""A closed-form flight for testing the mechanization: a steady coordinated turn with a
sinusoidal climb/descent, written in the Earth-fixed Cartesian ENU frame ``w`` at a datum.

Position, velocity, acceleration, attitude and body rate are all closed-form functions of time,
so the ideal IMU outputs (:mod:`dpos_core.kinematics`) and the navigation truth are exact to
rounding.  In ``w``:

* heading ``psi(t) = psi0 + r t`` with the coordinated-turn rate ``r = g tan(bank) / V``;
* ``p_E = -V/r (cos psi - cos psi0)``, ``p_N = V/r (sin psi - sin psi0)``, ``p_U = A sin(W t)``;
* pitch = flight-path angle ``atan(v_U / V)``, roll = bank (constant);
* body rate from the 3-2-1 Euler-angle kinematics.

The attitude is coordinated in ``w``; relative to the local level frame it differs by the small
angle between ``w`` and the local vertical (< 0.01 rad over 60 km), which does not matter for
a mechanization test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from dpos_core.units import FloatArray

from .earth import C_en, geodetic_to_ecef, normal_gravity
from .frames import C_nb_from_hpr
from .kinematics import imu_from_ecef_kinematics, nav_from_ecef


@dataclass(frozen=True)
class CoordinatedTurnClimb:
    """Closed-form turning, climbing flight.

    Attributes:
        datum_llh: ``[lat_rad, lon_rad, h_m]`` of the start point (and of the frame ``w``).
        speed_mps: horizontal speed V.
        bank_rad: constant bank angle (positive = right turn).
        heading0_rad: initial aviation heading.
        climb_amp_m: amplitude A of the sinusoidal height profile.
        climb_period_s: its period (W = 2 pi / period).
    """

    datum_llh: tuple[float, float, float] = (np.deg2rad(40.0), np.deg2rad(116.0), 500.0)
    speed_mps: float = 100.0
    bank_rad: float = np.deg2rad(30.0)
    heading0_rad: float = np.deg2rad(40.0)
    climb_amp_m: float = 150.0
    climb_period_s: float = 120.0

    @property
    def turn_rate_radps(self) -> float:
        g = float(normal_gravity(self.datum_llh[0], self.datum_llh[2]))
        return g * np.tan(self.bank_rad) / self.speed_mps

    def ecef_kinematics(
        self, t_s: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(p_e (N,3), v_e (N,3), a_e (N,3), C_eb (N,3,3), omega_eb_b (N,3))`` for an FLU body."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        V, r = self.speed_mps, self.turn_rate_radps
        W = 2.0 * np.pi / self.climb_period_s
        A = self.climb_amp_m
        psi = self.heading0_rad + r * t
        sp, cp = np.sin(psi), np.cos(psi)
        s0, c0 = np.sin(self.heading0_rad), np.cos(self.heading0_rad)
        p_w = np.stack([-V / r * (cp - c0), V / r * (sp - s0), A * np.sin(W * t)], axis=-1)
        vu = A * W * np.cos(W * t)
        au = -A * W * W * np.sin(W * t)
        v_w = np.stack([V * sp, V * cp, vu], axis=-1)
        a_w = np.stack([V * r * cp, -V * r * sp, au], axis=-1)
        theta = np.arctan2(vu, V)
        theta_dot = V * au / (V * V + vu * vu)
        phi = np.full_like(t, self.bank_rad)
        C_wb = C_nb_from_hpr(psi, theta, phi)
        # 3-2-1 Euler kinematics (FRD body), roll rate zero; then FRD -> FLU
        p = -r * np.sin(theta)
        q = theta_dot * np.cos(phi) + r * np.sin(phi) * np.cos(theta)
        rr = -theta_dot * np.sin(phi) + r * np.cos(phi) * np.cos(theta)
        omega_wb_b = np.stack([p, -q, -rr], axis=-1)
        lat0, lon0, h0 = self.datum_llh
        C_ew = C_en(lat0, lon0)
        p_e = geodetic_to_ecef(lat0, lon0, h0) + p_w @ C_ew.T
        return p_e, v_w @ C_ew.T, a_w @ C_ew.T, C_ew @ C_wb, omega_wb_b

    def imu_rates(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Ideal ``(omega_ib_b_radps (N,3), f_b_mps2 (N,3))``."""
        p_e, v_e, a_e, C_eb, om = self.ecef_kinematics(t_s)
        return imu_from_ecef_kinematics(p_e, v_e, a_e, C_eb, om)

    def truth(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Navigation truth ``(llh (N,3), vel_n_mps (N,3), C_nb (N,3,3))``."""
        p_e, v_e, _, C_eb, _ = self.ecef_kinematics(t_s)
        return nav_from_ecef(p_e, v_e, C_eb)
