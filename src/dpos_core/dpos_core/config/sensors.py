"""Sensor models in datasheet units: IMU errors, GNSS, and the main system's navigation output.

The papers specify sensor errors as a "constant" and a "random" part ([Gong2018] sec. 4.1.2:
gyro 0.01 deg/h + 0.01 deg/h, accelerometer 50 ug + 50 ug): the constant part is a per-run bias
with that 1 sigma per axis, the random part white noise with that standard deviation on every
output sample (the mean rate / specific force over the sample interval).  The simulator draws
them (:mod:`dpos_core.sim.sensors`); the estimators take their statistics from here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..units import FloatArray


@dataclass(frozen=True)
class ImuErrorModel:
    """Gyro and accelerometer errors (1 sigma)."""

    gyro_bias_deg_h: float = 0.0
    gyro_noise_deg_h: float = 0.0
    accel_bias_ug: float = 0.0
    accel_noise_ug: float = 0.0

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"IMU error model: {k} must be finite and >= 0, got {v}")


@dataclass(frozen=True)
class NoiseInterval:
    """GNSS noise scaling (``scale`` x nominal sigma) or outage (``outage``) over [t_start, t_end)."""

    t_start_s: float
    t_end_s: float
    scale: float = 1.0
    outage: bool = False

    def __post_init__(self) -> None:
        if not self.t_end_s > self.t_start_s:
            raise ValueError(f"GNSS interval: t_end_s {self.t_end_s} must be after t_start_s {self.t_start_s}")
        if not self.scale > 0:
            raise ValueError(f"GNSS interval: scale must be > 0, got {self.scale}")


@dataclass(frozen=True)
class GnssModel:
    """GNSS position / velocity at the antenna.

    Attributes:
        rate_hz: fix rate.
        pos_sigma_m: (E, N, U) 1 sigma of the position noise.
        vel_sigma_mps: (E, N, U) 1 sigma of the velocity noise.
        schedule: noise changes and outages over time.
    """

    rate_hz: float = 1.0
    pos_sigma_m: tuple[float, float, float] = (1.5, 1.5, 1.5)
    vel_sigma_mps: tuple[float, float, float] = (0.03, 0.03, 0.03)
    schedule: tuple[NoiseInterval, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"GNSS rate_hz must be > 0, got {self.rate_hz}")
        if any(s <= 0 for s in (*self.pos_sigma_m, *self.vel_sigma_mps)):
            raise ValueError("GNSS sigmas must be > 0 (a zero covariance is not a measurement)")

    def scale_at(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Noise scale (N,) and availability mask (N,) at times t."""
        t = np.asarray(t_s, dtype=float)
        scale = np.ones_like(t)
        ok = np.ones(t.shape, dtype=bool)
        for iv in self.schedule:
            inside = (t >= iv.t_start_s) & (t < iv.t_end_s)
            if iv.outage:
                ok &= ~inside
            else:
                scale = np.where(inside, iv.scale, scale)
        return scale, ok


@dataclass(frozen=True)
class NavNoiseModel:
    """Main-system navigation output = truth + white noise (``alignment: reference``, [Gong2018])."""

    heading_deg: float = 0.005
    pitch_deg: float = 0.0025
    roll_deg: float = 0.0025
    vel_mps: float = 0.005
    pos_m: float = 0.0
