"""Sensor error models of the simulator: IMUs, GNSS, and the main system's navigation output.

The seeds specify sensor errors as a "constant" and a "random" part ([Gong2018] sec. 4.1.2:
gyro 0.01 deg/h + 0.01 deg/h, accelerometer 50 ug + 50 ug).  Here the constant part is drawn
once per run and axis from N(0, constant^2) and the random part is white noise with that
standard deviation on every output sample (the mean rate / specific force over the sample
interval), as in the papers' simulations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
DEG = np.pi / 180.0
DEG_PER_H = DEG / 3600.0
UG_MPS2 = 9.80665e-6


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

    def draw_biases(self, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
        """Per-run constant biases ``(gyro_radps (3,), accel_mps2 (3,))``."""
        return (rng.normal(0.0, self.gyro_bias_deg_h * DEG_PER_H, 3),
                rng.normal(0.0, self.accel_bias_ug * UG_MPS2, 3))

    def measure(
        self,
        dtheta_rad: FloatArray,
        dvel_mps: FloatArray,
        dt_s: FloatArray,
        biases: tuple[FloatArray, FloatArray],
        rng: np.random.Generator,
    ) -> tuple[FloatArray, FloatArray]:
        """Measured mean angular rate and specific force (N, 3) from ideal increments (N, 3)."""
        dt = np.asarray(dt_s, dtype=float).reshape(-1, 1)
        n = dtheta_rad.shape[0]
        omega = dtheta_rad / dt + biases[0] + rng.normal(0.0, self.gyro_noise_deg_h * DEG_PER_H, (n, 3))
        f = dvel_mps / dt + biases[1] + rng.normal(0.0, self.accel_noise_ug * UG_MPS2, (n, 3))
        return omega, f


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
