"""SINS/SAR/baro navigation of a session's messages ([Yan2016], docs/sar.md): what sar_nav_node runs
when its session ends and ``dpos-sar`` runs on a recording - the same decoding, the same core call
(:func:`dpos_core.sar.navigate.navigate`).

Inputs (design.md "Topics"): ``/master/imu`` (the free SINS's samples; their covariances give the
white-noise densities), the first ``/master/nav`` (the initial state; its stamp is t = 0),
``/sar/fix`` (PoseWithCovarianceStamped in ``enu``), ``/baro/pressure`` (FluidPressure, ISA pressure
altitude + ``baro_height_offset_m`` = ellipsoidal height) and the ``enu`` datum.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dpos_core import earth
from dpos_core.attitude import quat_to_dcm
from dpos_core.errors import SarInputError
from dpos_core.frames import hpr_from_C_nb
from dpos_core.sar.navigate import BaroSeries, SarFixes, SarNavResult, SarNavSettings, navigate
from dpos_core.series import ImuSeries
from dpos_core.strapdown import NavState
from dpos_core.units import DEG, FloatArray
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T

#: the topics a SINS/SAR run needs (the datum: /dpos/datum or the datum parameter)
INPUT_TOPICS = (T.MASTER_IMU, T.MASTER_NAV, T.SAR_FIX, T.BARO_PRESSURE)


@dataclass
class SarInputs:
    """A session's data in the core's terms: origin_ns (t = 0, the initial state's stamp), the
    initial state, IMU, fixes, barometer and the IMU's white-noise densities; counts of what was
    dropped (``dropped``: reason -> count)."""

    origin_ns: int
    init: NavState
    imu: ImuSeries
    fixes: SarFixes
    baro: BaroSeries
    gyro_psd: float
    accel_psd: float
    dropped: dict[str, int]


def session_inputs(imu: cv.ImuBlock, nav0: tuple[int, FloatArray], fixes: Sequence[cv.SarFix],
                   baro: Sequence[tuple[int, float, float]], datum_llh: FloatArray, baro_height_offset_m: float = 0.0) -> SarInputs:
    """Decoded messages -> :class:`SarInputs`.  ``nav0`` = (stamp, Odometry doubles) of the first
    /master/nav; IMU samples at or before it, non-finite values, fixes or heights without a positive
    variance and repeated stamps are dropped and counted.  :class:`SarInputError` when nothing usable
    is left of a stream."""
    dropped: dict[str, int] = {}

    def drop(reason: str, n: int) -> None:
        if n:
            dropped[reason] = dropped.get(reason, 0) + int(n)

    t0_ns, v0 = nav0
    blk = cv.odometry_from_values(np.array([t0_ns], dtype=np.int64), np.asarray(v0, dtype=float)[None], datum_llh)
    init = NavState(0.0, blk.q_nb[0], blk.vel_n_mps[0], blk.llh[0])
    t = np.asarray(imu.t_ns, dtype=np.int64)
    ok = (t > t0_ns) & np.isfinite(imu.omega_radps).all(axis=1) & np.isfinite(imu.f_mps2).all(axis=1)
    drop("imu_before_start", int((t <= t0_ns).sum()))
    drop("imu_not_finite", int((~ok & (t > t0_ns)).sum()))
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(t[idx], kind="stable")]
    uniq = np.r_[True, np.diff(t[idx]) > 0] if idx.size else np.zeros(0, dtype=bool)
    drop("imu_duplicate", int((~uniq).sum()))
    idx = idx[uniq]
    if idx.size < 2:
        raise SarInputError(f"fewer than 2 usable {T.MASTER_IMU} samples after the initial state ({T.MASTER_NAV} at {t0_ns} ns)")
    t_s = np.asarray((t[idx] - t0_ns) * 1e-9, dtype=float)
    dt = float(np.median(np.diff(np.r_[0.0, t_s])))
    gv, av = np.median(imu.gyro_var[idx], axis=0), np.median(imu.accel_var[idx], axis=0)
    if not (np.all(gv > 0) and np.all(av > 0)):
        raise SarInputError(f"{T.MASTER_IMU} carries no white-noise variance (angular_velocity_covariance / "
                            "linear_acceleration_covariance diagonal 0): the filter's process noise comes from it")
    imu_s = ImuSeries(t_s, imu.omega_radps[idx], imu.f_mps2[idx])

    fx = sorted((f for f in fixes), key=lambda f: f.t_ns)
    good = [f for f in fx if f.t_ns > t0_ns and np.isfinite([f.lat_rad, f.lon_rad, f.heading_rad, f.pos_sigma_m, f.heading_sigma_rad]).all()]
    drop("fix_before_start_or_invalid", len(fx) - len(good))
    seen: set[int] = set()
    fx_ok = []
    for f in good:
        if f.t_ns in seen:
            drop("fix_duplicate", 1)
            continue
        seen.add(f.t_ns)
        fx_ok.append(f)
    if not fx_ok:
        raise SarInputError(f"no usable {T.SAR_FIX} after the initial state")
    sar = SarFixes(np.array([(f.t_ns - t0_ns) * 1e-9 for f in fx_ok]),
                   np.array([[f.lat_rad, f.lon_rad, init.llh[2]] for f in fx_ok]),
                   np.array([f.heading_rad for f in fx_ok]),
                   np.array([f.pos_sigma_m for f in fx_ok]), np.array([f.heading_sigma_rad for f in fx_ok]))
    b = sorted(baro)
    b_ok = [x for x in b if np.isfinite(x[1]) and np.isfinite(x[2]) and x[2] > 0]
    drop("baro_invalid", len(b) - len(b_ok))
    b_t = np.array([x[0] for x in b_ok], dtype=np.int64)
    keep = np.r_[True, np.diff(b_t) > 0] if b_t.size else np.zeros(0, dtype=bool)
    drop("baro_duplicate", int((~keep).sum()))
    b_ok = [x for x, k in zip(b_ok, keep, strict=True) if k]
    if not b_ok:
        raise SarInputError(f"no usable {T.BARO_PRESSURE} sample")
    bs = BaroSeries(np.array([(x[0] - t0_ns) * 1e-9 for x in b_ok]), np.array([x[1] for x in b_ok]) + baro_height_offset_m,
                    np.array([x[2] for x in b_ok]))
    return SarInputs(int(t0_ns), init, imu_s, sar, bs, float(np.mean(gv)) * dt, float(np.mean(av)) * dt, dropped)


def run(inputs: SarInputs, settings: SarNavSettings) -> SarNavResult:
    """:func:`dpos_core.sar.navigate.navigate` on the inputs (the densities of the IMU's messages);
    :class:`SarInputError` for data the core refuses (e.g. a barometer that misses a filter step)."""
    try:
        return navigate(inputs.imu, inputs.init, inputs.fixes, inputs.baro,
                        replace(settings, gyro_psd=inputs.gyro_psd, accel_psd=inputs.accel_psd))
    except ValueError as e:
        raise SarInputError(str(e)) from None


def odometry(result: SarNavResult, origin_ns: int, datum_llh: FloatArray) -> tuple[NDArray[np.int64], NDArray[np.uint8]]:
    """Stamps and serialized ``/sar_nav/nav`` messages (Odometry, ``enu`` / ``master_imu``, the
    filter's covariances) of a result: one per filter epoch."""
    t_ns = origin_ns + np.round(result.t_s * 1e9).astype(np.int64)
    vals = cv.odometry_values_cov(result.llh, result.vel_n_mps, result.q_nb, datum_llh, None, result.pos_cov, result.att_cov, result.vel_cov)
    return t_ns, cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, t_ns, vals)


def summary(result: SarNavResult, settings: SarNavSettings, inputs: SarInputs) -> dict[str, Any]:
    """The numbers of a run for the status / report.json."""
    last_pos = np.sqrt(np.diag(result.pos_cov[-1]))
    out: dict[str, Any] = {
        "method": settings.method, "particles": settings.n_particles if settings.method not in ("ekf", "ukf") else 0,
        "seed": settings.seed, "bandwidth_scale": settings.bandwidth_scale, "filter_rate_hz": settings.filter_rate_hz,
        "epochs": int(result.t_s.size), "epochs_with_fix": int(result.sar.sum()), "fixes_off_grid": result.fixes_off_grid,
        "imu_samples": int(inputs.imu.t_s.size), "sar_fixes": int(inputs.fixes.t_s.size), "baro_samples": int(inputs.baro.t_s.size),
        "duration_s": float(result.t_s[-1]), "final_pos_sigma_m": [float(x) for x in last_pos],
        "final_heading_sigma_arcmin": float(np.sqrt(max(result.att_cov[-1][2, 2], 0.0)) / DEG * 60.0),
        "dropped": dict(inputs.dropped),
    }
    out.update(result.extra)
    return out


def errors_vs_truth(result: SarNavResult, truth: cv.OdometryBlock, origin_ns: int) -> dict[str, Any]:
    """Errors of the result against a ``/truth/master`` at the same stamps: per epoch attitude
    (pitch, roll, yaw [arcmin]) and position (east, north, up [m]); ``mae`` per component and the
    epochs compared."""
    t_ns = origin_ns + np.round(result.t_s * 1e9).astype(np.int64)
    k = np.searchsorted(truth.t_ns, t_ns)
    k = np.minimum(k, truth.t_ns.size - 1)
    on = truth.t_ns[k] == t_ns
    tr_llh, tr_q = truth.llh[k[on]], truth.q_nb[k[on]]
    pos = earth.dllh_to_enu(result.llh[on] - tr_llh, tr_llh)
    d = hpr_from_C_nb(quat_to_dcm(result.q_nb[on])) - hpr_from_C_nb(quat_to_dcm(tr_q))
    d = (d + np.pi) % (2 * np.pi) - np.pi
    att = np.stack([d[:, 1], d[:, 2], d[:, 0]], axis=1) / DEG * 60.0
    names = ("pitch_arcmin", "roll_arcmin", "yaw_arcmin", "east_m", "north_m", "up_m")
    e = np.hstack([att, pos])
    return {"epochs": int(on.sum()), "t_s": result.t_s[on], "err": e,
            "mae": {n: float(np.mean(np.abs(e[:, i]))) for i, n in enumerate(names)} if e.size else {}}
