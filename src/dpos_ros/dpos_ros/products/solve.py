"""Transfer alignment of a recorded session's sub-IMUs and the antennas they carry (design.md
"Session products"; docs/long_flights.md): :func:`solve`, over blocks of rows.

Each sub-IMU is aligned by :func:`align_to_store` (a worker's task): its data taken from the
:class:`SubImuSource` (a recording the worker reads itself - its own topic and the main POS only,
:func:`dpos_ros.io.session.read_session` - or a session in memory, dpos-eval's simulated
one), the output rows handed over a block at a time (``pipeline.run_segments(sink=...)``), its
antennas' rows (moved by the lever arm) and its own (the wing fit's input) appended to
:class:`~dpos_ros.products.rows.RowStore` s as they come: in memory, or spilled to a scratch
directory (``store_dir``) for a long flight - the same rows either way.  The ``fit`` antennas are
made by the least-squares wing fit over consecutive windows of :data:`FIT_WINDOW_S` (the rigid
misalignment, the degree choice and the variance factor per window; one window for a session
shorter than that); ``status.json`` ``wing_fit`` gives the first window's choice and the number of
windows.  The products are written by :mod:`dpos_ros.products.write`, evaluated against the truth
by :mod:`dpos_ros.products.evaluate`."""

from __future__ import annotations

import concurrent.futures as cf
import shutil
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.attitude import mount_dcm, quat_to_dcm
from dpos_core.config import AircraftConfig
from dpos_core.errors import AlignmentDiverged, RejectedInput
from dpos_core.series import ImuSeries, NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import pipeline
from dpos_core.ta import qc as Q
from dpos_core.ta.antenna import ImuRates, antenna_motion, lever_velocity_var
from dpos_core.ta.model import Installation
from dpos_core.ta.pipeline import TASettings
from dpos_core.ta.wingfit import SubImuTrack, fit_wing
from dpos_core.units import FloatArray
from dpos_ros.contract import topics as T
from dpos_ros.io.session import MASTER_SOURCE_KEY, MASTER_SOURCE_SOLUTION, RecordedSession, read_session

from . import rows as R
from .antenna import AntennaSolution
from .progress import NO_PROGRESS, ProductProgress
from .rows import ROW_COLUMNS, RowStore, StampCursor, drained, release_memory

#: seconds of the wing fit's windows (module docstring)
FIT_WINDOW_S = 300.0
#: wing-fit windows submitted to the workers ahead of the one being stored (their rows in memory)
FIT_IN_FLIGHT = 4


# ------------------------------------------------------------------------------------ the sub-IMUs' data


@dataclass(frozen=True)
class SubImuSource:
    """Where a worker finds its sub-IMU's data: the recording ``bag`` (read in the worker: its own
    topic and, unless ``master`` is sent, the main POS; ``include_late``: a spill's late messages
    too, as :func:`dpos_ros.io.session.read_session`), or ``imus`` in memory (a simulated
    session's; the main POS is then sent).  ``read_master``: the worker reads the main POS from
    ``bag`` (the recorded one) instead of being sent it."""

    bag: str | None = None
    include_late: bool = True
    read_master: bool = True
    imus: dict[str, ImuSeries] | None = None

    @classmethod
    def of_session(cls, sess: RecordedSession) -> SubImuSource:
        """The sub-IMUs of a session read (or simulated) in memory."""
        return cls(imus=dict(sess.sub_imus), read_master=False)

    def only(self, sub: str) -> SubImuSource:
        """This source with sub-IMU ``sub``'s data alone (what its worker is sent)."""
        if self.imus is None:
            return self
        return dc_replace(self, imus={k: v for k, v in self.imus.items() if k == sub})

    def read(self, sub: str) -> tuple[ImuSeries | None, RecordedSession | None, list[str]]:
        """Sub-IMU ``sub``'s samples (None: not in the source), the recording read with it (its main
        POS; None in memory) and the reading's warnings."""
        if self.imus is not None:
            return self.imus.get(sub), None, []
        assert self.bag is not None
        sess = read_session(Path(self.bag), keep=lambda t: t == T.sub_imu(sub), include_late=self.include_late)
        release_memory()  # (what decoding the recording's parts left in the heap)
        return sess.sub_imus.get(sub), sess, sess.warnings


