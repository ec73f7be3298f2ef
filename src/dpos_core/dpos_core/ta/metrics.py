"""Accuracy metrics in the papers' format ([Gong2018] eq. 21, Table 1).

For every evaluated body (antenna or sub-IMU) and imaging segment: RMSE and STD of the errors of
heading, pitch, roll [deg], east/north/up velocity [m/s], latitude/longitude/height [m], and the
baseline (master-to-antenna distance) [m]; then means over the segments and over bodies.

    RMSE = sqrt(sum e_i^2 / n),   STD = sqrt(sum (e_i - mean e)^2 / n)
"""

from __future__ import annotations

import numpy as np

from dpos_core.units import FloatArray

from .. import earth
from ..frames import hpr_error, hpr_from_C_nb
from ..series import NavSeries

KEYS = ("heading_deg", "pitch_deg", "roll_deg", "vel_e_mps", "vel_n_mps", "vel_u_mps", "lat_m", "lon_m", "h_m", "baseline_m")


def errors(est: NavSeries, truth: NavSeries, master_est: FloatArray | None = None, master_true: FloatArray | None = None) -> dict[str, FloatArray]:
    """Error series (N,) per key, est - truth at the same stamps.

    ``master_est`` / ``master_true``: master positions (N, 3) llh for the baseline error
    ``|p_est - p_m,est| - |p_true - p_m,true|`` ([Gong2018] sec. 4.2); omitted without them.
    """
    if est.t_s.shape != truth.t_s.shape or np.max(np.abs(est.t_s - truth.t_s), initial=0.0) > 1e-6:
        raise ValueError("estimate and truth must be sampled at the same stamps")
    e_hpr = np.rad2deg(hpr_error(hpr_from_C_nb(est.C_nb), hpr_from_C_nb(truth.C_nb)))
    d_enu = earth.dllh_to_enu(est.llh - truth.llh, truth.llh)
    out = {
        "heading_deg": e_hpr[:, 0], "pitch_deg": e_hpr[:, 1], "roll_deg": e_hpr[:, 2],
        "vel_e_mps": est.vel_n_mps[:, 0] - truth.vel_n_mps[:, 0],
        "vel_n_mps": est.vel_n_mps[:, 1] - truth.vel_n_mps[:, 1],
        "vel_u_mps": est.vel_n_mps[:, 2] - truth.vel_n_mps[:, 2],
        "lat_m": d_enu[:, 1],
        "lon_m": d_enu[:, 0],
        "h_m": d_enu[:, 2],
    }
    if master_est is not None and master_true is not None:
        def dist(a: FloatArray, b: FloatArray) -> FloatArray:
            return np.linalg.norm(earth.geodetic_to_ecef(*a.T) - earth.geodetic_to_ecef(*b.T), axis=-1)

        out["baseline_m"] = dist(est.llh, master_est) - dist(truth.llh, master_true)
    return out


def rmse_std(e: FloatArray) -> tuple[float, float]:
    """[Gong2018] eq. 21."""
    e = np.asarray(e, dtype=float)
    if e.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(e * e))), float(np.sqrt(np.mean((e - e.mean()) ** 2)))


def segment_stats(err: dict[str, FloatArray], t_s: FloatArray, segments: dict[str, tuple[float, float]]) -> dict:
    """``{"rmse": {key: mean over segments}, "std": {...}, "segments": {name: {"rmse": ..., "std": ...}}}``."""
    per: dict[str, dict[str, dict[str, float]]] = {}
    for name, (a, b) in segments.items():
        sel = (t_s >= a) & (t_s <= b)
        per[name] = {"rmse": {}, "std": {}}
        for k, e in err.items():
            r, s = rmse_std(e[sel])
            per[name]["rmse"][k], per[name]["std"][k] = r, s
    keys = [k for k in KEYS if k in err]
    mean = {
        "rmse": {k: float(np.mean([per[n]["rmse"][k] for n in per])) for k in keys},
        "std": {k: float(np.mean([per[n]["std"][k] for n in per])) for k in keys},
    }
    return {**mean, "segments": per}


def average(stats: list[dict]) -> dict:
    """Mean of several ``{"rmse": {...}, "std": {...}}`` (over bodies or runs)."""
    keys = [k for k in KEYS if all(k in s["rmse"] for s in stats)]
    return {
        "rmse": {k: float(np.mean([s["rmse"][k] for s in stats])) for k in keys},
        "std": {k: float(np.mean([s["std"][k] for s in stats])) for k in keys},
    }
