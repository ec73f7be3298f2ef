"""The main-POS reference of an offline transfer alignment (``dpos-process --master-reference``).

* ``recorded`` (default): the recording's ``/master/nav`` (what pos_master_node published live).
* ``forward``: the in-flight alignment re-run offline from the recording's ``/master/imu``,
  ``/gnss/fix`` and ``/gnss/vel`` (:func:`dpos_core.ifa.pipeline.run`, ADD2, the GNSS lever arm and
  the main IMU's model from the aircraft file; the start by pos_master_node's live rule,
  :func:`dpos_core.ifa.reference.initial_state`) - the forward-only solution with its covariance.
* ``smoothed``: the same run smoothed forward-backward (:func:`dpos_core.ifa.smoother.smooth`, RTS
  over the alignment's filter steps) - the better reference once the whole flight is recorded.

Either replaces ``sess.master`` (same :class:`~dpos_core.series.NavSeries`: attitude, velocity,
position, body rate, covariances) before the transfer alignment; everything downstream (the
aligned-main-POS rule, the sub-IMUs' alignment, the wing fit) is unchanged.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dpos_core.attitude import quat_to_dcm
from dpos_core.config.aircraft import AircraftConfig
from dpos_core.earth import dllh_to_enu
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.ifa.pipeline import run
from dpos_core.ifa.reference import initial_state
from dpos_core.ifa.smoother import smooth
from dpos_core.series import NavSeries
from dpos_core.units import DEG
from dpos_ros.io.gnss_ins import InputError, _topics, read_recording
from dpos_ros.io.session import RecordedSession, SessionError

REFERENCES = ("recorded", "forward", "smoothed")
#: what the in-flight alignment reads from the recording
IFA_TOPICS = ("/master/imu", "/gnss/fix", "/gnss/vel")


@dataclass
class MasterReference:
    """The main-POS reference used: ``which`` (:data:`REFERENCES`), the navigation, and how it was
    made (``info``: method, start, alignment time, fixes, runtime)."""

    which: str
    nav: NavSeries
    info: dict[str, Any]


def ifa_config(aircraft: AircraftConfig, pos_sigma_m: np.ndarray, vel_sigma_mps: np.ndarray) -> IfaFilterConfig:
    """The alignment's configuration for a recording: the main IMU's datasheet model of the
    aircraft file (the default model when it states none) and the receiver's median reported
    sigmas as the nominal GNSS noise (ADD2 adapts it from the first epoch)."""
    kw: dict[str, Any] = {"gnss_pos_sigma_m": tuple(float(v) for v in pos_sigma_m),
                          "gnss_vel_sigma_mps": tuple(float(v) for v in vel_sigma_mps)}
    if aircraft.master_imu is not None:
        kw["imu"] = aircraft.master_imu
    return IfaFilterConfig(**kw)


def master_reference(sess: RecordedSession, aircraft: AircraftConfig, which: str, method: str = "add2",
                     min_course_speed_mps: float = 5.0) -> MasterReference:
    """The main-POS reference ``which`` of a recording (module docstring).  Raises
    :class:`~dpos_ros.io.session.SessionError` naming what the recording lacks (``/master/imu``,
    ``/gnss/fix``, ``/gnss/vel``) or why the alignment cannot start."""
    if which not in REFERENCES:
        raise ValueError(f"unknown main-POS reference {which!r}: one of {REFERENCES}")
    if which == "recorded":
        return MasterReference(which, sess.master, {"source": "/master/nav"})
    return ifa_references(sess, aircraft, which, method, min_course_speed_mps)[which]


def ifa_references(sess: RecordedSession, aircraft: AircraftConfig, which: str = "smoothed", method: str = "add2",
                   min_course_speed_mps: float = 5.0) -> dict[str, MasterReference]:
    """``{"forward": ..., "smoothed": ...}`` from one in-flight alignment of the recording (``which``
    names the option in the error messages; :func:`master_reference`)."""
    avail = _topics(sess.path)
    missing = [t for t in IFA_TOPICS if avail and t not in avail]
    if missing:
        raise SessionError(f"--master-reference {which}: the recording {sess.path} has no {', '.join(missing)}: the in-flight "
                           f"alignment of the main POS needs {', '.join(IFA_TOPICS)} (use --master-reference recorded)")
    try:
        origin_ns, imu, gnss, notes = read_recording(sess.path, IFA_TOPICS, np.eye(3))
    except InputError as e:
        raise SessionError(f"--master-reference {which}: {e}") from None
    lever = np.asarray(aircraft.gnss_lever_arm_m, dtype=float)
    cfg = ifa_config(aircraft, np.median(gnss.pos_sigma_m, axis=0), np.median(gnss.vel_sigma_mps, axis=0))
    try:
        init = initial_state(imu, gnss, min_course_speed_mps, lever_arm_m=lever)
    except ValueError as e:
        raise SessionError(f"--master-reference {which}: the in-flight alignment cannot start: {e}") from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run(imu, gnss, lever, cfg, method, init, record_smoother=True)
    sm = smooth(res, imu)
    shift = (origin_ns - sess.t0_ns) * 1e-9  # read_recording's times: after the first IMU sample
    info: dict[str, Any] = {
        "start_s": float(init.t_s + shift), "aligned_s": None if res.aligned_t_s is None else float(res.aligned_t_s + shift),
        "fixes": int(len(gnss.t_s)), "rejected_fixes": len(res.rejected), "runtime_s": float(res.runtime_s),
        "final_heading_sigma_deg": float(res.heading_sigma_deg[-1]) if res.heading_sigma_deg.size else None,
        "notes": notes + sorted({str(w.message) for w in caught})[:5],
    }
    src = f"in-flight alignment ({method.upper()}) of {', '.join(IFA_TOPICS)}"
    return {w: MasterReference(w, replace(nav, t_s=nav.t_s + shift), {**info, "source": src + (", RTS-smoothed" if w == "smoothed" else ", forward")})
            for w, nav in (("forward", sm.forward), ("smoothed", sm.nav))}


#: correlation time [s] of a GNSS/INS main POS's position and velocity errors when they are
#: estimated by default (``master_error_tau_s`` / ``--master-error-tau`` auto): that of the
#: mismatch suite's master_ref_ifa+states (docs/mismatch.md "Installation states"); the graph's
#: own ADD2 alignment on paper_su decorrelates to 1/e in 6-13 s, the smoothed one more slowly
GNSS_INS_ERROR_TAU_S = 20.0
#: ``master_error_tau_s`` value meaning "from the main POS's source" (:func:`master_error_tau`)
AUTO_TAU = -1.0


def master_error_tau(requested: float, mechanized: bool, which: str = "recorded", imported: bool = False) -> tuple[float, str]:
    """The correlation time [s] of the main POS's position and velocity errors the transfer
    alignment takes (``TAConfig.master_error_tau_s``; 0 = white noise), and why.

    ``requested`` >= 0 is taken as given.  :data:`AUTO_TAU` (-1) derives it from the main POS's
    source: a GNSS/INS - the in-flight alignment re-run offline (``which`` forward or smoothed),
    or a recorded /master/nav that is pos_master_node's mechanization (``mechanized``:
    :attr:`~dpos_ros.io.session.RecordedSession.master_mechanized`) - has errors correlated in time, estimated as states with
    :data:`GNSS_INS_ERROR_TAU_S`; the simulator's reference main POS (truth + white noise, [Gong2018]'s
    model; no /pos_master/status) and an ``imported`` navigation solution (dpos-import --nav: a
    solution of record, its sigmas as given) keep 0."""
    if requested >= 0:
        return float(requested), "configured"
    if requested != AUTO_TAU:
        raise ValueError(f"master_error_tau_s must be >= 0 or {AUTO_TAU:g} (auto), got {requested:g}")
    if which != "recorded":
        return GNSS_INS_ERROR_TAU_S, f"auto: the main POS is the in-flight alignment ({which}), a GNSS/INS with correlated errors"
    if mechanized:
        return GNSS_INS_ERROR_TAU_S, "auto: /master/nav is pos_master_node's GNSS/INS mechanization (/pos_master/status), correlated errors"
    if imported:
        return 0.0, "auto: /master/nav is an imported navigation solution (dpos-import --nav): white noise with its sigmas"
    return 0.0, "auto: /master/nav without /pos_master/status (the simulator's reference main POS): white noise"


def aligned_since(nav: NavSeries, sigma_deg: float = 0.1) -> float:
    """The first stamp from which the attitude 1-sigma (every axis) stays below ``sigma_deg`` (the
    transfer alignment's rule for an aligned main POS); the first stamp without covariance."""
    if nav.att_cov is None:
        return float(nav.t_s[0])
    sig = np.sqrt(np.max(np.diagonal(nav.att_cov, axis1=1, axis2=2), axis=1))
    bad = np.flatnonzero(~(sig < sigma_deg * DEG))
    if bad.size == 0:
        return float(nav.t_s[0])
    return float(nav.t_s[min(bad[-1] + 1, nav.t_s.size - 1)])


def accuracy(nav: NavSeries, truth: NavSeries, since_s: float, until_s: float = np.inf) -> dict[str, list[float]]:
    """RMSE of a main-POS navigation against ``/truth/master`` over ``[since_s, until_s]``: heading /
    pitch / roll [deg], velocity E, N, U [m/s], position E, N, U [m], at the rows whose stamp the
    truth has (within 1 ms; the simulated truth is at the main IMU's stamps)."""
    j = np.clip(np.searchsorted(truth.t_s, nav.t_s), 1, truth.t_s.size - 1)
    j = np.where(np.abs(truth.t_s[j - 1] - nav.t_s) < np.abs(truth.t_s[j] - nav.t_s), j - 1, j)
    keep = (np.abs(truth.t_s[j] - nav.t_s) < 1e-3) & (nav.t_s >= since_s) & (nav.t_s <= until_s)
    if not keep.any():
        raise ValueError("no row of the navigation at a truth stamp in the window")
    n, tr = nav.select(keep), truth.select(j[keep])
    att = hpr_error(hpr_from_C_nb(quat_to_dcm(n.q_nb)), hpr_from_C_nb(quat_to_dcm(tr.q_nb))) / DEG
    rms = lambda e: [float(v) for v in np.sqrt(np.mean(e**2, axis=0))]  # noqa: E731
    return {"hpr_deg": rms(att), "vel_mps": rms(n.vel_n_mps - tr.vel_n_mps), "pos_m": rms(dllh_to_enu(n.llh - tr.llh, tr.llh))}


__all__ = ["REFERENCES", "GNSS_INS_ERROR_TAU_S", "AUTO_TAU", "master_error_tau", "IFA_TOPICS", "MasterReference", "master_reference", "ifa_references", "ifa_config", "accuracy", "aligned_since"]
