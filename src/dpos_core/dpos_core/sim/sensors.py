"""The simulator's sensors: per-run biases and noisy outputs drawn from the sensor models of
:mod:`dpos_core.config.sensors` (constant part once per run and axis from N(0, constant^2), random
part white noise on every output sample), as in the papers' simulations.
"""

from __future__ import annotations

import numpy as np

from ..config.sensors import ImuErrorModel
from ..units import DEG_PER_H, UG_MPS2, FloatArray


def draw_biases(model: ImuErrorModel, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """Per-run constant biases ``(gyro_radps (3,), accel_mps2 (3,))``."""
    return (rng.normal(0.0, model.gyro_bias_deg_h * DEG_PER_H, 3),
            rng.normal(0.0, model.accel_bias_ug * UG_MPS2, 3))


def measure(
    model: ImuErrorModel,
    dtheta_rad: FloatArray,
    dvel_mps: FloatArray,
    dt_s: FloatArray,
    biases: tuple[FloatArray, FloatArray],
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """Measured mean angular rate and specific force (N, 3) from ideal increments (N, 3)."""
    dt = np.asarray(dt_s, dtype=float).reshape(-1, 1)
    n = dtheta_rad.shape[0]
    omega = dtheta_rad / dt + biases[0] + rng.normal(0.0, model.gyro_noise_deg_h * DEG_PER_H, (n, 3))
    f = dvel_mps / dt + biases[1] + rng.normal(0.0, model.accel_noise_ug * UG_MPS2, (n, 3))
    return omega, f
