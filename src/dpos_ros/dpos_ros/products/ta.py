"""Transfer alignment of a recorded session and its products (design.md "Session products").

``output_dir/<session id>/``:
  ``antennas/``            rosbag2 (MCAP) with ``/antenna/<name>/odom`` (pose in ``enu``, twist in the
                           antenna frame, covariances from the smoother)
  ``<antenna>.csv``        time, lat, lon, h, vE, vN, vU, heading, pitch, roll and their 1-sigma
  ``metrics.json``         when truth is in the recording: RMSE/STD ([Gong2018] eq. 21) per antenna
  ``report.md`` + PNGs     the papers' table layout and error plots
  ``qc.md``, ``qc/``       quality control without truth, every session (:mod:`dpos_ros.products.qc`)
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import errno
import functools
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from dpos_core.attitude import mount_dcm
from dpos_core.config import AircraftConfig, AntennaConfig
from dpos_core.errors import ProductsExistError, RejectedInput
from dpos_core.filters.variational import CGStats, pool_summaries
from dpos_core.frames import hpr_from_C_nb
from dpos_core.series import ImuSeries, NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import metrics as M
from dpos_core.ta import pipeline
from dpos_core.ta import qc as ta_qc
from dpos_core.ta.antenna import antenna_motion, lever_velocity_var, rate_at, rate_interpolation_var
from dpos_core.ta.model import Installation, TAConfig
from dpos_core.ta.wingfit import SubImuTrack, fit_wing
from dpos_core.units import FloatArray
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.session import RecordedSession
from dpos_ros.runtime.pool import process_pool, worker_count


@dataclass
class AntennaSolution:
    """An antenna's smoothed trajectory (``traj``) with 1-sigma (N, 9): attitude (rad, rotation
    about local ENU), velocity (m/s, ENU), position (m, ENU); or a status saying why there is none.
    ``chol_jitter_repairs``: Cholesky jitter repairs made by its sub-IMU's smoother (counted, not silent).
    ``flags`` (N,): each row's quality bits (:mod:`dpos_core.ta.flags`; none set when None).
    ``not_estimated``: the spans ``(t_from_s, t_to_s, reason)`` without rows (sub-IMU gaps).
    ``carrier``: its sub-IMU's own solution at the same rows (the input of the least-squares wing
    fit, :func:`fit_antennas`); ``wing_fit``: for a ``fit`` antenna, the fit's basis choice and
    cross-validation (:class:`dpos_core.ta.wingfit.WingFit`); ``qc``: its sub-IMU's consistency
    measures at the filter epochs (:class:`dpos_core.ta.qc.EpochQC`; None for a ``fit`` antenna);
    ``cg``: the CDVF's conjugate-gradient record per epoch (:class:`dpos_core.filters.variational.CGStats`;
    None for the other methods); ``installation``: its sub-IMU's installation-state estimates
    (:attr:`dpos_core.ta.pipeline.TAResult.installation`; empty without them)."""

    name: str
    sub_imu: str | None
    status: str
    traj: NavSeries | None = None
    sigma: FloatArray | None = None
    chol_jitter_repairs: int = 0
    flags: ta_flags.FlagArray | None = None
    not_estimated: list[tuple[float, float, str]] = field(default_factory=list)
    carrier: SubImuTrack | None = None
    wing_fit: dict | None = None
    qc: ta_qc.EpochQC | None = None
    cg: CGStats | None = None
    installation: dict = field(default_factory=dict)


def solve(
    sess: RecordedSession,
    aircraft: AircraftConfig,
    method: str = "ups",
    particles: int = 100,
    seed: int = 0,
    initial_attitude_error_deg: float = 0.0,
    oracle_truth: dict | None = None,
    only: list[str] | None = None,
    filter_rate_hz: float = 1.0,
    position_matching: bool = True,
    inflate_sigma: bool = True,
    master_error_tau_s: float = 0.0,
    output_rate_hz: float = 0.0,
    master_aligned_sigma_deg: float = 0.1,
    workers: int = 1,
    known_wing: dict | None = None,
    pool: cf.Executor | None = None,
) -> tuple[dict[str, AntennaSolution], dict[str, float]]:
    """Transfer-align every sub-IMU of the aircraft found in the recording (or the ``only`` ones,
    with their antennas) from the first epoch at which the main POS is aligned
    (:func:`aligned_master`); carry the solutions to their antennas.  Returns the antennas and the
    timing (processing and data seconds).

    A sub-IMU's stream is aligned by :func:`dpos_core.ta.pipeline.run_segments`: across a gap
    longer than ``TAConfig.max_imu_gap_s`` it restarts from the main POS and the span has no rows
    (the status says ``estimated (not estimated over <from>-<to> s: <why>)`` and a warning names
    the spans); a sub-IMU whose data cannot be aligned at all (empty or all-NaN topic, too short,
    rejected by the core) gives its antennas ``not estimated: <why>`` and a warning, the other
    sub-IMUs going on.

    The rows get the quality control's flags (:func:`dpos_core.ta.qc.row_flags`):
    ``INCONSISTENT_INNOVATIONS`` from the sub-IMU's filter, ``MASTER_UNALIGNED`` where the main
    POS's attitude 1-sigma is ``master_aligned_sigma_deg`` or more (after its first alignment).

    ``workers``: the sub-IMUs are aligned in that many spawned worker processes (0 = one per
    core; 1 = in this process, one after the other).  Each worker gets only its sub-IMU's data,
    the main POS, its installation and the configuration; every sub-IMU uses ``seed`` either way,
    so the results (and the order of the warnings: the aircraft's sub-IMUs) do not depend on it.
    ``pool``: an executor already started (:func:`dpos_ros.runtime.pool.warm_pool`: its workers
    have imported and run the filters while the recording was read), used instead of starting
    one when there are at least 2 sub-IMUs (``workers`` is then ignored); it is left running.

    ``inflate_sigma``: each sub-IMU's output 1-sigma is scaled by the innovations' variance factor
    per match group where they say the filter is optimistic (:func:`dpos_core.ta.qc.sigma_scale`;
    docs/qc.md "Sigma inflation"); the fit antennas inherit it through their sub-IMUs.

    ``master_error_tau_s``: the main POS's position and velocity errors as correlated states of that
    correlation time (``TAConfig.master_error_tau_s``; the antennas then follow the main POS), 0 = white.

    ``known_wing`` (evaluation only, with ``method`` ``oracle_wing``): per sub-IMU the true wing
    (:func:`dpos_core.ta.from_sim.known_wing`), set as ``Installation.known_wing``."""
    cfg = TAConfig(filter_rate_hz=filter_rate_hz, attitude_sigma_deg=max(initial_attitude_error_deg, 1.0), use_position=position_matching,
                   master_error_tau_s=master_error_tau_s)
    results = {}
    unusable: dict[str, str] = {}  # sub-IMU -> why it is not estimated
    t0 = time.perf_counter()
    master = aligned_master(sess, master_aligned_sigma_deg)
    if only is not None:
        aircraft = dc_replace(aircraft, sub_imus=tuple(s for s in aircraft.sub_imus if s.name in only),
                              antennas=tuple(a for a in aircraft.antennas if a.sub_imu in only))
    e = initial_attitude_error_deg

    def install(name: str) -> Installation:
        ins = Installation.from_aircraft(aircraft, name)
        return ins if known_wing is None else dc_replace(ins, known_wing=known_wing[name])

    tasks = {s.name: (sess.sub_imus[s.name], master, install(s.name), cfg, method, particles, seed,
                      (e, e, e), None if oracle_truth is None else oracle_truth[s.name])
             for s in aircraft.sub_imus if s.name in sess.sub_imus and master is not None}
    n_workers = worker_count(workers, len(tasks))
    futs: dict[str, cf.Future[pipeline.TAResult]] = {}
    out: dict[str, AntennaSolution] = {}
    with contextlib.ExitStack() as stack:
        ex: cf.Executor | None = None
        if pool is not None and len(tasks) > 1:
            ex = pool
            stack.callback(lambda: [f.cancel() for f in futs.values()])  # on an error: the queued ones are not run
        elif n_workers > 1:
            ex = process_pool(n_workers)
            stack.callback(ex.shutdown, wait=True, cancel_futures=True)  # on an error: the queued ones are not run
        if ex is not None:  # submitted all at once, collected below in the aircraft's order
            # the core's function itself (pickled by name): a worker imports dpos_core.ta.pipeline, not this module
            futs = {name: ex.submit(pipeline.run_segments, *args[:-1], oracle_truth=args[-1]) for name, args in tasks.items()}
        for s in aircraft.sub_imus:
            if s.name not in sess.sub_imus:
                sess.warnings.append(f"sub-IMU {s.name}: no /sub_imu/{s.name}/imu in the recording; its antennas are not estimated")
                continue
            if master is None:
                continue
            try:
                res = futs[s.name].result() if futs else _align_sub_imu(*tasks[s.name])
            except RejectedInput as ex:
                unusable[s.name] = f"sub-IMU {s.name}: {ex}"
                sess.warnings.append(f"sub-IMU {s.name}: {ex}; its antennas are not estimated")
                continue
            if res.not_estimated:
                sess.warnings.append(f"sub-IMU {s.name}: no pose over {_spans(res.not_estimated)}; each part after a gap "
                                     f"restarts from the main POS (flag {ta_flags.RESTARTED_AFTER_GAP} in the antenna CSV)")
            res.flags |= _qc_flags(res, master, master_aligned_sigma_deg)
            if inflate_sigma:  # the innovations' variance factor where they say the filter is optimistic
                res.sigma = res.sigma * ta_qc.sigma_scale(res.qc, res.t_s)
            results[s.name] = res
            # its antennas now, while the workers align the next sub-IMUs
            out.update({a.name: _sub_imu_antenna(sess, aircraft, a, res, output_rate_hz) for a in aircraft.antennas if a.sub_imu == s.name})
    for name in sess.sub_imus if only is None else ():
        if name not in {s.name for s in aircraft.sub_imus}:
            sess.warnings.append(f"/sub_imu/{name}/imu is not in the aircraft configuration {aircraft.name!r}; ignored")
    timing = {"processing_s": time.perf_counter() - t0,
              "data_s": float(sess.master.t_s[-1] - sess.master.t_s[0]) * max(1, len(results))}
    for a in aircraft.antennas:
        if a.sub_imu is not None and a.sub_imu not in results:  # (the fit antennas: fit_antennas below)
            why = "the main POS is never aligned" if master is None else unusable.get(a.sub_imu, f"sub-IMU {a.sub_imu} has no data")
            out[a.name] = AntennaSolution(a.name, a.sub_imu, f"not estimated: {why}")
    out = {a.name: out[a.name] for a in aircraft.antennas if a.name in out}  # the aircraft's order (as the wing fit takes them)
    if any(a.sub_imu is None for a in aircraft.antennas):
        out.update(fit_antennas(sess, aircraft, out))
    return {a.name: out[a.name] for a in aircraft.antennas if a.name in out}, timing


def status_doc(sess: RecordedSession, antennas: dict, method: str, timing: dict[str, float], estimated: set[str]) -> dict:
    """status.json without its ``qc`` (design.md "Products"): the antennas' status, the warnings,
    the timing, the jitter repairs of the ``estimated`` antennas, the wing fits and each sub-IMU's
    installation states (aircraft file: lever_arm_sigma_m, time_offset_sigma_ms, axis_error_states)
    and how the main POS's errors were modelled (``sess.master_error_model``: tau_s, why).
    ``antennas``: AntennaSolution or the streaming path's antennas (the same fields)."""
    doc = {"session_id": sess.session_id, "method": method, "antennas": {name: a.status for name, a in antennas.items()},
           "warnings": sess.warnings, "timing": timing,
           "chol_jitter_repairs": {name: a.chol_jitter_repairs for name, a in antennas.items() if name in estimated}}
    fits = {a.wing_fit["wing"]: a.wing_fit for a in antennas.values() if a.wing_fit is not None}
    if fits:
        doc["wing_fit"] = fits
    inst = {a.sub_imu: a.installation for a in antennas.values() if a.sub_imu is not None and a.installation}
    if inst:
        doc["installation_states"] = inst
    if sess.master_error_model:
        doc["master_error_model"] = sess.master_error_model
    return doc


def _sub_imu_antenna(sess: RecordedSession, aircraft: AircraftConfig, a: AntennaConfig, r: pipeline.TAResult,
                     output_rate_hz: float) -> AntennaSolution:
    """Antenna ``a`` (one with a sub-IMU) carried by its sub-IMU's solution ``r`` (:func:`solve`):
    its position and velocity by the lever arm, the rows at ``output_rate_hz``."""
    assert a.sub_imu is not None
    imu = sess.sub_imus[a.sub_imu]
    # the rate at the rows (with a time offset, at the instant the moved rows stand for)
    tau = r.installation.get("time_offset", {}).get("value", [0.0])[0]
    C = r.C_nb
    llh, v = antenna_motion(C, r.vel_n_mps, r.llh, rate_at(imu.t_s, imu.omega_radps, r.t_s + tau), a.lever_arm_m)
    keep = _decimate(r.t_s, output_rate_hz)
    status = f"estimated (not estimated over {_spans(r.not_estimated)})" if r.not_estimated else "estimated"
    # the velocity sigma adds what the rate between the IMU's samples leaves unknown, through the lever arm
    sigma = r.sigma[keep].copy()
    w_var = rate_interpolation_var(imu.t_s, imu.omega_radps, r.t_s[keep] + tau)
    sigma[:, 3:6] = np.sqrt(sigma[:, 3:6] ** 2 + lever_velocity_var(C[keep], w_var, a.lever_arm_m))
    return AntennaSolution(a.name, a.sub_imu, status, NavSeries(r.t_s[keep], r.q_nb[keep], v[keep], llh[keep]), sigma,
                           r.chol_jitter_repairs, r.flags[keep], list(r.not_estimated), _carrier(aircraft, a.sub_imu, r, keep), qc=r.qc,
                           cg=r.cg, installation=r.installation)


def _qc_flags(r: pipeline.TAResult, master: NavSeries, sigma_deg: float) -> ta_flags.FlagArray:
    """The quality control's bits of a sub-IMU's rows (:func:`dpos_core.ta.qc.row_flags`)."""
    (att_cov,) = master.required("att_cov")
    sig = np.sqrt(np.max(np.diagonal(att_cov, axis1=1, axis2=2), axis=1))
    return ta_qc.row_flags(r.t_s, r.qc, master.t_s, sig, np.deg2rad(sigma_deg))


def _align_sub_imu(imu: ImuSeries, master: NavSeries, ins: Installation, cfg: TAConfig, method: str, particles: int,
                   seed: int, err0_deg: tuple[float, float, float], oracle_truth) -> pipeline.TAResult:
    """One sub-IMU's transfer alignment (:func:`solve`), in this process or in a worker (a module
    function: it is pickled by name); what it needs is all it gets."""
    return pipeline.run_segments(imu, master, ins, cfg, method, particles, seed, err0_deg, oracle_truth=oracle_truth)


def _carrier(aircraft: AircraftConfig, sub: str, r: pipeline.TAResult, keep: NDArray[np.intp]) -> SubImuTrack:
    """The sub-IMU's smoothed solution at the output rows ``keep``, for the wing fit."""
    s = aircraft.sub_imu(sub)
    return SubImuTrack(sub, s.span_m, np.asarray(s.lever_arm_m, dtype=float), mount_dcm(s.mount_rpy_deg, (0.0, 0.0, 0.0)),
                       r.t_s[keep], r.C_nb[keep], r.vel_n_mps[keep], r.llh[keep], r.sigma[keep], r.flags[keep])


#: the status of an antenna estimated by the wing fit starts with this
FIT_STATUS = "estimated (least-squares wing fit"


def fit_antennas(sess: RecordedSession, aircraft: AircraftConfig, antennas: dict[str, AntennaSolution]) -> dict[str, AntennaSolution]:
    """The antennas without a sub-IMU (``sub_imu: fit``) by the least-squares wing fit ([LSFit]
    sec. 2, :func:`dpos_core.ta.wingfit.fit_wing`) from the estimated sub-IMUs of their wing side
    (the ``carrier`` of ``antennas``, the solutions of :func:`solve`, or collected from the
    transfer_align_node's workers) and the main POS of ``sess``.  Each wing side with at least 2
    estimated sub-IMUs gives its ``fit`` antennas the status ``estimated (least-squares wing fit,
    <basis>; from sub-IMUs ...)``; otherwise ``not estimated: ...``.  Their rows' flags are the
    fit's (:mod:`dpos_core.ta.flags`: ``WING_FIT``, ``EXTRAPOLATED``, ``FEWER_SUB_IMUS``, the used
    sub-IMUs' own bits), with ``FEWER_SUB_IMUS`` on every row when a sub-IMU of the wing side in
    the aircraft is not estimated."""
    out: dict[str, AntennaSolution] = {}
    tracks: dict[str, SubImuTrack] = {}
    for sol in antennas.values():
        if sol.carrier is not None and sol.traj is not None and sol.carrier.t_s.size > 1:
            tracks.setdefault(sol.carrier.name, sol.carrier)
    for side in (1.0, -1.0):
        fits = [a for a in aircraft.antennas if a.sub_imu is None and np.sign(a.span_m or 1.0) == side]
        if not fits:
            continue
        subs = sorted((tr for tr in tracks.values() if np.sign(tr.span_m) == side), key=lambda tr: (-tr.t_s.size, abs(tr.span_m)))
        wing = "right" if side > 0 else "left"
        if len(subs) < 2:
            why = (f"not estimated: the least-squares wing fit needs at least 2 estimated sub-IMUs on the {wing} wing, "
                   f"has {len(subs)}")
            out.update({a.name: AntennaSolution(a.name, None, why) for a in fits})
            continue
        try:
            wf = fit_wing(sess.master, subs, [(a.name, a.span_m, np.asarray(a.lever_arm_m, dtype=float)) for a in fits])
        except Exception as ex:  # noqa: BLE001 - a bug or bad data of the fit: its antennas only, the others' products go on
            sess.warnings.append(f"least-squares wing fit of the {wing} wing failed: {ex}; its fit antennas are not estimated")
            out.update({a.name: AntennaSolution(a.name, None, f"not estimated: the least-squares wing fit failed: {ex}") for a in fits})
            continue
        names = ", ".join(sorted(tr.name for tr in subs))
        n_wing = sum(1 for s in aircraft.sub_imus if np.sign(s.span_m) == side)
        fewer = np.uint32(ta_flags.FEWER_SUB_IMUS if len(subs) < n_wing else 0)  # a sub-IMU of the wing not estimated at all
        info = {"wing": wing, "sub_imus": sorted(tr.name for tr in subs), "degree": wf.degree,
                "variance_factor": wf.variance_factor,
                "cv": {c: {str(k): v for k, v in cv.items()} for c, cv in wf.cv.items()}}
        for a in fits:
            fa = wf.antennas[a.name]
            status = f"{FIT_STATUS}, {wf.basis_text()}; from sub-IMUs {names})"
            if fa.traj.t_s.size == 0:
                out[a.name] = AntennaSolution(a.name, None, "not estimated: the least-squares wing fit has no epoch with enough sub-IMUs")
                continue
            fl = (ta_flags.none(fa.traj.t_s.size) | np.uint32(ta_flags.WING_FIT) if fa.flags is None else fa.flags) | fewer
            out[a.name] = AntennaSolution(a.name, None, status, fa.traj, fa.sigma, flags=fl.astype(np.uint32), wing_fit=info)
    return out


def _spans(spans: list[tuple[float, float, str]]) -> str:
    """``12.0-72.0 s: sub-IMU gap of 60.000 s; ...`` for the spans ``(t_from_s, t_to_s, reason)``."""
    return "; ".join(f"{a:.1f}-{b:.1f} s: {why}" for a, b, why in spans)


def aligned_master(sess: RecordedSession, sigma_deg: float = 0.1):
    """The main-system navigation from its first epoch whose attitude 1-sigma (every axis, from
    the /master/nav covariance) is below ``sigma_deg`` - the covariance is how pos_master_node flags
    a navigation that the in-flight alignment has not aligned yet (design.md) - or None if it never
    is.  Transfer alignment against an unaligned main POS (e.g. a 30 deg heading error with a
    100 deg sigma) would start the sub-IMUs from a wrong attitude; their poses start when the main
    POS is aligned instead, and a warning says so."""
    m = sess.master
    (att_cov,) = m.required("att_cov")
    sig = np.rad2deg(np.sqrt(np.max(np.diagonal(att_cov, axis1=1, axis2=2), axis=1)))
    ok = np.nonzero(sig < sigma_deg)[0]
    if ok.size == 0:
        sess.warnings.append(f"/master/nav is never aligned (attitude 1-sigma >= {sigma_deg:g} deg throughout, "
                             f"min {sig.min():.3g} deg): no sub-IMU is aligned")
        return None
    i = int(ok[0])
    if i == 0:
        return m
    sess.warnings.append(f"/master/nav is unaligned (attitude 1-sigma >= {sigma_deg:g} deg) for its first "
                         f"{m.t_s[i] - m.t_s[0]:.1f} s: the antenna poses start at t = {m.t_s[i]:.2f} s")
    return m.select(slice(i, None))


def _decimate(t_s: FloatArray, rate_hz: float) -> NDArray[np.intp]:
    """Indices of the samples at ``rate_hz`` (the first sample at or after each multiple of
    1/rate); all samples for rate 0."""
    if rate_hz <= 0.0:
        return np.arange(t_s.size)
    k = np.floor(t_s * rate_hz + 1e-6)
    first = np.concatenate([[True], np.diff(k) > 0])
    return np.nonzero(first)[0]


def evaluate(sess: RecordedSession, antennas: dict[str, AntennaSolution]) -> dict[str, dict]:
    """RMSE/STD per antenna over the imaging segments (whole session when none), when truth exists."""
    segs = sess.imaging_segments() or {"session": (float(sess.master.t_s[0]), float(sess.master.t_s[-1]))}
    tm = sess.truth.get("master")
    out = {}
    for name, a in antennas.items():
        tr = sess.truth.get(f"antenna/{name}")
        if a.traj is None or tr is None:
            continue
        t = a.traj.t_s
        idx = np.searchsorted(tr.t_s, t)
        ok = (idx < tr.t_s.size) & (np.abs(tr.t_s[np.clip(idx, 0, tr.t_s.size - 1)] - t) < 1e-6)
        i = idx[ok]
        est = a.traj.select(ok)
        tru = tr.select(i)
        m_est = m_true = None
        if tm is not None:
            m_est = _interp_llh(sess.master.t_s, sess.master.llh, est.t_s)
            m_true = _interp_llh(tm.t_s, tm.llh, est.t_s)
        err = M.errors(est, tru, m_est, m_true)
        out[name] = {**M.segment_stats(err, est.t_s, segs), "errors": err, "t_s": est.t_s}
        if a.sigma is not None:  # the reported sigma against the errors, over the same segments
            sel = np.zeros(est.t_s.size, dtype=bool)
            for t_a, t_b in segs.values():
                sel |= (est.t_s >= t_a) & (est.t_s <= t_b)
            e9, s9 = M.state_errors(est, tru)[sel], a.sigma[ok][sel]
            out[name]["consistency"] = M.consistency(e9, s9)
            out[name]["nsq"] = (e9 / s9) ** 2  # (n, 9) normalized squared errors, for the ANEES over runs
        if a.cg is not None:  # the CDVF's conjugate-gradient iterations (whole session)
            out[name]["cg"] = a.cg.summary()
    return out


def _interp_llh(t: FloatArray, llh: FloatArray, tq: FloatArray) -> FloatArray:
    return np.stack([np.interp(tq, t, llh[:, i]) for i in range(3)], -1)


def write(
    out_root: Path,
    sess: RecordedSession,
    antennas: dict[str, AntennaSolution],
    method: str,
    timing: dict[str, float],
    evaluation: dict[str, dict] | None = None,
    *,
    overwrite: bool = False,
    pool: cf.Executor | None = None,
) -> Path:
    """Write the products under ``out_root/<session id>/`` (module docstring); returns that directory.

    The directory is new: when it exists, :class:`ProductsExistError` (a FileExistsError) is raised
    before anything is written, unless ``overwrite``; then the products are written into a
    temporary sibling ``.<session id>.new-<pid>`` and swapped in only when complete (the old
    products are kept when writing fails). On any exception while writing, what this call created
    (the new directory or the temporary one) is removed and the exception re-raised: the
    products are complete or absent, never mixed or partial. ``out_root`` is created if needed.
    ``pool``: each antenna's files (CSV, QC figure, error figure) are written by its workers (the
    smoothers' pool, idle by then), the rest in this process meanwhile."""

    final = Path(out_root) / sess.session_id
    out = _new_products_dir(final, overwrite)
    try:
        _write_products(out, sess, antennas, method, timing, evaluation, pool)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    if out != final:
        _swap_in(out, final)
    return final


def _new_products_dir(final: Path, overwrite: bool) -> Path:
    """The new directory to write the products into: ``final`` itself when it does not exist,
    else (``overwrite``) a temporary sibling; :class:`ProductsExistError` otherwise."""

    final.parent.mkdir(parents=True, exist_ok=True)
    if not final.exists():
        final.mkdir()
        return final
    if not overwrite:
        raise ProductsExistError(errno.EEXIST, "products of an earlier run exist (they are not mixed with new ones; "
                                 "overwrite replaces them)", str(final))
    tmp = final.with_name(f".{final.name}.new-{os.getpid()}")
    if tmp.exists():  # left by a killed run of the same pid
        shutil.rmtree(tmp)
    tmp.mkdir()
    return tmp


def _swap_in(tmp: Path, final: Path) -> None:
    """Replace ``final`` by the complete ``tmp`` (two renames in one directory); the old products
    are restored if the second rename fails, and removed once the new ones are in place."""

    old = final.with_name(f".{final.name}.old-{os.getpid()}")
    if old.exists():
        shutil.rmtree(old)
    os.rename(final, old)
    try:
        os.rename(tmp, final)
    except BaseException:
        os.rename(old, final)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)


