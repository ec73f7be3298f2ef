"""A simulated installation for the import tests: a main navigation solution that manoeuvres and a
sub-IMU on its own clock (offset, drift) at a known mounting. Rates are exact interval means."""

from __future__ import annotations

import numpy as np

from dpos_core.attitude import dcm_to_rotvec, mount_dcm
from dpos_core.frames import C_nb_from_hpr
from dpos_core.units import DEG


def hpr(t_s: np.ndarray, manoeuvre: bool = True) -> np.ndarray:
    """(N, 3) heading, pitch, roll [rad]: turns and pitch/roll wobbles at unrelated periods (none: level, straight)."""
    t = np.asarray(t_s, dtype=float)
    if not manoeuvre:
        z = np.zeros_like(t)
        return np.column_stack([z + 1.0, z, z])
    h = 1.0 + 0.5 * np.sin(2 * np.pi * t / 37.0) + 0.2 * np.sin(2 * np.pi * t / 11.3)
    p = 8 * DEG * np.sin(2 * np.pi * t / 7.1) + 3 * DEG * np.sin(2 * np.pi * t / 2.3)
    r = 12 * DEG * np.sin(2 * np.pi * t / 5.3 + 0.4) + 4 * DEG * np.sin(2 * np.pi * t / 1.7)
    return np.column_stack([h, p, r])


def C_nb(t_s: np.ndarray, manoeuvre: bool = True) -> np.ndarray:
    a = hpr(t_s, manoeuvre)
    return C_nb_from_hpr(a[:, 0], a[:, 1], a[:, 2])


def sub_rates(t_true_s: np.ndarray, dt_s: float, mount_rpy_deg: tuple[float, float, float], manoeuvre: bool = True,
              bias_dps: tuple[float, float, float] = (0.0, 0.0, 0.0), noise_dps: float = 0.0, seed: int = 0) -> np.ndarray:
    """Sub-IMU rates (N, 3) [rad/s]: the body rate's mean over (t - dt, t] in the sub-IMU axes
    (``omega_s = C_bs^T omega_b``), plus a bias and white noise."""
    Ca, Cb = C_nb(t_true_s - dt_s, manoeuvre), C_nb(t_true_s, manoeuvre)
    w_b = dcm_to_rotvec(np.einsum("nji,njk->nik", Ca, Cb)) / dt_s
    C_bs = mount_dcm(mount_rpy_deg, (0.0, 0.0, 0.0))
    w_s = w_b @ C_bs  # C_bs^T w_b, row-wise
    rng = np.random.default_rng(seed)
    return w_s + np.asarray(bias_dps) * DEG + rng.normal(0.0, noise_dps * DEG, w_s.shape)