@dataclass(frozen=True)
class SubImuTask:
    """One sub-IMU's work (:func:`align_to_store`): its data's ``source``, the aligned main POS
    ``master`` (None: read with the sub-IMU by the worker, :meth:`SubImuSource.read`), its
    installation, the settings, its antennas (name, lever arm [m] (3,)), the store its rows go
    beside and, for the evaluation only, the oracle's truth of the sub-IMU."""

    source: SubImuSource
    sub: str
    master: NavSeries | None
    install: Installation
    settings: TASettings
    antennas: tuple[tuple[str, FloatArray], ...]
    store: RowStore
    oracle_truth: object | None = None
    #: the main POS's covariances are its absolute accuracy, its errors correlated in time (an
    #: imported navigation solution): the filter, taking them as white, averages them down; the rows
    #: add them back (position and velocity only where the filter does not model them as states,
    #: ``settings.master_error_tau_s`` 0; with states it adds them itself), and the filter's own
    #: sigmas grow by its innovations' correlation in time (:func:`dpos_core.ta.qc.correlation_scale`:
    #: what it averaged, the mounting above all, it averaged over fewer independent epochs than it took)
    master_sigma_absolute: bool = False


# ------------------------------------------------------------------------------------ the workers


def align_to_store(task: SubImuTask) -> dict:
    """One sub-IMU (a worker's task; module docstring): aligned, its antennas' rows and its own at
    ``settings.output_rate_hz`` appended to RowStores as the transfer alignment hands them over.
    Returns ``{"missing": True}``, ``{"rejected": why}`` or the per-epoch results and stores."""
    try:
        return _align_to_store(task)
    finally:
        release_memory()