def _write_products(
    out: Path,
    sess: RecordedSession,
    antennas: dict[str, AntennaSolution],
    method: str,
    timing: dict[str, float],
    evaluation: dict[str, dict] | None,
    pool: cf.Executor | None = None,
) -> None:
    """The products (module docstring) into the new, empty directory ``out``; the antennas' own
    files by :func:`_antenna_files`, on ``pool`` when given."""
    from dpos_ros.io.bag import write_stream_batches

    from .qc import qc_dir, write_qc

    est = {name: a for name, a in antennas.items() if a.traj is not None and a.sigma is not None}
    if est:
        qc_dir(out).mkdir(exist_ok=True)
    files = []
    for name, a in est.items():
        assert a.traj is not None
        args = (out, name, antenna_stamps_ns(sess, a.traj.t_s), a, method, (evaluation or {}).get(name))
        if pool is None:
            _antenna_files(*args)
        else:
            files.append(pool.submit(_antenna_files, *args))
    bag_dir = out / "antennas"
    if est:  # (out is a new directory: write() never mixes runs); a batch of poses in memory at a time
        write_stream_batches(bag_dir, antenna_stream_batches(sess, est),
                             custom_data={"dpos.session_id": sess.session_id, "dpos.method": method})
    doc = status_doc(sess, antennas, method, timing, {name for name, a in antennas.items() if a.traj is not None})
    doc["qc"] = write_qc(out, antennas, sess.session_id, method)  # never reads truth (its figures: _antenna_files)
    if evaluation:
        metrics = metrics_json(sess, {method: (evaluation, timing)}, runs=1)
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
        (out / "report.md").write_text(report_md(metrics, title=f"Session {sess.session_id}"))
    for f in files:  # the workers' part: an exception there is this call's (write() removes the products)
        f.result()
    (out / "status.json").write_text(json.dumps(doc, indent=2) + "\n")  # last: its presence says the products are complete


