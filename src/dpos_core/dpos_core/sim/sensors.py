"""The simulator's sensors: per-run errors and noisy outputs drawn from the datasheet models of
:mod:`dpos_core.config.sensors`, as in the papers' simulations plus what real units add.

Per run (:func:`draw_biases`, :func:`draw_axes_errors`): a turn-on bias per axis from
N(0, bias^2); a scale factor per axis from N(0, scale^2) and six misalignment terms from
N(0, misalignment^2) (``M = I + diag(s) + offdiag(m)``, the measured rate ``M w``).  Per sample
(:func:`measure`): white noise of ``noise`` on every sample plus ``ARW / sqrt(dt)``; the in-run
bias variation as a first-order Gauss-Markov process (steady-state sigma ``bias_instability``,
correlation time ``bias_tau_s``) added to the turn-on bias.

Terms that are zero in the model draw nothing, so the papers' scenarios (bias + white noise only)
produce the same samples as before these terms existed.
"""

from __future__ import annotations

import numpy as np

from ..config.sensors import ImuErrorModel
from ..units import DEG, DEG_PER_H, UG_MPS2, FloatArray
from .ar1 import ar1

_OFFDIAG = ~np.eye(3, dtype=bool)


def draw_biases(model: ImuErrorModel, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """Per-run constant biases ``(gyro_radps (3,), accel_mps2 (3,))``."""
    return (rng.normal(0.0, model.gyro_bias_deg_h * DEG_PER_H, 3),
            rng.normal(0.0, model.accel_bias_ug * UG_MPS2, 3))


def draw_axes_errors(model: ImuErrorModel, rng: np.random.Generator) -> tuple[FloatArray, FloatArray] | None:
    """Per-run axis matrices ``(M_gyro (3, 3), M_accel (3, 3))`` = I + scale factors on the
    diagonal + misalignments off it; None when the model has neither (nothing drawn)."""
    if not (model.gyro_scale_ppm or model.gyro_misalignment_mrad or model.accel_scale_ppm or model.accel_misalignment_mrad):
        return None
    out = []
    for scale_ppm, mis_mrad in ((model.gyro_scale_ppm, model.gyro_misalignment_mrad),
                                (model.accel_scale_ppm, model.accel_misalignment_mrad)):
        M = np.eye(3) + np.diag(rng.normal(0.0, scale_ppm * 1e-6, 3))
        M[_OFFDIAG] += rng.normal(0.0, mis_mrad * 1e-3, 6)
        out.append(M)
    return out[0], out[1]


def _gauss_markov(sigma: float, tau_s: float, dt: FloatArray, rng: np.random.Generator) -> FloatArray:
    """(N, 3) first-order Gauss-Markov samples, stationary start, steady-state 1 sigma ``sigma``
    (mean step for the correlation: the jitter of real intervals is far below tau)."""
    n = dt.shape[0]
    a = float(np.exp(-float(np.mean(dt)) / tau_s))
    w = rng.normal(0.0, sigma * np.sqrt(1.0 - a * a), (n, 3))
    x0 = rng.normal(0.0, sigma, 3)
    return ar1(w, a, x0)


def measure(
    model: ImuErrorModel,
    dtheta_rad: FloatArray,
    dvel_mps: FloatArray,
    dt_s: FloatArray,
    biases: tuple[FloatArray, FloatArray],
    rng: np.random.Generator,
    axes: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Measured mean angular rate and specific force (N, 3) from ideal increments (N, 3) over the
    sample intervals ``dt_s`` (N,): ``M (ideal) + bias + in-run bias + white noise`` (module docstring)."""
    dt = np.asarray(dt_s, dtype=float).reshape(-1, 1)
    n = dtheta_rad.shape[0]
    om_true, f_true = dtheta_rad / dt, dvel_mps / dt
    if axes is not None:
        om_true, f_true = om_true @ axes[0].T, f_true @ axes[1].T
    g_sig: float | FloatArray = model.gyro_noise_deg_h * DEG_PER_H
    a_sig: float | FloatArray = model.accel_noise_ug * UG_MPS2
    if model.gyro_arw_deg_rth:
        g_sig = np.hypot(g_sig, model.gyro_arw_deg_rth * DEG / 60.0 / np.sqrt(dt))
    if model.accel_vrw_mps_rth:
        a_sig = np.hypot(a_sig, model.accel_vrw_mps_rth / 60.0 / np.sqrt(dt))
    omega = om_true + biases[0] + rng.normal(0.0, 1.0, (n, 3)) * g_sig
    f = f_true + biases[1] + rng.normal(0.0, 1.0, (n, 3)) * a_sig
    if model.gyro_bias_instability_deg_h:
        omega = omega + _gauss_markov(model.gyro_bias_instability_deg_h * DEG_PER_H, model.gyro_bias_tau_s, dt[:, 0], rng)
    if model.accel_bias_instability_ug:
        f = f + _gauss_markov(model.accel_bias_instability_ug * UG_MPS2, model.accel_bias_tau_s, dt[:, 0], rng)
    return omega, f
