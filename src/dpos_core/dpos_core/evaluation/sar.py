"""Monte Carlo evaluation of the SINS/SAR filters on simulated sessions ([Yan2016] sec. 5,
``paper_sar``): the free SINS from the simulated main IMU with the scenario's initial errors, the
SAR and barometer measurements of :mod:`dpos_core.sim.sar`, every method on the same data, and
[Yan2016] Table 2's statistics - the mean absolute error (MAE) and standard deviation (STD) of the
attitude (pitch, roll, yaw) and position (longitude, latitude, altitude) errors over 100-1000 s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from dpos_core.units import DEG, DEG_PER_H, UG_MPS2, FloatArray

from .. import earth
from ..attitude import dcm_to_quat, quat_mul, rotvec_to_quat
from ..sar.model import N_STATES, Q_ATT, SarMeasurements, SarModel, SarNoise, SinsTrack, error_state, navigation_errors
from ..sar.navigate import free_sins
from ..sar.navigate import measurements as sar_measurements
from ..sar.pipeline import ORACLE, run
from ..sim.sar import baro_heights, sar_config, sar_fixes
from ..sim.session import SimulatedSession
from ..strapdown import NavState

#: [Yan2016]'s evaluation window [s]
WINDOW_S = (100.0, 1000.0)
#: the error components of [Yan2016] Table 2 (attitude in arcmin, position in m)
COMPONENTS = ("pitch", "roll", "yaw", "lon", "lat", "alt")
ARCMIN = DEG / 60.0
#: [Yan2016] sec. 5: the error ranges (min, max) over 100-1000 s read from its text (its Table 2's
#: MAE/STD values were lost in the extraction): attitude [arcmin] pitch, roll, yaw; position [m]
#: longitude, latitude, altitude (the classical PF's altitude range is printed as (34.74, 36.28))
PAPER_RANGES = {
    "pf": ((-1.01, 1.26), (-0.96, 1.12), (-2.09, 1.92), (-26.92, 24.42), (-30.08, 30.33), (34.74, 36.28)),
    "rpf": ((-0.71, 0.86), (-0.73, 0.76), (-1.17, 1.25), (-26.11, 18.57), (-21.98, 21.51), (-33.43, 32.57)),
    "mcmc_rpf": ((-0.40, 0.54), (-0.58, 0.53), (-0.78, 0.93), (-12.70, 12.93), (-17.39, 13.51), (-19.01, 20.69)),
}


@dataclass
class SarProblem:
    """One simulated run's filtering problem: the model, prior, the true error states (K, 16)
    and the truth at the epochs."""

    model: SarModel
    x0: FloatArray
    P0: FloatArray
    truth_x: FloatArray
    truth: object  # NavSeries at the epochs


def _initial_errors(ss: SimulatedSession) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The scenario's initial SINS errors ([Yan2016] sec. 5, the ``ifa`` block): position ENU [m],
    velocity ENU [m/s], attitude as a rotation vector about ENU [rad] (``C_nb_sins = exp(phi) C_nb``)."""
    d = ss.scenario.ifa
    pos = np.asarray(d.get("initial_position_error_m", [10.0, 10.0, 15.0]), dtype=float)
    vel = np.asarray(d.get("initial_velocity_error_mps", [0.8, 0.8, 0.8]), dtype=float)
    att = np.asarray(d.get("initial_attitude_error_arcmin", [1.2, 1.2, 1.5]), dtype=float) * ARCMIN
    for name, v in (("initial_position_error_m", pos), ("initial_velocity_error_mps", vel), ("initial_attitude_error_arcmin", att)):
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"scenario {ss.scenario.name}: ifa.{name} must be 3 finite numbers, got {v}")
    return pos, vel, att


def noise_model(ss: SimulatedSession) -> SarNoise:
    """The filter's noise model from the scenario's main IMU (white noise on every sample, or
    ARW / VRW; turn-on biases)."""
    m, f_imu = ss.scenario.master_imu, ss.scenario.rates.master_imu_hz
    g = (m.gyro_noise_deg_h * DEG_PER_H) ** 2 / f_imu + (m.gyro_arw_deg_rth * DEG / 60.0) ** 2
    a = (m.accel_noise_ug * UG_MPS2) ** 2 / f_imu + (m.accel_vrw_mps_rth / 60.0) ** 2
    return SarNoise(g, a, m.gyro_bias_deg_h * DEG_PER_H, m.accel_bias_ug * UG_MPS2, ss.duration_s)