def _antenna_files(out: Path, name: str, t_ns: NDArray[np.int64], a: AntennaSolution, method: str, ev: dict | None) -> None:
    """One estimated antenna's files of the products: ``<name>.csv``, ``qc/<name>_qc.png`` and, with
    its evaluation against the truth ``ev``, ``errors_<name>.png`` (a module function: it runs in
    the workers of :func:`write`'s pool)."""
    from .qc import plot_qc, qc_dir

    assert a.traj is not None and a.sigma is not None  # antenna_streams: estimated antennas only
    _write_csv(out / f"{name}.csv", t_ns, a.traj, a.sigma, a.flags)
    plot_qc(qc_dir(out) / f"{name}_qc.png", a, method)
    if ev is not None:
        plot_antenna_errors(out / f"errors_{name}.png", name, ev, method)


def antenna_streams(sess: RecordedSession, antennas: dict[str, AntennaSolution]):
    """``/antenna/<name>/odom`` TopicStreams (pose in ``enu`` with the smoother's covariance; twist
    in the antenna frame with the velocity covariance; angular rate not estimated) of the
    estimated antennas."""
    return [_antenna_stream(sess, name, a, slice(None)) for name, a in antennas.items() if a.traj is not None and a.sigma is not None]


#: seconds of antenna poses per batch of the products' antenna bag (:func:`antenna_stream_batches`)
BAG_BATCH_S = 60.0


