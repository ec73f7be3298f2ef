"""Transfer alignment of a recorded session's sub-IMUs and the antennas they carry (design.md
"Session products"): :func:`solve` (the sub-IMUs aligned in workers, their antennas carried by the
lever arm, the ``fit`` antennas by the least-squares wing fit).  The products are written by
:mod:`dpos_ros.products.write`, evaluated and reported by :mod:`dpos_ros.products.report`."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import time
from dataclasses import replace as dc_replace

import numpy as np
from numpy.typing import NDArray

from dpos_core.attitude import mount_dcm
from dpos_core.config import AircraftConfig, AntennaConfig
from dpos_core.errors import RejectedInput
from dpos_core.series import NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import pipeline
from dpos_core.ta import qc as ta_qc
from dpos_core.ta.antenna import antenna_motion, lever_velocity_var, rate_at, rate_interpolation_var
from dpos_core.ta.model import Installation
from dpos_core.ta.pipeline import TASettings
from dpos_core.ta.wingfit import SubImuTrack, fit_wing
from dpos_core.units import FloatArray
from dpos_ros.io.session import RecordedSession
from dpos_ros.runtime.pool import process_pool, worker_count

from .antenna import AntennaSolution


def solve(
    sess: RecordedSession,
    aircraft: AircraftConfig,
    settings: TASettings,
    *,
    only: list[str] | None = None,
    oracle_truth: dict | None = None,
    known_wing: dict | None = None,
    workers: int = 1,
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
    POS's attitude 1-sigma is ``settings.master_aligned_sigma_deg`` or more (after its first alignment).

    ``workers``: the sub-IMUs are aligned in that many spawned worker processes (0 = one per
    core; 1 = in this process, one after the other).  Each worker gets only its sub-IMU's data,
    the main POS, its installation and the settings; every sub-IMU uses ``settings.seed`` either way,
    so the results (and the order of the warnings: the aircraft's sub-IMUs) do not depend on it.
    ``pool``: an executor already started (:func:`dpos_ros.runtime.pool.warm_pool`: its workers
    have imported and run the filters while the recording was read), used instead of starting
    one when there are at least 2 sub-IMUs (``workers`` is then ignored); it is left running.

    ``settings`` (:class:`dpos_core.ta.pipeline.TASettings`): the method and the filter's settings,
    as transfer_align_node's ``TransferAlignConfig.core_config()`` and dpos-process make them.
    ``settings.inflate_sigma``: each sub-IMU's output 1-sigma is scaled by the innovations' variance factor
    per match group where they say the filter is optimistic (:func:`dpos_core.ta.qc.sigma_scale`;
    docs/qc.md "Sigma inflation"); the fit antennas inherit it through their sub-IMUs.

    ``settings.master_error_tau_s``: the main POS's position and velocity errors as correlated states of that
    correlation time (``TAConfig.master_error_tau_s``; the antennas then follow the main POS), 0 = white.

    ``known_wing`` (evaluation only, with the method ``oracle_wing``): per sub-IMU the true wing
    (:func:`dpos_core.evaluation.ta.known_wing`), set as ``Installation.known_wing``."""
    results = {}
    unusable: dict[str, str] = {}  # sub-IMU -> why it is not estimated
    t0 = time.perf_counter()
    master = aligned_master(sess, settings.master_aligned_sigma_deg)
    if only is not None:
        aircraft = dc_replace(aircraft, sub_imus=tuple(s for s in aircraft.sub_imus if s.name in only),
                              antennas=tuple(a for a in aircraft.antennas if a.sub_imu in only))

    def install(name: str) -> Installation:
        ins = Installation.from_aircraft(aircraft, name)
        return ins if known_wing is None else dc_replace(ins, known_wing=known_wing[name])

    tasks = {s.name: (sess.sub_imus[s.name], master, install(s.name), settings, None if oracle_truth is None else oracle_truth[s.name])
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
            futs = {name: ex.submit(pipeline.align, *args[:-1], oracle_truth=args[-1]) for name, args in tasks.items()}
        for s in aircraft.sub_imus:
            if s.name not in sess.sub_imus:
                sess.warnings.append(f"sub-IMU {s.name}: no /sub_imu/{s.name}/imu in the recording; its antennas are not estimated")
                continue
            if master is None:
                continue
            try:
                res = futs[s.name].result() if futs else pipeline.align(*tasks[s.name][:-1], oracle_truth=tasks[s.name][-1])
            except RejectedInput as ex:
                unusable[s.name] = f"sub-IMU {s.name}: {ex}"
                sess.warnings.append(f"sub-IMU {s.name}: {ex}; its antennas are not estimated")
                continue
            if res.not_estimated:
                sess.warnings.append(f"sub-IMU {s.name}: no pose over {spans_text(res.not_estimated)}; each part after a gap "
                                     f"restarts from the main POS (flag {ta_flags.RESTARTED_AFTER_GAP} in the antenna CSV)")
            res.flags |= _qc_flags(res, master, settings.master_aligned_sigma_deg)
            if settings.inflate_sigma:  # the innovations' variance factor where they say the filter is optimistic
                res.sigma = res.sigma * ta_qc.sigma_scale(res.qc, res.t_s)
            results[s.name] = res
            # its antennas now, while the workers align the next sub-IMUs
            out.update({a.name: _sub_imu_antenna(sess, aircraft, a, res, settings.output_rate_hz) for a in aircraft.antennas if a.sub_imu == s.name})
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
    keep = decimate(r.t_s, output_rate_hz)
    status = f"estimated (not estimated over {spans_text(r.not_estimated)})" if r.not_estimated else "estimated"
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


def spans_text(spans: list[tuple[float, float, str]]) -> str:
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


def decimate(t_s: FloatArray, rate_hz: float) -> NDArray[np.intp]:
    """Indices of the samples at ``rate_hz`` (the first sample at or after each multiple of
    1/rate); all samples for rate 0."""
    if rate_hz <= 0.0:
        return np.arange(t_s.size)
    k = np.floor(t_s * rate_hz + 1e-6)
    first = np.concatenate([[True], np.diff(k) > 0])
    return np.nonzero(first)[0]
