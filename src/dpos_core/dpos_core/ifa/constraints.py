"""Measurements of the main POS besides the GNSS: zero velocity (ZUPT) and zero angular rate (ZARU)
at rest, the non-holonomic constraint (NHC) of a ground vehicle in motion (#31 part 2).

Each builder returns ``(y (m,), h: (..., n) -> (..., m), R (m, m))`` in the error-state convention
of :mod:`.model` (``y = h(x) + v``, errors = computed - true), so that the filters apply them with
the same update as a GNSS fix (DD2 / ADD2: :func:`~dpos_core.filters.dd2.dd2_update`; AEKF: an EKF
update), sequentially after the fix's, with the nominal R (no adaptation).  ``E = expm([phi x])``
and ``C_true = E C_est`` (:mod:`.model`).

* **ZUPT** (Skog et al. 2010; Groves 2013 sec. 15.3): at rest the IMU's velocity over the earth is
  zero: ``y = v_INS = dv + v``, ``R = sigma_zupt^2 I + C_est diag(s_v^2) C_est^T``
  (``IfaFilterConfig.zupt_sigma_mps``, mm/s, plus the spread ``s_v`` per IMU axis of the velocity
  the window's own specific force says the unit moves by, ``cumsum((f - mean f) dt)``: the
  vibration of a running engine, the sway of a hand).
* **ZARU** (Groves 2013 sec. 15.3.2): at rest the gyros see the earth rate alone, so the mean
  bias-compensated rate of the window ``w_bar`` minus the computed earth rate in IMU axes is the
  remaining gyro bias plus the attitude error's share of the earth rate,
  ``w_bar - C_est^T w_ie^n = eps + C_est^T (E^T - I) w_ie^n + v``.  Only its vertical component in
  the navigation frame is used: ``y = (C_est w_bar - w_ie^n)_U = (C_est eps + (E^T - I) w_ie^n)_U``.
  The horizontal components tell the level gyro biases, which the ZUPT already sees through the
  tilt they drive, and the same tilt drift again: used as well, the two (in a divided-difference
  filter with a heading still uncertain by tens of degrees) made the filter find heading
  information at rest that is not there (mems_vehicle: attitude NEES 13 against 3, the outage's
  error doubled); the vertical component, the heading axis's bias that nothing else observes at rest,
  holds no heading error (a rotation about Up leaves the vertical earth rate as it is).  Its noise
  is the window mean's: ``u^T C_est diag(max(s^2, s_g^2) / W) C_est^T u`` (u = Up) with ``s^2``
  the samples' own variance per axis over the window (the vibration of a running engine, which
  the datasheet's white noise ``s_g`` does not hold) and W samples.
* **NHC** (Sukkarieh 2000; Groves 2013 sec. 15.4): a wheeled vehicle neither slips sideways nor
  leaves the road: the body velocity's lateral and vertical components (FLU ``y``, ``z``) are zero
  within ``sigma_nhc`` (side slip, suspension, an IMU not at the rear axle):
  ``y = (C_est^T v_INS)_{y,z}``, ``h(x) = (C_est^T v_INS - C_est^T E^T (v_INS - dv))_{y,z}``.
  Requires the IMU's axes to be the vehicle's (the installation's input rotation).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dpos_core.units import FloatArray

from ..attitude import rotvec_to_dcm

Measurement = tuple[FloatArray, Callable[[FloatArray], FloatArray], FloatArray]

# 15-state slices of the extended layout (as dpos_core.ifa.model)
_DV, _PHI, _EPS = slice(3, 6), slice(6, 9), slice(9, 12)


def zupt(vel_n_mps: FloatArray, sigma_mps: float, full: Callable[[FloatArray], FloatArray],
         f_mps2: FloatArray | None = None, dt_s: float = 0.0, C_nb: FloatArray | None = None) -> Measurement:
    """Zero velocity: the nominal IMU velocity (3,) ENU [m/s] observed as ``dv`` (module docstring);
    ``full`` maps states (..., n) to the extended (..., 24) layout (:meth:`.model.IfaModel.full`).
    With the window's specific forces ``f_mps2`` (W, 3), their interval ``dt_s`` and the attitude
    ``C_nb`` (3, 3), R adds the spread of the velocity they integrate to."""
    y = np.asarray(vel_n_mps, dtype=float).reshape(3).copy()
    R = np.eye(3) * float(sigma_mps) ** 2
    if f_mps2 is not None and C_nb is not None:
        fb = np.asarray(f_mps2, dtype=float).reshape(-1, 3)
        v = np.cumsum((fb - fb.mean(axis=0)) * dt_s, axis=0)
        C = np.asarray(C_nb, dtype=float)
        R = R + (C * v.var(axis=0)) @ C.T

    def h(x: FloatArray) -> FloatArray:
        return full(np.asarray(x, dtype=float))[..., _DV]

    return y, h, R


def zaru(omega_radps: FloatArray, gyro_bias_comp_radps: FloatArray, C_nb: FloatArray, w_ie_n_radps: FloatArray,
         sigma_g_radps: float, full: Callable[[FloatArray], FloatArray]) -> Measurement:
    """Zero angular rate about the vertical: the window's raw rates (W, 3) [rad/s] minus the
    compensation (3,), through the computed attitude ``C_nb`` (3, 3), against the earth rate
    ``w_ie_n`` (3,) ENU; the samples' white noise 1 sigma ``sigma_g_radps`` is the floor of the
    noise (module docstring).  One row."""
    w = np.asarray(omega_radps, dtype=float).reshape(-1, 3)
    if w.shape[0] < 2:
        raise ValueError(f"ZARU needs a window of W >= 2 samples, got {w.shape}")
    C = np.asarray(C_nb, dtype=float)
    wie = np.asarray(w_ie_n_radps, dtype=float).reshape(3)
    y = np.array([(C @ (w.mean(axis=0) - np.asarray(gyro_bias_comp_radps, dtype=float)) - wie)[2]])
    var = np.maximum(w.var(axis=0, ddof=1), sigma_g_radps**2) / w.shape[0]
    u = C[2]  # the Up row of C: (C v)_U = u . v

    def h(x: FloatArray) -> FloatArray:
        X = full(np.asarray(x, dtype=float))
        E = rotvec_to_dcm(X[..., _PHI])
        d = np.einsum("...ji,j->...i", E, wie) - wie  # (E^T - I) w_ie (..., 3)
        return (X[..., _EPS] @ u + d[..., 2])[..., None]

    return y, h, np.array([[float(np.sum(u**2 * var))]])


def nhc(vel_n_mps: FloatArray, C_nb: FloatArray, sigma_mps: float, full: Callable[[FloatArray], FloatArray]) -> Measurement:
    """Non-holonomic constraint: the lateral and vertical body velocity (FLU y, z) of the nominal
    velocity (3,) ENU and attitude ``C_nb`` (3, 3) observed as zero within ``sigma_mps`` (module
    docstring)."""
    v = np.asarray(vel_n_mps, dtype=float).reshape(3)
    C = np.asarray(C_nb, dtype=float)
    vb = C.T @ v
    y = vb[1:3].copy()

    def h(x: FloatArray) -> FloatArray:
        X = full(np.asarray(x, dtype=float))
        E = rotvec_to_dcm(X[..., _PHI])
        v_true = v - X[..., _DV]
        vb_true = np.einsum("...ji,...j->...i", E, v_true) @ C  # C^T E^T v_true
        return (vb - vb_true)[..., 1:3]

    return y, h, np.eye(2) * float(sigma_mps) ** 2


__all__ = ["zupt", "zaru", "nhc", "Measurement"]