def antenna_stream_batches(sess: RecordedSession, antennas: dict[str, AntennaSolution], batch_s: float = BAG_BATCH_S):
    """:func:`antenna_streams` in consecutive time windows of ``batch_s`` seconds (each window a list
    with every estimated antenna's stream, empty where it has no row): the same messages, a window's
    in memory at a time (for :func:`dpos_ros.io.bag.write_stream_batches`)."""
    est = {name: a for name, a in antennas.items() if a.traj is not None and a.sigma is not None}
    if not est:
        return
    t_lo = min((float(a.traj.t_s[0]) for a in est.values() if a.traj is not None and a.traj.t_s.size), default=0.0)
    t_hi = max((float(a.traj.t_s[-1]) for a in est.values() if a.traj is not None and a.traj.t_s.size), default=t_lo)
    n = max(1, int(np.floor((t_hi - t_lo) / batch_s)) + 1)
    edges = t_lo + batch_s * np.arange(n + 1)
    edges[-1] = np.inf
    for k in range(n):
        out = []
        for name, a in est.items():
            assert a.traj is not None
            i0 = 0 if k == 0 else int(np.searchsorted(a.traj.t_s, edges[k]))
            i1 = int(np.searchsorted(a.traj.t_s, edges[k + 1]))
            out.append(_antenna_stream(sess, name, a, slice(i0, i1)))
        yield out