def _align_to_store(task: SubImuTask) -> dict:
    sub, settings = task.sub, task.settings
    imu, sess, warnings = task.source.read(sub)
    if imu is None:
        return {"missing": True, "warnings": warnings}
    master = task.master
    if master is None:
        assert sess is not None
        master = aligned_master(sess, settings.master_aligned_sigma_deg)
        if master is None:  # (the caller has found it aligned)
            return {"rejected": "the main POS is never aligned", "warnings": warnings}
    ta_rows = task.store.child(f"ta_{sub}", {k: v for k, v in ROW_COLUMNS.items() if k != "flags"})

    def sink(t: FloatArray, llh: FloatArray, vel: FloatArray, q: FloatArray, sigma: FloatArray) -> None:
        ta_rows.append(t_s=t, llh=llh, vel_n_mps=vel, q_nb=q, sigma=sigma)

    try:
        res = pipeline.align(imu, master, task.install, settings, sink=sink, oracle_truth=task.oracle_truth)
    except RejectedInput as ex:
        ta_rows.remove()
        return {"rejected": str(ex), "warnings": warnings}
    except AlignmentDiverged as ex:  # (dpos_core.ta.guard: the run ended but its rows are no estimate)
        ta_rows.remove()
        return {"rejected": f"the transfer alignment diverged ({ex.reason}): {ex}", "warnings": warnings}
    if ta_rows.n == 0 and res.t_s.size:  # (the oracle methods, evaluation only, keep their rows in the result)
        ta_rows.append(t_s=res.t_s, llh=res.llh, vel_n_mps=res.vel_n_mps, q_nb=res.q_nb, sigma=res.sigma)
    # the rows' quality bits (dpos_core.ta.qc.row_flags: INCONSISTENT_INNOVATIONS from the filter, MASTER_UNALIGNED
    # where the main POS's attitude 1-sigma is master_aligned_sigma_deg or more), the decimation, the rate at the rows
    # (with a time offset, at the instant the moved rows stand for) and what the rate between the IMU's samples leaves
    # unknown through the lever arm, a block of rows at a time (no array of them all but their stamps and flags)
    (att_cov,) = master.required("att_cov")
    att_sig = np.sqrt(np.max(np.diagonal(att_cov, axis1=1, axis2=2), axis=1))
    # the rows' columns: attitude, velocity, position (ENU, as the main POS's covariances)
    master_covs = [att_cov] + (list(master.required("vel_cov", "pos_cov")) if settings.master_error_tau_s == 0 else [])
    # an imported solution's errors are correlated in time, which the filter (white main-POS errors) does not know: its
    # innovations show it, and the sigmas of what it averaged (the mounting, the biases) grow by their correlation factor
    corr = Q.correlation_scale(res.qc) if task.master_sigma_absolute else np.ones(9)
    if np.any(corr > 1.0):
        warnings = [*warnings, f"sub-IMU {sub}: the innovations are correlated in time (the main POS's errors are not white): "
                    f"its own sigmas widened x{' / '.join(f'{c:.1f}' for c in corr[0:3])} (attitude E / N / U), "
                    f"x{' / '.join(f'{c:.1f}' for c in corr[3:6])} (velocity), x{' / '.join(f'{c:.1f}' for c in corr[6:9])} (position)"]
    tau = res.installation.get("time_offset", {}).get("value", [0.0])[0]
    rates = ImuRates(imu.t_s, imu.omega_radps)
    stores = {name: task.store.child(f"ant_{name}") for name, _ in task.antennas}
    own = task.store.child(f"sub_{sub}")
    for i0 in range(0, res.t_s.size, R.ROW_BLOCK):
        i1 = min(i0 + R.ROW_BLOCK, res.t_s.size)
        c = ta_rows.rows(i0, i1)
        t, sigma = c["t_s"], c["sigma"]
        flags = res.flags[i0:i1] | Q.row_flags(t, res.qc, master.t_s, att_sig, np.deg2rad(settings.master_aligned_sigma_deg))
        k = _kept(res.t_s, i0, i1, settings.output_rate_hz)
        if settings.inflate_sigma:  # the innovations' variance factor where they say the filter is optimistic
            sigma = sigma * Q.sigma_scale(res.qc, t)
        if task.master_sigma_absolute:  # (SubImuTask): the sub-IMU's pose is known relative to the main POS's
            sigma = sigma * corr
            var_m = np.column_stack([np.interp(t, master.t_s, cov[:, j, j]) for cov in master_covs for j in range(3)])
            sigma[:, :var_m.shape[1]] = np.sqrt(sigma[:, :var_m.shape[1]] ** 2 + var_m)
        C = quat_to_dcm(c["q_nb"])
        w = rates.rate_at(t + tau) if task.antennas else np.zeros((0, 3))
        w_var = rates.interpolation_var(t[k] + tau) if task.antennas else np.zeros((0, 3))
        for name, lever in task.antennas:
            llh, v = antenna_motion(C, c["vel_n_mps"], c["llh"], w, lever)
            s_a = sigma[k].copy()
            s_a[:, 3:6] = np.sqrt(s_a[:, 3:6] ** 2 + lever_velocity_var(C[k], w_var, lever))
            stores[name].append(t_s=t[k], q_nb=c["q_nb"][k], vel_n_mps=v[k], llh=llh[k], sigma=s_a, flags=flags[k])
        own.append(t_s=t[k], q_nb=c["q_nb"][k], vel_n_mps=c["vel_n_mps"][k], llh=c["llh"][k], sigma=sigma[k], flags=flags[k])
    ta_rows.remove()
    return {"stores": stores, "own": own, "qc": res.qc, "cg": res.cg, "not_estimated": list(res.not_estimated),
            "chol_jitter_repairs": res.chol_jitter_repairs, "installation": res.installation, "warnings": warnings}


