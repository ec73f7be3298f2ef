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
from ..attitude import attitude_error
from ..chi2 import chi2_quantile
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


# ---------------------------------------------------------------------------- consistency

#: the 9 components of an antenna's reported 1-sigma (AntennaSolution.sigma, (N, 9)): attitude
#: error about local E, N, U [rad], velocity E, N, U [m/s], position E, N, U [m]
CONS_KEYS = ("rot_e", "rot_n", "rot_u", "vel_e", "vel_n", "vel_u", "pos_e", "pos_n", "pos_u")


def state_errors(est: NavSeries, truth: NavSeries) -> FloatArray:
    """Errors (N, 9) in the components of :data:`CONS_KEYS`, est - truth at the same stamps: the
    attitude error phi^n (``attitude_error``: ``C_est = expm(-[phi x]) C_true``), ENU velocity and
    ENU position differences."""
    out = np.empty((est.t_s.shape[0], 9))
    out[:, 0:3] = attitude_error(est.C_nb, truth.C_nb)
    out[:, 3:6] = est.vel_n_mps - truth.vel_n_mps
    out[:, 6:9] = earth.dllh_to_enu(est.llh - truth.llh, truth.llh)
    return out


def consistency(err: FloatArray, sigma: FloatArray) -> dict:
    """Whether reported 1-sigma ``sigma`` (N, 9) fit the errors ``err`` (N, 9), per component:
    ``within_2sigma`` the fraction of |e| <= 2 sigma (0.954 for a Gaussian error with that sigma),
    ``nees`` the mean of e^2 / sigma^2 (1 for an honest sigma), ``n`` the samples."""
    e, s = np.asarray(err, dtype=float), np.asarray(sigma, dtype=float)
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(s) & (s > 0), axis=1)
    z2 = (e[ok] / s[ok]) ** 2
    n = int(z2.shape[0])
    if n == 0:
        return {"n": 0, "within_2sigma": {}, "nees": {}}
    return {"n": n, "within_2sigma": {k: float(np.mean(z2[:, i] <= 4.0)) for i, k in enumerate(CONS_KEYS)},
            "nees": {k: float(np.mean(z2[:, i])) for i, k in enumerate(CONS_KEYS)}}


def average_consistency(items: list[dict]) -> dict:
    """The pooled :func:`consistency` of several (over antennas or runs), weighted by their samples."""
    items = [c for c in items if c and c.get("n")]
    n = sum(c["n"] for c in items)
    if n == 0:
        return {"n": 0, "within_2sigma": {}, "nees": {}}
    return {"n": n, **{part: {k: float(sum(c[part][k] * c["n"] for c in items) / n) for k in CONS_KEYS}
                       for part in ("within_2sigma", "nees")}}


def nees_bounds(runs: int, p: float = 0.95, dof: int = 1) -> tuple[float, float]:
    """Two-sided ``p`` bounds of the average over ``runs`` independent runs of a normalized squared
    error with ``dof`` degrees of freedom per run (chi^2(runs dof) / runs), the ANEES test of
    Bar-Shalom et al. (2001) sec. 5.4 per epoch.

    They bound the pooled ANEES of :func:`consistency` over the runs too (``dof`` 1), whatever the
    errors' correlation in time within a run (:func:`anees_in_bounds`)."""
    m = runs * dof
    return chi2_quantile((1 - p) / 2, m) / runs, chi2_quantile((1 + p) / 2, m) / runs


def anees_in_bounds(nees: dict[str, float], runs: int, p: float = 0.95) -> dict[str, bool]:
    """Per component, whether the ANEES pooled over ``runs`` independent runs of equal length
    (:func:`average_consistency`'s ``nees``) lies inside :func:`nees_bounds` ``(runs, p)``: False
    says the sigma is optimistic (above) or pessimistic (below) beyond chance.

    Why the per-epoch bounds hold for the time average: an honest sigma makes each run's time
    average of e^2 / sigma^2 a Gaussian quadratic form ``sum_i l_i Z_i^2`` with ``sum_i l_i = 1``
    (the eigenvalues of the errors' correlation over the run, divided by the samples), so the
    pooled ANEES is ``(1/R) sum_r sum_i l_ri Z_ri^2``.  The most concentrated form, an error
    constant over each run (``l = (1, 0, ..)``), gives chi^2(R) / R exactly; spreading the weights
    narrows the distribution, and for thresholds above 1.54 no form of mean 1 has a heavier upper
    tail than the concentrated one (Szekely and Bakirov 2003, one run; for R runs checked by
    simulation, test/dpos_core/ta/test_metrics.py).  So the bounds are sound, conservative where
    the errors decorrelate within a run, and exact where they do not: the transfer alignment's
    attitude errors stay nearly constant over a 1300 s flight (2-3 independent samples per run on
    paper_su, docs/mismatch.md "Honest sigmas"), so a few runs' ANEES scatters by the chi^2(R) / R
    spread, not by the number of epochs."""
    lo, hi = nees_bounds(runs, p)
    return {k: bool(lo <= v <= hi) for k, v in nees.items()}