def antenna_stamps_ns(sess: RecordedSession, t_s: FloatArray) -> NDArray[np.int64]:
    """The ROS stamps [ns] of the products' rows at session times ``t_s`` [s]."""
    return sess.t0_ns + np.round(t_s * 1e9).astype(np.int64)


def _antenna_stream(sess: RecordedSession, name: str, a: AntennaSolution, rows: slice):
    """The ``/antenna/<name>/odom`` stream of the rows ``rows`` of an estimated antenna (:func:`antenna_streams`)."""
    from dpos_ros.io.streams import TopicStream

    assert a.traj is not None and a.sigma is not None
    tr, s = a.traj.select(rows), a.sigma[rows]
    t_ns = antenna_stamps_ns(sess, tr.t_s)
    vals = cv.antenna_odometry_values(tr.llh, tr.vel_n_mps, tr.C_nb, s, sess.datum_llh)
    return TopicStream(T.antenna_odom(name), T.ODOMETRY, t_ns, rows=cv.odometry_rows(cv.WORLD_FRAME, cv.antenna_frame(name), t_ns, vals), qos="nav")


def _write_csv(path: Path, t_ns: NDArray[np.int64], tr: NavSeries, s: FloatArray, flags: ta_flags.FlagArray | None = None) -> None:
    """The antenna CSV (design.md "Session products"): per row (N) stamp, position, velocity,
    attitude, their 1-sigma (s (N, 9) as AntennaSolution.sigma) and ``flags`` (N,) (the quality
    bits of :mod:`dpos_core.ta.flags`; 0 when None)."""
    write_csv_rows(path, CSV_HEADER, np.asarray(t_ns, dtype=np.int64), _csv_columns(tr, s, flags), _CSV_FORMATS)