def _kept(t_s: FloatArray, i0: int, i1: int, rate_hz: float) -> NDArray[np.bool_]:
    """Which of the rows i0 .. i1 - 1 of the rows stamped ``t_s`` (N,) :func:`decimate` keeps at
    ``rate_hz`` (the same rows, from the block and the row before it)."""
    if rate_hz <= 0.0:
        return np.ones(i1 - i0, dtype=bool)
    j0 = max(i0 - 1, 0)  # (the row before decides whether row i0 starts a new step)
    kept = np.zeros(i1 - j0, dtype=bool)
    kept[decimate(t_s[j0:i1], rate_hz)] = True
    return kept[i0 - j0:]


# ------------------------------------------------------------------------------------ the session


@dataclass(frozen=True)
class Oracle:
    """What the oracle methods know (evaluation of simulations only, :mod:`dpos_core.evaluation.ta`):
    ``truth``: per sub-IMU the simulation's truth (``pipeline.run_segments``'s ``oracle_truth``);
    ``known_wing``: per sub-IMU the true wing, set as ``Installation.known_wing``."""

    truth: dict | None = None
    known_wing: dict | None = None


#: no oracle (every method but the evaluation's oracles)
NO_ORACLE = Oracle()


def solve(sess: RecordedSession, aircraft: AircraftConfig, settings: TASettings, *, source: SubImuSource | None = None,
          store_dir: Path | None = None, pool: cf.Executor | None = None, sub_imus: list[str] | None = None,
          oracle: Oracle = NO_ORACLE,
          progress: ProductProgress = NO_PROGRESS) -> tuple[dict[str, AntennaSolution], dict[str, float]]:
    """Transfer-align every sub-IMU of the aircraft found in the recording from the first epoch at
    which the main POS is aligned (:func:`aligned_master`); carry the solutions to their antennas
    (module docstring).  Returns the antennas (the aircraft's order) and the timing (processing and
    data seconds).

    ``sess``: the recording's main POS and metadata (read without the sub-IMUs when ``source`` is a
    recording); ``source``: where the sub-IMUs' data are (default: ``sess``'s own, in memory);
    ``sub_imus``: the sub-IMU topics the recording has (default: ``sess.sub_imus``);
    ``store_dir``: the rows spilled to files under it (a long flight), None: in memory.
    ``pool``: the sub-IMUs aligned (and the wing-fit windows fitted) on its workers, else in this
    process one after the other; every sub-IMU uses ``settings.seed`` either way, so the results
    (and the order of the warnings: the aircraft's sub-IMUs) do not depend on it.

    A sub-IMU's stream is aligned by :func:`dpos_core.ta.pipeline.run_segments`: across a gap
    longer than ``TAConfig.max_imu_gap_s`` it restarts from the main POS and the span has no rows
    (the status says ``estimated (not estimated over <from>-<to> s: <why>)`` and a warning names
    the spans); a sub-IMU whose data cannot be aligned at all (empty or all-NaN topic, too short,
    rejected by the core) gives its antennas ``not estimated: <why>`` and a warning, the other
    sub-IMUs going on.  ``settings.inflate_sigma``: each sub-IMU's output 1-sigma is scaled by the
    innovations' variance factor where they say the filter is optimistic (docs/qc.md).

    ``oracle`` (evaluation only, the oracle methods): :class:`Oracle`.

    ``progress`` (:class:`~dpos_ros.products.progress.ProductProgress`, dpos_ros.cli.progress):
    ``sub_imu(name, outcome)`` as each sub-IMU's result arrives, ``fit_window(done, total)`` after
    each window of the wing fit."""
    t0 = time.perf_counter()
    source = SubImuSource.of_session(sess) if source is None else source
    store = RowStore(None if store_dir is None else Path(store_dir))
    imported = sess.custom.get(MASTER_SOURCE_KEY) == MASTER_SOURCE_SOLUTION
    if imported:
        # an imported navigation solution (dpos-import --nav) is a finished solution: aligned throughout, its sigmas
        # its accuracy (a live in-flight alignment's threshold would refuse an honest 0.1 deg: aligned_master)
        settings = dc_replace(settings, master_aligned_sigma_deg=float("inf"))
    master = aligned_master(sess, settings.master_aligned_sigma_deg)
    release_memory()  # (what reading the main POS grew the heap to)
    present = set(sess.sub_imus if sub_imus is None else sub_imus)

    def install(name: str) -> Installation:
        ins = Installation.from_aircraft(aircraft, name)
        return ins if oracle.known_wing is None else dc_replace(ins, known_wing=oracle.known_wing[name])

    # the workers read the recorded main POS with their sub-IMU's topic (a long flight's main POS is not pickled to them)
    send_master = pool is None or not source.read_master or source.bag is None
    tasks = {s.name: SubImuTask(source.only(s.name), s.name, master if send_master else None, install(s.name), settings,
                                tuple((a.name, np.asarray(a.lever_arm_m, dtype=float)) for a in aircraft.antennas if a.sub_imu == s.name),
                                store, None if oracle.truth is None else oracle.truth[s.name], imported)
             for s in aircraft.sub_imus if s.name in present and master is not None}
    futs = {name: pool.submit(align_to_store, task) for name, task in tasks.items()} if pool is not None else {}
    out: dict[str, AntennaSolution] = {}
    unusable: dict[str, str] = {}
    carriers: dict[str, RowStore] = {}
    n_done = 0
    with drained(futs.values):  # (a worker's failure: the others' rows are written in store_dir)
        for s in aircraft.sub_imus:
            if s.name not in present:
                sess.warnings.append(f"sub-IMU {s.name}: no /sub_imu/{s.name}/imu in the recording; its antennas are not estimated")
                continue
            if master is None:
                continue
            r = futs[s.name].result() if futs else align_to_store(tasks[s.name])
            sess.warnings.extend(w for w in r.get("warnings", []) if w not in sess.warnings)
            if "rejected" in r:
                unusable[s.name] = f"sub-IMU {s.name}: {r['rejected']}"
                sess.warnings.append(f"sub-IMU {s.name}: {r['rejected']}; its antennas are not estimated")
                progress.sub_imu(s.name, f"not estimated: {r['rejected']}")
                continue
            if "missing" in r:
                progress.sub_imu(s.name, "no data")
                continue
            n_done += 1
            if r["not_estimated"]:
                sess.warnings.append(f"sub-IMU {s.name}: no pose over {spans_text(r['not_estimated'])}; each part after a gap "
                                     f"restarts from the main POS (flag {ta_flags.RESTARTED_AFTER_GAP} in the antenna CSV)")
            status = f"estimated (not estimated over {spans_text(r['not_estimated'])})" if r["not_estimated"] else "estimated"
            progress.sub_imu(s.name, status)
            for a in aircraft.antennas:
                if a.sub_imu == s.name:
                    out[a.name] = AntennaSolution(a.name, s.name, status, r["stores"][a.name], r["chol_jitter_repairs"],
                                                  list(r["not_estimated"]), r["qc"], r["cg"], installation=r["installation"])
            if r["own"].n > 1 and any(a.sub_imu == s.name for a in aircraft.antennas):  # (the antennas' carriers)
                carriers[s.name] = r["own"]
    for name in sorted(present):
        if name not in {s.name for s in aircraft.sub_imus}:
            sess.warnings.append(f"/sub_imu/{name}/imu is not in the aircraft configuration {aircraft.name!r}; ignored")
    timing = {"processing_s": time.perf_counter() - t0, "data_s": float(sess.master.t_s[-1] - sess.master.t_s[0]) * max(1, n_done)}
    for a in aircraft.antennas:
        if a.sub_imu is not None and a.name not in out:
            why = "the main POS is never aligned" if master is None else unusable.get(a.sub_imu, f"sub-IMU {a.sub_imu} has no data")
            out[a.name] = AntennaSolution(a.name, a.sub_imu, f"not estimated: {why}")
    if any(a.sub_imu is None for a in aircraft.antennas):
        out.update(_fit_windows(sess, aircraft, carriers, store, pool, progress.fit_window))
    release_memory()
    return {a.name: out[a.name] for a in aircraft.antennas if a.name in out}, timing


