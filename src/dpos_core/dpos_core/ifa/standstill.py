"""Standstill detection from the IMU (and the GNSS speed when there) and the level at the start.

**Test statistic.**  Over a window of W samples of rates ``w_k`` (3,) and specific forces ``f_k``
(3,), with the IMU model's white-noise 1 sigma per sample ``s_g``, ``s_a``
(:meth:`~dpos_core.config.sensors.ImuErrorModel.white_sigma`):

    T = ( sum_k |w_k - mean(w)|^2 / s_g^2 + sum_k |f_k - mean(f)|^2 / s_a^2 ) / (6 (W - 1))

At rest the samples are a constant (bias, earth rate, gravity: whatever their values) plus white
noise, so ``6 (W - 1) T`` is chi-square with ``6 (W - 1)`` degrees of freedom and ``T`` is about 1;
any motion (a turn, an acceleration, the vibration of a moving vehicle or of a gait) adds variance.
This is the variance form of the generalized likelihood-ratio detector of Skog et al. 2010 (SHOE)
with the mean removed, so an unknown turn-on bias (a MEMS gyro's 0.2 deg/s) does not hide the rest.
The window is at rest when ``T <= noise_factor^2 chi2.ppf(quantile, 6 (W - 1)) / (6 (W - 1))``
(``noise_factor``: a real unit at rest with an engine running is noisier than its datasheet), the
mean rate is below what the gyro bias and the earth can explain (``|mean(w)| <= 3 b_g + 7.3e-5
rad/s + 5 s_g / sqrt(W)``: a steady turn has no variance but a mean rate), the mean specific force
is gravity within ``3 x`` the accelerometer turn-on bias (+ 0.05 m/s^2) and, when a GNSS velocity is
given, its speed is below ``max_gnss_speed_mps``.  A steady linear acceleration without rotation
is indistinguishable from a tilt for the IMU (its variance is zero and ``|f|`` changes by only
``a^2 / 2g``): only the GNSS speed tells it from rest.

**Level at the start** (:func:`start_level`): at rest, pitch and roll from the mean specific force
(the tilt is then only the accelerometer bias's, ``asin(b / g)`` per axis; the level sigma is
``2 asin(b / g)``, the fine phase's level prior, ``IfaFilterConfig.fine_level_sigma_rad``).  In motion the mean specific
force is ``C_bn (a_n + g_up)``: levelling it raw tilts the result by ``|a_h| / g`` (a 2 m/s^2 turn:
11.5 deg).  The vehicle's acceleration ``a_n`` is taken from the GNSS velocities (the fix's minus
the previous fix's over their interval, at most 1.5 windows) and removed to first order (its pitch and roll as seen in
the heading frame subtracted); the level 1 sigma then says what is left: half the horizontal
acceleration (its change within the window) plus the velocity noise's ``sqrt(2) sigma_v / dt``,
over g.  Without a previous fix the acceleration is unknown: the level is the raw one with a 1 sigma
of ``atan(max(1 m/s^2, rms spread of f over the window, |mean(w)| |v|) / g)`` (5.8 deg at least).
The last term is the centripetal acceleration ``w x v`` of a turn, at most ``|w| |v|`` whatever the
heading: a coordinated turn (an aircraft banked at ``phi``) has no spread of ``f`` and no lateral
specific force, so the raw level is wings-level while the roll is ``phi = atan(|w| |v| / g)``
(thor_flight75 started at 450.7 s in a 41 deg bank: the raw level's roll -0.7 deg with the former
5.8 deg sigma; docs/ifa.md, "thor_flight75").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dpos_core.units import FloatArray

from ..chi2 import chi2_quantile
from ..config.sensors import ImuErrorModel
from ..series import GnssSeries, ImuSeries
from .mechanization import level_from_specific_force

#: standard gravity [m/s^2]
G0_MPS2 = 9.80665
#: micro-g in m/s^2
_UG = 1e-6 * G0_MPS2


@dataclass(frozen=True)
class StandstillTest:
    """The detector's answer for one window (module docstring): ``statistic`` T, ``threshold``,
    ``gravity_error_mps2`` (| |mean f| - g |), ``gnss_speed_mps`` (nan without one), ``at_rest``."""

    statistic: float
    threshold: float
    gravity_error_mps2: float
    gnss_speed_mps: float
    at_rest: bool


def standstill_statistic(omega_radps: FloatArray, f_mps2: FloatArray, sigma_g_radps: float, sigma_a_mps2: float) -> float:
    """T of the module docstring for a window of samples (W, 3), (W, 3), W >= 2 (about 1 at rest)."""
    w = np.asarray(omega_radps, dtype=float).reshape(-1, 3)
    f = np.asarray(f_mps2, dtype=float).reshape(-1, 3)
    n = w.shape[0]
    if n < 2 or f.shape[0] != n:
        raise ValueError(f"need W >= 2 samples of rates and specific forces, got {w.shape} and {f.shape}")
    s = np.sum((w - w.mean(axis=0)) ** 2) / sigma_g_radps**2 + np.sum((f - f.mean(axis=0)) ** 2) / sigma_a_mps2**2
    return float(s / (6.0 * (n - 1)))


def detect_standstill(omega_radps: FloatArray, f_mps2: FloatArray, imu: ImuErrorModel, dt_s: float,
                      gnss_vel_n_mps: FloatArray | None = None, noise_factor: float = 3.0, quantile: float = 0.999,
                      max_gnss_speed_mps: float = 0.2) -> StandstillTest:
    """Whether a window of IMU samples (W, 3), (W, 3) at interval ``dt_s`` is at rest (module
    docstring), with the GNSS velocity (3,) ENU of the window when there is one."""
    w = np.asarray(omega_radps, dtype=float).reshape(-1, 3)
    f = np.asarray(f_mps2, dtype=float).reshape(-1, 3)
    s_g, s_a = imu.white_sigma(dt_s)
    T = standstill_statistic(w, f, s_g, s_a)
    dof = 6 * (w.shape[0] - 1)
    thr = noise_factor**2 * chi2_quantile(quantile, dof) / dof
    g_err = abs(float(np.linalg.norm(f.mean(axis=0))) - G0_MPS2)
    speed = float(np.hypot(gnss_vel_n_mps[0], gnss_vel_n_mps[1])) if gnss_vel_n_mps is not None else float("nan")
    rate_max = 3.0 * imu.gyro_bias_deg_h * np.pi / 180.0 / 3600.0 + 7.2921e-5 + 5.0 * s_g / np.sqrt(w.shape[0])
    ok = (T <= thr and float(np.linalg.norm(w.mean(axis=0))) <= rate_max and g_err <= 3.0 * imu.accel_bias_ug * _UG + 0.05
          and not speed > max_gnss_speed_mps)
    return StandstillTest(T, thr, g_err, speed, bool(ok))


@dataclass(frozen=True)
class StartLevel:
    """Pitch and roll [rad] at the start, their 1 sigma [rad] (the filter's ``level_sigma_deg`` is
    widened to it, never narrowed), how they were found (``rest``, ``compensated``, ``raw``), and the
    standstill test of the window (None without an IMU model)."""

    pitch_rad: float
    roll_rad: float
    sigma_rad: float | None
    how: str
    standstill: StandstillTest | None


def start_level(imu: ImuSeries, gnss: GnssSeries, j: int, t_fix_s: float, heading_rad: float, window_s: float = 1.0,
                imu_model: ImuErrorModel | None = None) -> StartLevel:
    """The level at the start fix ``j`` (on the IMU's clock at ``t_fix_s``) from the IMU samples of
    the ``window_s`` before it (module docstring).  Without samples there: 0, 0 and a 90 deg sigma."""
    t = np.asarray(imu.t_s, dtype=float)
    win = (t > t_fix_s - window_s) & (t <= t_fix_s)
    if np.count_nonzero(win) < 2:
        return StartLevel(0.0, 0.0, np.pi / 2, "none", None)
    om, fb = np.asarray(imu.omega_radps)[win], np.asarray(imu.f_mps2)[win]
    f_mean = fb.mean(axis=0)
    pitch, roll = level_from_specific_force(f_mean)
    v = np.asarray(gnss.vel_n_mps[j], dtype=float)
    test = None
    if imu_model is not None:
        dt = float(np.median(np.diff(t[win]))) if np.count_nonzero(win) > 2 else float(window_s)
        test = detect_standstill(om, fb, imu_model, dt, v)
        if test.at_rest:  # the tilt the accelerometer bias leaves (IfaFilterConfig.fine_level_sigma_rad's 2 asin(b / g))
            return StartLevel(pitch, roll, 2.0 * float(np.arcsin(min(imu_model.accel_bias_ug * 1e-6, 0.5))), "rest", test)
    # in motion (or not known to be at rest): the vehicle's acceleration from the GNSS velocities
    if j >= 1:
        dt_g = float(gnss.t_s[j] - gnss.t_s[j - 1])
        if 0.0 < dt_g <= 1.5 * window_s + 1e-9:  # an acceleration over a longer span is not the window's
            a_n = (v - np.asarray(gnss.vel_n_mps[j - 1], dtype=float)) / dt_g
            sh, ch = np.sin(heading_rad), np.cos(heading_rad)
            # the acceleration in the heading frame (forward, left, up): ENU -> FLU by the heading alone
            a_h = np.array([sh * a_n[0] + ch * a_n[1], -ch * a_n[0] + sh * a_n[1], a_n[2]])
            p_a, r_a = level_from_specific_force(a_h + np.array([0.0, 0.0, G0_MPS2]))
            sv = np.asarray(gnss.vel_sigma_mps[j], dtype=float)
            sig = (0.5 * float(np.hypot(a_n[0], a_n[1])) + np.sqrt(2.0) * float(np.hypot(sv[0], sv[1])) / dt_g) / G0_MPS2
            return StartLevel(pitch - p_a, roll - r_a, float(np.arctan(sig)), "compensated", test)
    # raw: the acceleration is unknown; at least 1 m/s^2 of doubt, the window's own spread of f, or the
    # centripetal acceleration |w x v| <= |w| |v| of a turn (a coordinated turn leaves no trace in f)
    spread = float(np.sqrt(np.mean(np.sum((fb - f_mean) ** 2, axis=1))))
    centripetal = float(np.linalg.norm(om.mean(axis=0))) * float(np.linalg.norm(v))
    sig = max(spread, centripetal, 1.0) / G0_MPS2
    return StartLevel(pitch, roll, float(np.arctan(sig)), "raw", test)


__all__ = ["StandstillTest", "standstill_statistic", "detect_standstill", "StartLevel", "start_level", "G0_MPS2"]