def _csv_columns(tr: NavSeries, s: FloatArray, flags: ta_flags.FlagArray | None) -> FloatArray:
    """The antenna CSV's columns after the stamp (N, 19), as :data:`_CSV_FORMATS` formats them."""
    hpr = np.rad2deg(hpr_from_C_nb(tr.C_nb))
    fl = ta_flags.none(tr.t_s.size) if flags is None else flags
    return np.column_stack([
        np.rad2deg(tr.llh[:, 0]), np.rad2deg(tr.llh[:, 1]), tr.llh[:, 2], tr.vel_n_mps, hpr,
        s[:, 7], s[:, 6], s[:, 8], s[:, 3:6], np.rad2deg(s[:, 2]), np.rad2deg(s[:, 0]), np.rad2deg(s[:, 1]), fl,
    ])


#: the antenna CSV's header
CSV_HEADER = ("stamp_s,lat_deg,lon_deg,h_m,vel_e_mps,vel_n_mps,vel_u_mps,heading_deg,pitch_deg,roll_deg,"
              "sigma_north_m,sigma_east_m,sigma_h_m,sigma_vel_e_mps,sigma_vel_n_mps,sigma_vel_u_mps,"
              "sigma_heading_deg,sigma_rot_e_deg,sigma_rot_n_deg,flags")


#: the antenna CSV's columns after the stamp (``%.10f`` = ("f", 10), ``%.4e`` = ("e", 4), ``%d`` = ("d", 0))
_CSV_FORMATS: tuple[tuple[str, int], ...] = (
    (("f", 10),) * 2 + (("f", 4),) + (("f", 5),) * 3 + (("f", 6),) * 3 + (("e", 4),) * 9 + (("d", 0),))


def write_csv_rows(path: Path, header: str, t_ns: NDArray[np.int64], cols: FloatArray, formats: tuple[tuple[str, int], ...]) -> None:
    """``header``, then per row the stamp ``t_ns`` (N,) in seconds with its 9 decimals (exact: from
    the integer nanoseconds) and the columns ``cols`` (N, m) formatted as printf's ``%.<d>f``,
    ``%.<d>e``, ``%d`` (``formats`` (m,): ``("f" | "e" | "d", d)``), comma-separated
    (:func:`csv_rows`)."""
    with open(path, "wb") as f:
        f.write(header.encode() + b"\n")
        CsvRows(formats).write(f, t_ns, cols)


def csv_rows(t_ns: NDArray[np.int64], cols: FloatArray, formats: tuple[tuple[str, int], ...]) -> bytes:
    """The rows of :func:`write_csv_rows` (no header), by a numba kernel (:mod:`._csv_kernel`):
    ~0.7 us a number through ``np.savetxt``."""
    return CsvRows(formats).text(t_ns, cols).tobytes()


@functools.cache
def _csv_tables() -> tuple[FloatArray, FloatArray]:
    """The kernel's tables of ``10.0**e`` and of the starts of ``floor(log10)`` (each (661,))."""
    from . import _csv_kernel as K

    return K.pow10_table(), K.log10_floor_starts()


class CsvRows:
    """The rows of :func:`write_csv_rows` block after block (``formats`` (m,) as there), written
    into one byte buffer kept between the blocks (grown when a block needs more)."""

    #: rows formatted at a time by :meth:`write` (their text, ~1 MB, stays in the CPU's cache
    #: until written: 65 536 rows at a time cost ~1.4x the CPU)
    WRITE_ROWS = 4096

    def __init__(self, formats: tuple[tuple[str, int], ...]) -> None:
        from . import _csv_kernel as K

        self._k = K
        self.m = len(formats)
        self.kinds = np.array([{"f": K.FIXED, "e": K.EXP, "d": K.INT}[k] for k, _ in formats], dtype=np.int64)
        self.decs = np.array([d for _, d in formats], dtype=np.int64)
        self.pow10, self.starts = _csv_tables()
        self.e_prev = np.zeros(self.m, dtype=np.int64)  # per EXP column its last exponent (the kernel's search start)
        self.buf = np.empty(0, np.uint8)
        self._nan, self._inf = np.frombuffer(b"nan", np.uint8), np.frombuffer(b"inf", np.uint8)

    def text(self, t_ns: NDArray[np.int64], cols: FloatArray) -> memoryview:
        """The text (L bytes) of the rows ``t_ns`` (N,) int64, ``cols`` (N, m): a view of the
        buffer, valid until the next call."""
        if cols.ndim != 2 or cols.shape[1] != self.m or cols.shape[0] != t_ns.shape[0]:
            raise ValueError(f"{self.m} formats for columns of shape {cols.shape} ({t_ns.shape[0]} stamps)")
        need = t_ns.shape[0] * self._k.max_line_bytes(self.m)
        if self.buf.size < need:
            self.buf = np.empty(need, np.uint8)
        n = self._k.rows_into(self.buf, np.ascontiguousarray(t_ns, dtype=np.int64), np.ascontiguousarray(cols, dtype=float),
                              self.kinds, self.decs, self._nan, self._inf, self.pow10, self.starts, self.e_prev)
        return self.buf[:n].data

    def write(self, f: BinaryIO, t_ns: NDArray[np.int64], cols: FloatArray) -> None:
        """Write the text of the rows ``t_ns`` (N,), ``cols`` (N, m) to ``f``, :attr:`WRITE_ROWS` rows at a time."""
        for i in range(0, t_ns.shape[0], self.WRITE_ROWS):
            f.write(self.text(t_ns[i:i + self.WRITE_ROWS], cols[i:i + self.WRITE_ROWS]))