# ------------------------------------------------------------------------------------ the wing fit


#: the status of an antenna estimated by the wing fit starts with this
FIT_STATUS = "estimated (least-squares wing fit"


@dataclass
class FitAntenna:
    """A ``fit`` antenna of one window of the wing fit (:func:`fit_antennas`): its status, the fit's
    record (``status.json`` ``wing_fit``) and its rows (N) with their 1-sigma (N, 9) and flags (N,), or None."""

    status: str
    wing_fit: dict | None = None
    traj: NavSeries | None = None
    sigma: FloatArray | None = None
    flags: ta_flags.FlagArray | None = None


def fit_antennas(master: NavSeries, aircraft: AircraftConfig, tracks: dict[str, SubImuTrack], warnings: list[str]) -> dict[str, FitAntenna]:
    """The antennas without a sub-IMU (``sub_imu: fit``) by the least-squares wing fit ([LSFit]
    sec. 2, :func:`dpos_core.ta.wingfit.fit_wing`) from the estimated sub-IMUs of their wing side
    (``tracks``: sub-IMU -> its smoothed rows, :func:`carrier_track`) and the main POS ``master``.
    Each wing side with at least 2 estimated sub-IMUs gives its ``fit`` antennas the status
    ``estimated (least-squares wing fit, <basis>; from sub-IMUs ...)``; otherwise ``not estimated:
    ...``.  Their rows' flags are the fit's (:mod:`dpos_core.ta.flags`: ``WING_FIT``,
    ``EXTRAPOLATED``, ``FEWER_SUB_IMUS``, the used sub-IMUs' own bits), with ``FEWER_SUB_IMUS`` on
    every row when a sub-IMU of the wing side in the aircraft is not estimated.  A failed fit is
    named in ``warnings``."""
    out: dict[str, FitAntenna] = {}
    usable = {name: tr for name, tr in tracks.items() if tr.t_s.size > 1}
    for side in (1.0, -1.0):
        fits = [a for a in aircraft.antennas if a.sub_imu is None and np.sign(a.span_m or 1.0) == side]
        if not fits:
            continue
        subs = sorted((tr for tr in usable.values() if np.sign(tr.span_m) == side), key=lambda tr: (-tr.t_s.size, abs(tr.span_m)))
        wing = "right" if side > 0 else "left"
        if len(subs) < 2:
            why = (f"not estimated: the least-squares wing fit needs at least 2 estimated sub-IMUs on the {wing} wing, "
                   f"has {len(subs)}")
            out.update({a.name: FitAntenna(why) for a in fits})
            continue
        try:
            wf = fit_wing(master, subs, [(a.name, a.span_m, np.asarray(a.lever_arm_m, dtype=float)) for a in fits])
        except Exception as ex:  # noqa: BLE001 - a bug or bad data of the fit: its antennas only, the others' products go on
            warnings.append(f"least-squares wing fit of the {wing} wing failed: {ex}; its fit antennas are not estimated")
            out.update({a.name: FitAntenna(f"not estimated: the least-squares wing fit failed: {ex}") for a in fits})
            continue
        names = ", ".join(sorted(tr.name for tr in subs))
        n_wing = sum(1 for s in aircraft.sub_imus if np.sign(s.span_m) == side)
        fewer = np.uint32(ta_flags.FEWER_SUB_IMUS if len(subs) < n_wing else 0)  # a sub-IMU of the wing not estimated at all
        info = {"wing": wing, "sub_imus": sorted(tr.name for tr in subs), "degree": wf.degree,
                "variance_factor": wf.variance_factor,
                "cv": {c: {str(k): v for k, v in cv.items()} for c, cv in wf.cv.items()}}
        for a in fits:
            fa = wf.antennas[a.name]
            if fa.traj.t_s.size == 0:
                out[a.name] = FitAntenna("not estimated: the least-squares wing fit has no epoch with enough sub-IMUs")
                continue
            fl = (ta_flags.none(fa.traj.t_s.size) | np.uint32(ta_flags.WING_FIT) if fa.flags is None else fa.flags) | fewer
            out[a.name] = FitAntenna(f"{FIT_STATUS}, {wf.basis_text()}; from sub-IMUs {names})", info, fa.traj, fa.sigma,
                                     fl.astype(np.uint32))
    return out


