"""SINS/SAR/baro navigation of one session from its data ([Yan2016]): the product path of
sar_nav_node and ``dpos-sar``, the same model and filters as the evaluation (:mod:`dpos_core.evaluation.sar`).

Inputs, in session time ``t_s`` (seconds after the initial state's stamp):

* the main IMU samples (:class:`~dpos_core.series.ImuSeries`, each the mean over the interval
  ending at its stamp) and the initial state (:class:`~dpos_core.strapdown.NavState` at t = 0): the
  free SINS is their strapdown mechanization (open loop, as [Yan2016]);
* :class:`~dpos_core.series.SarFixes`: scene-matching fixes of latitude, longitude and heading with their 1 sigmas;
  a fix is used at the filter epoch within ``FIX_TOL_S`` of its stamp (the SINS is compared at the
  fix's instant), others are counted as off the filter grid and not used;
* :class:`~dpos_core.series.BaroSeries`: barometric heights; the filter uses the mean of the samples within half a
  filter step of each epoch (with the SINS's height at the same instants), and needs at least one
  per epoch.

:func:`navigate` builds the 16-state model (:class:`~.model.SarModel`) and runs one method of
:data:`~.pipeline.METHODS` with :class:`SarNavSettings`; the result is the corrected SINS at the
filter epochs with its covariances (and, for the particle filters, ESS, resampling, MH acceptance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import earth
from ..attitude import dcm_to_quat
from ..series import BaroSeries, ImuSeries, NavSeries, SarFixes  # (SarFixes, BaroSeries: exported here too)
from ..strapdown import NavState, Strapdown
from .model import DP, DV, N_STATES, SarMeasurements, SarModel, SarNoise, SinsTrack, corrected, heading_of
from .pipeline import METHODS, SarEstimate, run

ARCMIN = DEG / 60.0
#: a SAR fix is used at a filter epoch within this of its stamp [s]
FIX_TOL_S = 1e-6


@dataclass(frozen=True)
class SarNavSettings:
    """What a SINS/SAR run needs besides the data.

    method: one of :data:`~.pipeline.METHODS`; n_particles, seed, bandwidth_scale: the particle
    filters' (``bandwidth_scale`` x h_opt is the regularization kernel's bandwidth); filter_rate_hz:
    the filter epochs; prior 1 sigmas of the initial state's errors: position E, N, U [m], velocity
    E, N, U [m/s], attitude about E, N, U [arcmin]; gyro_bias_sigma_deg_h / accel_bias_sigma_ug: the
    turn-on bias 1 sigmas (prior and the biases' small random walk, :class:`~.model.SarNoise`);
    gyro_psd / accel_psd: the IMU's white-noise densities [rad^2/s], [m^2/s^3] (0 = not known yet:
    :func:`navigate` needs them > 0; sar_nav_node and dpos-sar take them from the Imu covariances)."""

    method: str = "ekf"
    n_particles: int = 1000
    seed: int = 0
    bandwidth_scale: float = 1.0
    filter_rate_hz: float = 1.0
    pos_sigma_m: tuple[float, float, float] = (10.0, 10.0, 15.0)
    vel_sigma_mps: tuple[float, float, float] = (0.8, 0.8, 0.8)
    att_sigma_arcmin: tuple[float, float, float] = (1.2, 1.2, 1.5)
    gyro_bias_sigma_deg_h: float = 0.1
    accel_bias_sigma_ug: float = 100.0
    gyro_psd: float = 0.0
    accel_psd: float = 0.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown SINS/SAR method {self.method!r}; choose from {', '.join(METHODS)}")
        if self.method not in ("ekf", "ukf") and self.n_particles < 2:
            raise ValueError(f"the particle filters need n_particles >= 2, got {self.n_particles}")
        for k in ("bandwidth_scale", "filter_rate_hz", "gyro_bias_sigma_deg_h", "accel_bias_sigma_ug"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"SarNavSettings.{k} must be > 0, got {v}")
        for k in ("pos_sigma_m", "vel_sigma_mps", "att_sigma_arcmin"):
            v = np.asarray(getattr(self, k), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v) & (v > 0)):
                raise ValueError(f"SarNavSettings.{k} must be 3 values > 0, got {getattr(self, k)}")


@dataclass
class SarNavResult:
    """The corrected SINS at the filter epochs: t_s (K,), llh (K, 3), vel_n_mps (K, 3), q_nb (K, 4)
    (body -> local ENU), covariances pos_cov, vel_cov, att_cov (K, 3, 3) in local ENU (attitude error
    about E, N, U [rad^2]); ``sar`` (K,) epochs with a SAR fix; ``estimate`` the filter's own output;
    ``fixes_off_grid``: fixes not on a filter epoch (not used)."""

    t_s: FloatArray
    llh: FloatArray
    vel_n_mps: FloatArray
    q_nb: FloatArray
    pos_cov: FloatArray
    vel_cov: FloatArray
    att_cov: FloatArray
    sar: np.ndarray
    estimate: SarEstimate
    fixes_off_grid: int = 0
    extra: dict[str, float] = field(default_factory=dict)


def free_sins(imu: ImuSeries, init: NavState) -> NavSeries:
    """The free SINS: ``init`` (at t = 0) then one state per IMU sample (the samples' means over
    their intervals integrated as increments)."""
    dt = np.diff(imu.t_s, prepend=init.t_s)[:, None]
    nav = Strapdown(init).run_increments(imu.t_s, imu.omega_radps * dt, imu.f_mps2 * dt)
    return NavSeries(np.r_[init.t_s, nav.t_s], np.vstack([init.q_nb, nav.q_nb]), np.vstack([init.vel_n_mps, nav.vel_n_mps]),
                     np.vstack([init.llh, nav.llh]))


def measurements(nav: NavSeries, track: SinsTrack, fixes: SarFixes, baro: BaroSeries, filter_rate_hz: float) -> tuple[SarMeasurements, int]:
    """The measurement vector at each epoch ([Yan2016] eq. 4): a SAR fix stamped at the epoch, and
    the mean of the barometer samples within half a filter step of it (the SINS's height at the same
    instants: the two averages share their timing), sigma / sqrt(count).  Returns the measurements
    and the number of fixes off the filter grid."""
    K = track.t_s.size
    y = np.full((K, 4), np.nan)
    sar = np.zeros(K, dtype=bool)
    fx_t = np.asarray(fixes.t_s, dtype=float)
    k_fix = np.rint(fx_t * filter_rate_hz).astype(int)
    on = (np.abs(k_fix / filter_rate_hz - fx_t) < FIX_TOL_S) & (k_fix >= 0) & (k_fix < K)
    k_fix, i_fix = k_fix[on], np.flatnonzero(on)
    sar[k_fix] = True
    y[k_fix, 0] = (heading_of(track.C_nb[k_fix]) - fixes.heading_rad[i_fix] + np.pi) % (2 * np.pi) - np.pi
    d = earth.dllh_to_enu(track.llh[k_fix] - fixes.llh[i_fix], fixes.llh[i_fix])
    y[k_fix, 1], y[k_fix, 2] = d[:, 1], d[:, 0]
    hs = np.full(K, np.nan)
    ps = np.full(K, np.nan)
    hs[k_fix] = np.broadcast_to(np.asarray(fixes.heading_sigma_rad, dtype=float), fx_t.shape)[i_fix]
    ps[k_fix] = np.broadcast_to(np.asarray(fixes.pos_sigma_m, dtype=float), fx_t.shape)[i_fix]
    b_t = np.asarray(baro.t_s, dtype=float)
    h_ins = np.interp(b_t, nav.t_s, nav.llh[:, 2])
    half = 0.5 / filter_rate_hz
    k_b = np.floor((b_t + half) * filter_rate_hz - 1e-9).astype(int)  # sample in (t_k - half, t_k + half]
    ok = (k_b >= 0) & (k_b < K)
    cnt = np.bincount(k_b[ok], minlength=K).astype(float)
    s = np.bincount(k_b[ok], weights=(h_ins - baro.h_m)[ok], minlength=K)
    var = np.bincount(k_b[ok], weights=np.broadcast_to(np.asarray(baro.sigma_m, dtype=float) ** 2, b_t.shape)[ok], minlength=K)
    if np.any(cnt == 0):
        k0 = int(np.flatnonzero(cnt == 0)[0])
        raise ValueError(f"the barometer must sample every filter step ({filter_rate_hz:g} Hz): none within half a step of "
                         f"t = {k0 / filter_rate_hz:g} s")
    y[:, 3] = s / cnt
    # one sigma each when they are all equal (the evaluation's SarMeasurements), else per epoch
    h_sig = float(hs[k_fix[0]]) if k_fix.size and np.all(hs[k_fix] == hs[k_fix[0]]) else hs
    p_sig = float(ps[k_fix[0]]) if k_fix.size and np.all(ps[k_fix] == ps[k_fix[0]]) else ps
    if not k_fix.size:
        h_sig, p_sig = 1.0, 1.0  # unused: no epoch has a fix
    return SarMeasurements(y, sar, h_sig, p_sig, np.sqrt(var) / cnt), int((~on).sum())


def prior(settings: SarNavSettings) -> tuple[FloatArray, FloatArray]:
    """The initial error state (zero, unit quaternion) and its covariance P0 (16, 16)."""
    x0 = np.zeros(N_STATES)
    x0[0] = 1.0
    P0 = np.zeros((N_STATES, N_STATES))
    att = np.asarray(settings.att_sigma_arcmin, dtype=float) * ARCMIN
    qv = (0.5 * att) ** 2
    P0[1:4, 1:4] = np.diag(qv)
    P0[0, 0] = 1e-6 * float(np.min(qv))
    P0[4:7, 4:7] = np.diag(np.asarray(settings.vel_sigma_mps, dtype=float) ** 2)
    P0[7:10, 7:10] = np.diag(np.asarray(settings.pos_sigma_m, dtype=float)[[1, 0, 2]] ** 2)
    P0[10:13, 10:13] = (settings.gyro_bias_sigma_deg_h * DEG_PER_H) ** 2 * np.eye(3)
    P0[13:16, 13:16] = (settings.accel_bias_sigma_ug * UG_MPS2) ** 2 * np.eye(3)
    return x0, P0


def navigate(imu: ImuSeries, init: NavState, fixes: SarFixes, baro: BaroSeries, settings: SarNavSettings) -> SarNavResult:
    """The SINS/SAR navigation of one session (module docstring)."""
    if imu.t_s.size < 2 or imu.t_s[0] <= init.t_s:
        raise ValueError("navigate: the IMU needs at least 2 samples after the initial state")
    nav = free_sins(imu, init)
    t_end = float(nav.t_s[-1])
    K = int(np.floor((t_end - init.t_s) * settings.filter_rate_hz + 1e-6)) + 1
    t = init.t_s + np.arange(K) / settings.filter_rate_hz
    track = SinsTrack.from_nav(nav, t)
    meas, off_grid = measurements(nav, track, fixes, baro, settings.filter_rate_hz)
    noise = SarNoise(settings.gyro_psd, settings.accel_psd, settings.gyro_bias_sigma_deg_h * DEG_PER_H,
                     settings.accel_bias_sigma_ug * UG_MPS2, max(t_end - init.t_s, 1.0))
    model = SarModel(track, meas, noise)
    x0, P0 = prior(settings)
    est = run(settings.method, model, x0, P0, n_particles=settings.n_particles, rng=np.random.default_rng(settings.seed),
              bandwidth_scale=settings.bandwidth_scale)
    C, v, llh = corrected(track, est.x)
    q = dcm_to_quat(C)
    # covariances in local ENU: position (N, E, U state order -> E, N, U), velocity, attitude error
    # (the quaternion's vector part is half the rotation about the SINS's local axes: 4 x its covariance)
    P = est.P
    pe = [DP.start + 1, DP.start, DP.start + 2]
    pos_cov = P[:, pe][:, :, pe]
    vel_cov = P[:, DV, DV]
    att_cov = 4.0 * P[:, 1:4, 1:4]
    extra: dict[str, float] = {}
    for k in ("ess", "accept", "distinct"):
        if k in est.extra:
            a = np.asarray(est.extra[k], dtype=float)
            a = a[np.isfinite(a)]
            if a.size:
                extra[f"mean_{k}"], extra[f"min_{k}"], extra[f"final_{k}"] = float(a.mean()), float(a.min()), float(a[-1])
    return SarNavResult(t, llh, v, q, pos_cov, vel_cov, att_cov, meas.sar.copy(), est, off_grid, extra)