def combine_runs(per_method: dict[str, list[dict]], timing: dict[str, dict]) -> dict[str, tuple[dict, dict]]:
    """Per method, the mean over the runs of each antenna's RMSE / STD (and its consistency, where
    the runs have it) from the runs' :func:`evaluate` results, with the method's timing: the
    ``per_method`` argument of :func:`metrics_json`."""
    combined = {}
    for m, runs in per_method.items():
        names = runs[0].keys()
        ant = {n: M.average([{"rmse": run[n]["rmse"], "std": run[n]["std"]} for run in runs]) for n in names}
        cons = {n: M.average_consistency([run[n].get("consistency", {}) for run in runs]) for n in names}
        cg = {n: pool_summaries([run[n]["cg"] for run in runs if "cg" in run[n]]) for n in names}
        combined[m] = ({n: {**ant[n], **({"consistency": cons[n]} if cons[n]["n"] else {}), **({"cg": cg[n]} if cg[n]["updates"] else {})}
                        for n in names}, timing[m])
    return combined


def metrics_json(sess: RecordedSession | None, per_method: dict[str, tuple[dict, dict]], runs: int, scenario: str | None = None) -> dict:
    """design.md's metrics.json: per method the mean over antennas (and runs) and per antenna."""
    segs = list((sess.imaging_segments() if sess else {}).keys()) or ["session"]
    methods: dict[str, dict] = {}
    out = {"scenario": scenario or (sess.custom.get("dpos.scenario", "") if sess else ""), "runs": runs, "segments": segs, "methods": methods}
    for method, (ev, timing) in per_method.items():
        ants = {name: {"rmse": e["rmse"], "std": e["std"]} for name, e in ev.items()}
        methods[method] = {"mean": M.average(list(ants.values())) if ants else {}, "antennas": ants, "timing": timing}
        cons = {name: e["consistency"] for name, e in ev.items() if e.get("consistency")}
        if cons:  # the reported sigma against the errors (M.consistency), per antenna and pooled
            for name, c in cons.items():
                ants[name]["consistency"] = c
            methods[method]["consistency"] = M.average_consistency(list(cons.values()))
        cgs = {name: e["cg"] for name, e in ev.items() if e.get("cg")}
        if cgs:  # the CDVF's conjugate-gradient iterations, per antenna and pooled
            for name, c in cgs.items():
                ants[name]["cg"] = c
            methods[method]["cg"] = pool_summaries(list(cgs.values()))
    return out


PAPER_TABLE1 = {  # [Gong2018] Table 1: (URTSS RMSE, STD), (UPS RMSE, STD)
    "heading_deg": ((3.7874, 1.2914), (0.4959, 0.0217)), "pitch_deg": ((0.5166, 0.1218), (0.0766, 0.0781)),
    "roll_deg": ((0.8238, 0.0371), (0.0569, 0.0568)), "vel_e_mps": ((0.0264, 0.0245), (0.0133, 0.0134)),
    "vel_n_mps": ((0.0403, 0.0414), (0.0225, 0.0148)), "vel_u_mps": ((0.0125, 0.0124), (0.0224, 0.0211)),
    "lat_m": ((2.1444, 0.0990), (1.0077, 0.0529)), "lon_m": ((1.7280, 0.0878), (0.0510, 0.0495)),
    "h_m": ((0.1078, 0.0987), (0.1294, 0.0126)), "baseline_m": ((0.7039, 0.0532), (0.0014, 0.0008)),
}
ROWS = [("Attitude error", "Heading (°)", "heading_deg"), ("", "Pitch (°)", "pitch_deg"), ("", "Roll (°)", "roll_deg"),
        ("Velocity error", "East (m/s)", "vel_e_mps"), ("", "North (m/s)", "vel_n_mps"), ("", "Up (m/s)", "vel_u_mps"),
        ("Position error", "Latitude (m)", "lat_m"), ("", "Longitude (m)", "lon_m"), ("", "Height (m)", "h_m"),
        ("Baseline error", "(m)", "baseline_m")]