def carrier_track(aircraft: AircraftConfig, sub: str, c: dict[str, NDArray]) -> SubImuTrack:
    """Sub-IMU ``sub``'s smoothed rows ``c`` (a RowStore's columns) as the wing fit's input."""
    s = aircraft.sub_imu(sub)
    return SubImuTrack(sub, s.span_m, np.asarray(s.lever_arm_m, dtype=float), mount_dcm(s.mount_rpy_deg, (0.0, 0.0, 0.0)),
                       c["t_s"], quat_to_dcm(c["q_nb"]), c["vel_n_mps"], c["llh"], c["sigma"], c["flags"])


def fit_window(master: NavSeries, aircraft: AircraftConfig, carriers: dict[str, RowStore], ranges: dict[str, tuple[int, int]],
               store: RowStore) -> tuple[dict[str, tuple[str, dict | None, RowStore | None]], list[str]]:
    """One window of :func:`_fit_windows` (a worker's task): :func:`fit_antennas` of the carriers'
    rows ``ranges`` (name -> ``(i0, i1)``) with ``master`` (the main POS cut to the window); each
    ``fit`` antenna's rows put in a store beside ``store`` (files: not sent back, the main process
    appends them).  Returns per fit antenna (status, wing_fit info, its rows or None) and the
    warnings it added."""
    warnings: list[str] = []
    out: dict[str, tuple[str, dict | None, RowStore | None]] = {}
    try:
        tracks = {name: carrier_track(aircraft, name, st.rows(*ranges[name])) for name, st in carriers.items()}
        sol = fit_antennas(master, aircraft, tracks, warnings)
        del tracks
        for a in aircraft.antennas:
            fa = sol.get(a.name)
            if a.sub_imu is not None or fa is None:
                continue
            rows = None
            if fa.traj is not None and fa.sigma is not None and fa.flags is not None:
                rows = store.child(a.name)
                rows.append(t_s=fa.traj.t_s, q_nb=fa.traj.q_nb, vel_n_mps=fa.traj.vel_n_mps, llh=fa.traj.llh, sigma=fa.sigma, flags=fa.flags)
            out[a.name] = (fa.status, fa.wing_fit, rows)
    finally:
        release_memory()
    return out, warnings