def problem(ss: SimulatedSession, filter_rate_hz: float = 1.0) -> SarProblem:
    """Simulate the run of a session (module docstring): SINS, measurements, model, prior, truth."""
    cfg = sar_config(ss)
    pos0, vel0, att0 = _initial_errors(ss)

    tr0 = ss.truth("master", np.array([0.0]))
    q0 = quat_mul(rotvec_to_quat(att0), tr0.q_nb[0])
    llh0 = tr0.llh[0] + earth.enu_to_dllh(pos0, tr0.llh[0])
    init = NavState(0.0, q0, tr0.vel_n_mps[0] + vel0, llh0)
    nav = free_sins(ss.master_imu(), init)  # each sample is the mean over its interval: increments
    t = np.arange(0.0, ss.duration_s + 1e-9, 1.0 / filter_rate_hz)
    track = SinsTrack.from_nav(nav, t)
    meas = measurements(ss, nav, track, cfg.baro_rate_hz, filter_rate_hz)
    truth = ss.truth("master", t)
    xt = error_state(track, truth, *ss.imu_biases("master"))
    x0 = np.zeros(N_STATES)
    x0[0] = 1.0
    noise = noise_model(ss)
    P0 = np.zeros((N_STATES, N_STATES))
    qv = (0.5 * att0) ** 2
    P0[1:4, 1:4] = np.diag(qv)
    P0[0, 0] = 1e-6 * float(np.min(qv))
    P0[4:7, 4:7] = np.diag(vel0**2)
    P0[7:10, 7:10] = np.diag(pos0[[1, 0, 2]] ** 2)
    P0[10:13, 10:13] = noise.gyro_bias_radps**2 * np.eye(3)
    P0[13:16, 13:16] = noise.accel_bias_mps2**2 * np.eye(3)
    return SarProblem(SarModel(track, meas, noise), x0, P0, xt, truth)


def measurements(ss: SimulatedSession, nav, track: SinsTrack, baro_rate_hz: float, filter_rate_hz: float) -> SarMeasurements:
    """The measurement vector at each epoch ([Yan2016] eq. 4) from the session's SAR fixes and
    barometer (:func:`.navigate.measurements`, the product path's own)."""
    return sar_measurements(nav, track, sar_fixes(ss), baro_heights(ss), filter_rate_hz)[0]


def errors(prob: SarProblem, x: FloatArray) -> FloatArray:
    """Navigation errors (K, 6) of estimated error states x (K, 16): pitch, roll, yaw [arcmin],
    longitude, latitude, altitude [m] (:func:`~.model.navigation_errors`)."""
    att, pos = navigation_errors(prob.model.track, x, prob.truth)  # type: ignore[arg-type]
    return np.hstack([att / ARCMIN, pos])


def table_stats(t_s: FloatArray, err: FloatArray, window: tuple[float, float] = WINDOW_S) -> dict[str, dict[str, float]]:
    """[Yan2016] Table 2's statistics of errors (K, 6) over the window: per component MAE, STD,
    min and max."""
    sel = (t_s >= window[0]) & (t_s <= window[1])
    e = err[sel]
    return {c: {"mae": float(np.mean(np.abs(e[:, i]))), "std": float(np.std(e[:, i])), "min": float(np.min(e[:, i])),
                "max": float(np.max(e[:, i]))} for i, c in enumerate(COMPONENTS)}


def run_methods(prob: SarProblem, methods: list[str], n_particles: int, seed: int, bandwidth_scale: float = 1.0) -> dict[str, dict]:
    """Every method on one problem: per method ``stats`` (table_stats), ``err`` (K, 6), ``seconds``
    and, for the particle filters, ``ess`` (K,), ``accept`` (K,) and ``resampled`` (K,)."""
    out: dict[str, dict] = {}
    t = prob.model.track.t_s
    for i, m in enumerate(methods):
        t0 = time.process_time()
        est = run(m, prob.model, prob.x0, prob.P0, n_particles=n_particles, rng=np.random.default_rng([seed, i, n_particles]),
                  truth_x=prob.truth_x if m == ORACLE else None, bandwidth_scale=bandwidth_scale)
        sec = time.process_time() - t0
        e = errors(prob, est.x)
        out[m] = {"stats": table_stats(t, e), "err": e, "seconds": sec, **est.extra}
    return out


def truth_errors(prob: SarProblem) -> FloatArray:
    """The free SINS's own errors (K, 6) (no filter): the problem's scale."""
    x = np.zeros_like(prob.truth_x)
    x[:, Q_ATT] = np.array([1.0, 0.0, 0.0, 0.0])
    return errors(prob, x)


__all__ = ["COMPONENTS", "PAPER_RANGES", "SarProblem", "WINDOW_S", "errors", "problem", "run_methods", "table_stats", "dcm_to_quat"]