def report_md(metrics: dict, title: str, paper: bool | None = None) -> str:
    """[Gong2018] Table 1 layout: means of RMSE and STD over the imaging segments (and runs)."""
    methods = list(metrics["methods"])
    paper = metrics.get("scenario") == "paper_su" if paper is None else paper
    head = ["Parameter", ""] + [f"{m.upper()} {c}" for m in methods for c in ("RMSE", "STD")]
    if paper:
        head += ["paper URTSS RMSE", "paper URTSS STD", "paper UPS RMSE", "paper UPS STD"]
    what = f"Scenario `{metrics['scenario']}`" if metrics.get("scenario") else "Live session"
    lines = [f"# {title}", "", f"{what}, {metrics['runs']} run(s), segments {', '.join(metrics['segments'])}; "
             "means of RMSE and STD ([Gong2018] eq. 21) over the segments, the runs and the antennas.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group, label, key in ROWS:
        row = [group, label]
        for m in methods:
            mean = metrics["methods"][m].get("mean", {})
            row += [_fmt(mean.get("rmse", {}).get(key)), _fmt(mean.get("std", {}).get(key))]
        if paper:
            (ur, us), (pr, ps) = PAPER_TABLE1[key]
            row += [f"{ur:.4f}", f"{us:.4f}", f"{pr:.4f}", f"{ps:.4f}"]
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    cons = {m: metrics["methods"][m]["consistency"] for m in methods if metrics["methods"][m].get("consistency", {}).get("n")}
    if cons:
        lines += ["Reported 1-sigma against the errors, pooled over the antennas and runs: fraction of errors within "
                  "2 sigma (0.95 when honest) / mean e^2/sigma^2 (1 when honest); attitude about local E, N, U.", "",
                  "| method | " + " | ".join(M.CONS_KEYS) + " |", "|---|" + "---|" * len(M.CONS_KEYS)]
        for m, c in cons.items():
            lines.append(f"| {m} | " + " | ".join(f"{c['within_2sigma'][k]:.2f} / {c['nees'][k]:.2g}" for k in M.CONS_KEYS) + " |")
        lines.append("")
    if metrics.get("scenario") == "paper_cdvf":
        lines += table2_md(metrics)
    cgs = {m: metrics["methods"][m]["cg"] for m in methods if metrics["methods"][m].get("cg", {}).get("updates")}
    if cgs:
        lines += cg_md(cgs)
    for m in methods:
        t = metrics["methods"][m].get("timing", {})
        if t.get("data_s"):
            lines.append(f"- {m}: processing {t['processing_s']:.1f} s for {t['data_s']:.0f} s of sub-IMU data "
                         f"(processing time / data duration = {t['processing_s'] / t['data_s']:.4f})")
    return "\n".join(lines) + "\n"


#: [Ye2024] Table 2 (flight test, RMSE): the traditional method (CDKF), the modified method (the
#: H-infinity CDKF of its ref. 1) and the proposed method (CDVF)
PAPER_TABLE2 = {
    "heading_deg": (0.066, 0.058, 0.050), "pitch_deg": (0.006, 0.005, 0.004), "roll_deg": (0.005, 0.004, 0.003),
    "vel_e_mps": (0.026, 0.023, 0.019), "vel_n_mps": (0.023, 0.020, 0.016), "vel_u_mps": (0.031, 0.026, 0.022),
    "lat_m": (0.748, 0.645, 0.580), "lon_m": (0.848, 0.713, 0.660), "h_m": (0.976, 0.870, 0.741),
}
#: the relative improvements [%] [Ye2024] sec. 4.2 states in its text (they are not those of its Table 2)
PAPER_TABLE2_TEXT_PCT = {"heading_deg": 22.2, "pitch_deg": 10.5, "roll_deg": 12.5, "vel_e_mps": 19.2, "vel_n_mps": 18.1,
                         "vel_u_mps": 22.5, "lat_m": 17.3, "lon_m": 19.8, "h_m": 23.9}
#: (CDKF, CDVF) pairs whose relative improvement the Table 2 layout shows
CDVF_PAIRS = (("cdkf", "cdvf"), ("cdkf_rts", "cdvf_rts"))


def _improvement(base: float | None, new: float | None) -> str:
    """``(base - new) / base`` in % (positive: ``new`` is better), or a dash."""
    if base is None or new is None or not np.isfinite(base) or not np.isfinite(new) or base <= 0:
        return "—"
    return f"{100.0 * (base - new) / base:+.2f} %"


def table2_md(metrics: dict) -> list[str]:
    """[Ye2024] Table 2 layout (attitude, velocity, position RMSE; no baseline row): every method's
    RMSE, the relative improvement of each CDVF over its CDKF (:data:`CDVF_PAIRS`), the paper's three
    columns and its improvements (from its table, traditional -> proposed, and as its text states)."""
    methods = list(metrics["methods"])
    rmse = {m: metrics["methods"][m].get("mean", {}).get("rmse", {}) for m in methods}
    pairs = [(a, b) for a, b in CDVF_PAIRS if a in methods and b in methods]
    head = ["Items", ""] + methods + [f"{b} vs {a}" for a, b in pairs] + [
        "paper CDKF", "paper modified CDKF", "paper CDVF", "paper CDVF vs CDKF (table)", "paper (text)"]
    lines = ["", f"[Ye2024] Table 2 layout: RMSE over the imaging laps ({metrics['runs']} run(s)); improvement = "
             "(CDKF - CDVF) / CDKF, positive when the CDVF is better.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group, label, key in ROWS:
        if key not in PAPER_TABLE2:
            continue
        row = [group, label] + [(f"{rmse[m][key]:.4g}" if rmse[m].get(key) is not None else "—") for m in methods]
        row += [_improvement(rmse[a].get(key), rmse[b].get(key)) for a, b in pairs]
        t, mod, prop = PAPER_TABLE2[key]
        row += [f"{t:.3f}", f"{mod:.3f}", f"{prop:.3f}", _improvement(t, prop), f"+{PAPER_TABLE2_TEXT_PCT[key]:.1f} %"]
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def cg_md(cgs: dict[str, dict]) -> list[str]:
    """The CDVF's conjugate-gradient iterations per method (:meth:`dpos_core.filters.variational.CGStats.summary`, pooled)."""
    lines = ["CDVF conjugate-gradient state updates (stopping rule |grad J| <= 1e-3 in the whitened coordinates, "
             "dpos_core.filters.variational; J: the variational cost, J0 at the prediction, J_cdkf at the CDKF's update):", "",
             "| method | updates | iterations mean / max | stopped by the gradient rule | mean (J0 - J) / J0 | J < J_cdkf | "
             "mean (J_cdkf - J) / J_cdkf | max (J - J_cdkf) | max final abs(grad J) |", "|---|---|---|---|---|---|---|---|---|"]
    for m, c in cgs.items():
        lines.append(f"| {m} | {c['updates']} | {c['iterations_mean']:.2f} / {c['iterations_max']} | {c['stopped_by_gradient']:.3f} | "
                     f"{c['relative_cost_decrease_mean']:.4f} | {c['below_cdkf']:.3f} | {c['relative_gain_over_cdkf_mean']:.2e} | "
                     f"{c['cost_minus_cdkf_max']:.2e} | {c['grad_norm_max']:.2e} |")
    return lines + [""]


def _fmt(v) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.4f}" if abs(v) >= 1e-3 else f"{v:.2e}"


def plot_antenna_errors(path: Path, name: str, ev: dict, method: str) -> Path:
    """The antenna's errors against the truth over time (``ev``: its entry of :func:`evaluate`)."""
    from matplotlib.figure import Figure

    e, t = ev["errors"], ev["t_s"]
    fig = Figure(figsize=(9, 7.5))  # no pyplot: figures may be drawn in threads at once (thread-pool executors)
    axs = fig.subplots(3, 1, sharex=True)
    fig.subplots_adjust(left=0.11, right=0.98, top=0.95, bottom=0.07, hspace=0.1)  # (constrained layout: ~2x the time)
    for k, lab in (("heading_deg", "heading"), ("pitch_deg", "pitch"), ("roll_deg", "roll")):
        axs[0].plot(t, e[k], lw=0.7, label=lab)
    axs[0].set(ylabel="attitude error [deg]")
    for k, lab in (("vel_e_mps", "east"), ("vel_n_mps", "north"), ("vel_u_mps", "up")):
        axs[1].plot(t, e[k], lw=0.7, label=lab)
    axs[1].set(ylabel="velocity error [m/s]")
    for k, lab in (("lat_m", "latitude"), ("lon_m", "longitude"), ("h_m", "height")):
        axs[2].plot(t, e[k], lw=0.7, label=lab)
    if "baseline_m" in e:
        axs[2].plot(t, e["baseline_m"], lw=0.7, label="baseline")
    axs[2].set(ylabel="position error [m]", xlabel="t [s]")
    for ax in axs:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axs[0].set_title(f"antenna {name}: {method.upper()} errors against truth")
    fig.savefig(path, dpi=80)
    return path