def _fit_windows(sess: RecordedSession, aircraft: AircraftConfig, carriers: dict[str, RowStore],
                 store: RowStore, pool: cf.Executor | None = None,
                 on_window: Callable[[int, int], None] = NO_PROGRESS.fit_window) -> dict[str, AntennaSolution]:
    """The ``fit`` antennas by :func:`fit_antennas` over consecutive windows of :data:`FIT_WINDOW_S`
    (module docstring), their rows appended window by window; the windows fitted on ``pool`` when
    given (a few at a time, taken in order)."""
    fits = [a for a in aircraft.antennas if a.sub_imu is None]
    cursors = {name: StampCursor(st) for name, st in carriers.items()}
    if not cursors:
        sol = fit_antennas(sess.master, aircraft, {}, sess.warnings)
        return {a.name: AntennaSolution(a.name, None, sol[a.name].status) for a in fits if a.name in sol}
    spans = [c.first_last() for c in cursors.values()]
    t_lo = min(lo for lo, _ in spans)
    t_hi = max(hi for _, hi in spans)
    n_win = max(1, int(np.ceil((t_hi - t_lo) / FIT_WINDOW_S - 1e-9)))
    edges = t_lo + FIT_WINDOW_S * np.arange(n_win + 1)
    edges[-1] = np.inf
    stores = {a.name: store.child(f"ant_{a.name}") for a in fits}
    first: dict[str, tuple[str, dict | None]] = {}
    statuses: dict[str, set[str]] = {a.name: set() for a in fits}

    def task(w: int) -> tuple:
        ranges = {name: (cursors[name].index(edges[w]), cursors[name].index(edges[w + 1])) for name in carriers}
        lo, hi = (edges[w] - 1.0, edges[w + 1] + 1.0)
        m = sess.master.select((sess.master.t_s >= lo) & (sess.master.t_s <= hi))
        return m, aircraft, carriers, ranges, store.child(f"fit_window{w:05d}", {})

    pending: deque = deque()
    with drained(lambda: [f for _, f in pending if isinstance(f, cf.Future)]):
        for w in range(n_win):
            if pool is None:
                pending.append((w, fit_window(*task(w))))
            else:
                pending.append((w, pool.submit(fit_window, *task(w))))
            while pending and (pool is None or len(pending) > FIT_IN_FLIGHT or w == n_win - 1):
                w_done, r = pending.popleft()
                sol, warnings = r if pool is None else r.result()
                sess.warnings.extend(warnings)
                for a in fits:
                    if a.name not in sol:
                        continue
                    status, info, rows = sol[a.name]
                    statuses[a.name].add(status)
                    first.setdefault(a.name, (status, info))
                    if rows is not None:
                        stores[a.name].extend(rows)
                if store.path is not None:
                    shutil.rmtree(store.path / f"fit_window{w_done:05d}", ignore_errors=True)
                on_window(w_done + 1, n_win)
    out: dict[str, AntennaSolution] = {}
    for a in fits:
        if a.name not in first:
            continue
        status0, info0 = first[a.name]
        est = sorted(s for s in statuses[a.name] if s.startswith("estimated"))
        status = est[0] if est else status0
        if len(statuses[a.name]) > 1:
            status += f" ({len(statuses[a.name])} different outcomes over the {n_win} windows of the fit)"
        info = None if info0 is None else {**info0, "windows": n_win, "window_s": FIT_WINDOW_S}
        rows = stores[a.name] if stores[a.name].n else None
        out[a.name] = AntennaSolution(a.name, None, status if rows is not None else status0, rows, wing_fit=info)
    return out


# ------------------------------------------------------------------------------------ helpers


def spans_text(spans: list[tuple[float, float, str]]) -> str:
    """``12.0-72.0 s: sub-IMU gap of 60.000 s; ...`` for the spans ``(t_from_s, t_to_s, reason)``."""
    return "; ".join(f"{a:.1f}-{b:.1f} s: {why}" for a, b, why in spans)


def aligned_master(sess: RecordedSession, sigma_deg: float = 0.1) -> NavSeries | None:
    """The main-system navigation from its first epoch whose attitude 1-sigma (every axis, from
    the /master/nav covariance) is below ``sigma_deg`` - the covariance is how pos_master_node flags
    a navigation that the in-flight alignment has not aligned yet (design.md) - or None if it never
    is.  Transfer alignment against an unaligned main POS (e.g. a 30 deg heading error with a
    100 deg sigma) would start the sub-IMUs from a wrong attitude; their poses start when the main
    POS is aligned instead, and a warning says so.  (An imported navigation solution is aligned
    throughout: :func:`solve` passes ``sigma_deg`` = inf for it.)"""
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
