"""The session products of a long flight with memory that does not grow with it (docs/long_flights.md): ``dpos-process --stream``.

Each sub-IMU's worker reads only its own topic and the main POS from the recording
(:func:`dpos_ros.io.session.read_session_streaming`), aligns it with the output rows handed over a
block at a time (``pipeline.run_segments(sink=...)``: the nominal re-integrated, the UPS's
particle track in files) and writes its antennas' rows and its own (the wing fit's input) to
files (:class:`RowStore`) as they come; it returns the per-epoch results only.  The products
are then written from those files a block of rows at a time: the CSV files and the quality
control (each antenna's stamps, sigmas and flags loaded one antenna at a time; its figure from
every n-th row) by the workers, an antenna each; the antenna bag :data:`BAG_BATCH_S` of poses per
batch, each batch's messages made and compressed by a worker and the file written by the main
process in order; ``status.json``.

The same products as :func:`dpos_ros.products.write.write` after :func:`~dpos_ros.products.solve.solve`
(tested on a short session), except:

* the least-squares wing fit of the ``fit`` antennas is made over consecutive windows of
  :data:`FIT_WINDOW_S` (the rigid misalignment, the degree choice and the variance factor per
  window; the same as the whole-session fit for a session shorter than one window);
  ``status.json`` ``wing_fit`` gives the first window's choice and the number of windows;
* the evaluation against the truth (``metrics.json``, ``report.md``, the error figures) is
  :mod:`dpos_ros.products.evaluate_stream`'s, a part of the truth and a block of rows at a time:
  the same metrics, the error figures from every n-th row, and metrics.json's ``evaluation`` note.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import ctypes.util
import functools
import json
import shutil
import tempfile
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.attitude import mount_dcm, quat_to_dcm
from dpos_core.config import AircraftConfig
from dpos_core.errors import RejectedInput
from dpos_core.series import NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import pipeline
from dpos_core.ta import qc as Q
from dpos_core.ta.antenna import ImuRates, antenna_motion, lever_velocity_var
from dpos_core.ta.model import Installation
from dpos_core.ta.pipeline import TASettings
from dpos_core.ta.wingfit import SubImuTrack
from dpos_core.units import FloatArray
from dpos_ros.contract import topics as T
from dpos_ros.io.bag import EncodedBatch, abort_writer, encode_streams, new_writer, write_stream_batches
from dpos_ros.io.session import RecordedSession, read_session_streaming

from . import rows as R
from .antenna import AntennaSolution
from .evaluate_stream import write_evaluation
from .qc import json_safe, plot_qc, qc_dir, qc_md
from .rows import ROW_COLUMNS, RowStore, StampCursor, StreamedAntenna, nav_of
from .solve import aligned_master, decimate, fit_antennas, spans_text
from .write import CSV_FORMATS, CSV_HEADER, CsvRows, antenna_stream, csv_columns, status_doc, write_complete

#: seconds of the wing fit's windows (module docstring)
FIT_WINDOW_S = 300.0
#: seconds of antenna poses per batch of the antenna bag (the in-memory path's 60 s: ~0.2 GB of
#: messages and their values for twelve antennas at 200 Hz in this process at once)
BAG_BATCH_S = 20.0
#: antenna-bag batches made on the workers ahead of the one being written (~12 MB each compressed)
BAG_IN_FLIGHT = 4
#: wing-fit windows submitted to the workers ahead of the one being stored (their rows in memory)
FIT_IN_FLIGHT = 4






@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (None elsewhere), looked up once: ``ctypes.util.find_library`` runs
    ``ldconfig`` in a subprocess, ~10 ms a call (and it is called once per bag batch)."""
    try:
        fn: Callable[[int], int] = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
        return fn
    except (OSError, AttributeError):
        return None


def release_memory() -> None:
    """Give the C heap's free pages back to the system (glibc ``malloc_trim``; nothing elsewhere): a
    worker's heap otherwise keeps what a task grew it to while it idles or runs a smaller task."""
    fn = _malloc_trim()
    if fn is not None:
        fn(0)


@contextmanager
def _drained(futures: Callable[[], Iterable[cf.Future]]) -> Iterator[None]:
    """On an error inside, cancel the pool's tasks ``futures()`` that have not started and wait for
    those running: they write into a directory the caller removes (the rows' scratch, the products)."""
    try:
        yield
    except BaseException:
        fs = list(futures())
        for f in fs:
            f.cancel()
        cf.wait(fs)
        raise






# ------------------------------------------------------------------------------------ the workers


def align_to_store(bag: str, sub: str, master: NavSeries | None, ins: Installation, settings: TASettings,
                   antennas: list[tuple[str, FloatArray]], store_dir: str, include_late: bool = True) -> dict:
    """One sub-IMU (a worker's task; module docstring): its topic read alone, aligned, its antennas'
    rows (``antennas``: name, lever arm) and its own at ``settings.output_rate_hz`` written to RowStores under
    ``store_dir`` as the TA hands them over, exactly as :func:`dpos_ros.products.solve.solve` computes
    them (``include_late``: a spill's late messages too, :func:`read_session_streaming`).  ``master``: the aligned main POS, or None for that of the recording as this worker reads
    it with its topic (:func:`dpos_ros.products.solve.aligned_master`: the same series, not sent to
    the worker).  Returns ``{"missing": True}``, ``{"rejected": why}`` or the per-epoch results and stores."""
    try:
        return _align_to_store(bag, sub, master, ins, settings, antennas, store_dir, include_late)
    finally:
        release_memory()


def _align_to_store(bag: str, sub: str, master: NavSeries | None, ins: Installation, settings: TASettings,
                    antennas: list[tuple[str, FloatArray]], store_dir: str, include_late: bool = True) -> dict:
    sess = read_session_streaming(Path(bag), keep=lambda t: t == T.sub_imu(sub), include_late=include_late)
    release_memory()  # (what decoding the recording's parts left in the heap)
    if sub not in sess.sub_imus:
        return {"missing": True, "warnings": sess.warnings}
    imu = sess.sub_imus[sub]
    if master is None:
        master = aligned_master(sess, settings.master_aligned_sigma_deg)
        if master is None:  # (the caller has found it aligned)
            return {"rejected": "the main POS is never aligned", "warnings": sess.warnings}
    base = Path(store_dir)
    ta_rows = RowStore(base / f"ta_{sub}", {k: v for k, v in ROW_COLUMNS.items() if k != "flags"})

    def sink(t: FloatArray, llh: FloatArray, vel: FloatArray, q: FloatArray, sigma: FloatArray) -> None:
        ta_rows.append(t_s=t, llh=llh, vel_n_mps=vel, q_nb=q, sigma=sigma)

    try:
        res = pipeline.align(imu, master, ins, settings, sink=sink)
    except RejectedInput as ex:
        ta_rows.remove()
        return {"rejected": str(ex), "warnings": sess.warnings}
    # the rows' quality bits, the decimation, the rate at the rows (with a time offset, at the instant the moved
    # rows stand for) and what the rate between the IMU's samples leaves unknown, as _sub_imu_antenna
    # (dpos_ros.products.solve), a block of rows at a time (no array of them all but their stamps and flags)
    (att_cov,) = master.required("att_cov")
    att_sig = np.sqrt(np.max(np.diagonal(att_cov, axis1=1, axis2=2), axis=1))  # (as solve._qc_flags)
    tau = res.installation.get("time_offset", {}).get("value", [0.0])[0]
    rates = ImuRates(imu.t_s, imu.omega_radps)
    stores = {name: RowStore(base / f"ant_{name}") for name, _ in antennas}
    own = RowStore(base / f"sub_{sub}")
    for i0 in range(0, res.t_s.size, R.ROW_BLOCK):
        i1 = min(i0 + R.ROW_BLOCK, res.t_s.size)
        c = ta_rows.rows(i0, i1)
        t, sigma = c["t_s"], c["sigma"]
        flags = res.flags[i0:i1] | Q.row_flags(t, res.qc, master.t_s, att_sig, np.deg2rad(settings.master_aligned_sigma_deg))
        k = _kept(res.t_s, i0, i1, settings.output_rate_hz)
        if settings.inflate_sigma:  # the innovations' variance factor where they say the filter is optimistic
            sigma = sigma * Q.sigma_scale(res.qc, t)
        C = quat_to_dcm(c["q_nb"])
        w = rates.rate_at(t + tau) if antennas else np.zeros((0, 3))
        w_var = rates.interpolation_var(t[k] + tau) if antennas else np.zeros((0, 3))
        for name, lever in antennas:
            llh, v = antenna_motion(C, c["vel_n_mps"], c["llh"], w, lever)
            s_a = sigma[k].copy()
            s_a[:, 3:6] = np.sqrt(s_a[:, 3:6] ** 2 + lever_velocity_var(C[k], w_var, lever))
            stores[name].append(t_s=t[k], q_nb=c["q_nb"][k], vel_n_mps=v[k], llh=llh[k], sigma=s_a, flags=flags[k])
        own.append(t_s=t[k], q_nb=c["q_nb"][k], vel_n_mps=c["vel_n_mps"][k], llh=c["llh"][k], sigma=sigma[k], flags=flags[k])
    ta_rows.remove()
    return {"stores": stores, "own": own, "qc": res.qc, "cg": res.cg, "not_estimated": list(res.not_estimated),
            "chol_jitter_repairs": res.chol_jitter_repairs, "installation": res.installation, "warnings": sess.warnings}


def _kept(t_s: FloatArray, i0: int, i1: int, rate_hz: float) -> NDArray[np.bool_]:
    """Which of the rows i0 .. i1 - 1 of the rows stamped ``t_s`` (N,) :func:`dpos_ros.products.solve.decimate`
    keeps at ``rate_hz`` (the same rows, from the block and the row before it)."""
    if rate_hz <= 0.0:
        return np.ones(i1 - i0, dtype=bool)
    j0 = max(i0 - 1, 0)  # (the row before decides whether row i0 starts a new step)
    kept = np.zeros(i1 - j0, dtype=bool)
    kept[decimate(t_s[j0:i1], rate_hz)] = True
    return kept[i0 - j0:]


# ------------------------------------------------------------------------------------ the session


def solve_streaming(bag: Path, sess: RecordedSession, aircraft: AircraftConfig, store_dir: Path, settings: TASettings, *,
                    pool: cf.Executor | None = None, sub_imus: list[str] | None = None,
                    include_late: bool = True) -> tuple[dict[str, StreamedAntenna], dict[str, float]]:
    """:func:`dpos_ros.products.solve.solve` of the recording ``bag`` (``sess``: its main POS, read
    without the sub-IMUs; ``sub_imus``: the sub-IMU topics it has), the rows in files under
    ``store_dir`` (module docstring); the same statuses and warnings (in ``sess.warnings``).
    ``include_late``: the workers read a spill's late messages too (transfer_align_node: not)."""
    t0 = time.perf_counter()
    master = aligned_master(sess, settings.master_aligned_sigma_deg)
    release_memory()  # (what reading the main POS grew the heap to)
    present = set(sess.sub_imus if sub_imus is None else sub_imus)
    # the workers read the main POS with their sub-IMU's topic (a long flight's main POS is not pickled to them)
    tasks = {s.name: (str(bag), s.name, master if pool is None else None, Installation.from_aircraft(aircraft, s.name), settings,
                      [(a.name, np.asarray(a.lever_arm_m, dtype=float)) for a in aircraft.antennas if a.sub_imu == s.name],
                      str(store_dir), include_late)
             for s in aircraft.sub_imus if s.name in present and master is not None}
    futs = {name: pool.submit(align_to_store, *args) for name, args in tasks.items()} if pool is not None else {}
    out: dict[str, StreamedAntenna] = {}
    unusable: dict[str, str] = {}
    carriers: dict[str, RowStore] = {}
    n_done = 0
    with _drained(futs.values):  # (a worker's failure: the others' rows are written in store_dir)
        for s in aircraft.sub_imus:
            if s.name not in present:
                sess.warnings.append(f"sub-IMU {s.name}: no /sub_imu/{s.name}/imu in the recording; its antennas are not estimated")
                continue
            if master is None:
                continue
            r = futs[s.name].result() if futs else align_to_store(*tasks[s.name])
            sess.warnings.extend(w for w in r.get("warnings", []) if w not in sess.warnings)
            if "rejected" in r:
                unusable[s.name] = f"sub-IMU {s.name}: {r['rejected']}"
                sess.warnings.append(f"sub-IMU {s.name}: {r['rejected']}; its antennas are not estimated")
                continue
            if "missing" in r:
                continue
            n_done += 1
            if r["not_estimated"]:
                sess.warnings.append(f"sub-IMU {s.name}: no pose over {spans_text(r['not_estimated'])}; each part after a gap "
                                     f"restarts from the main POS (flag {ta_flags.RESTARTED_AFTER_GAP} in the antenna CSV)")
            status = f"estimated (not estimated over {spans_text(r['not_estimated'])})" if r["not_estimated"] else "estimated"
            for a in aircraft.antennas:
                if a.sub_imu == s.name:
                    out[a.name] = StreamedAntenna(a.name, s.name, status, r["stores"][a.name], r["chol_jitter_repairs"],
                                                  list(r["not_estimated"]), r["qc"], r["cg"], installation=r["installation"])
            if r["own"].n > 1 and any(a.sub_imu == s.name for a in aircraft.antennas):  # (as solve: the antennas' carriers)
                carriers[s.name] = r["own"]
    for name in sorted(present):
        if name not in {s.name for s in aircraft.sub_imus}:
            sess.warnings.append(f"/sub_imu/{name}/imu is not in the aircraft configuration {aircraft.name!r}; ignored")
    timing = {"processing_s": time.perf_counter() - t0, "data_s": float(sess.master.t_s[-1] - sess.master.t_s[0]) * max(1, n_done)}
    for a in aircraft.antennas:
        if a.sub_imu is not None and a.name not in out:
            why = "the main POS is never aligned" if master is None else unusable.get(a.sub_imu, f"sub-IMU {a.sub_imu} has no data")
            out[a.name] = StreamedAntenna(a.name, a.sub_imu, f"not estimated: {why}")
    if any(a.sub_imu is None for a in aircraft.antennas):
        out.update(_fit_windows(sess, aircraft, carriers, store_dir, pool))
    release_memory()
    return {a.name: out[a.name] for a in aircraft.antennas if a.name in out}, timing


def fit_window(sess: RecordedSession, aircraft: AircraftConfig, carriers: dict[str, RowStore],
               ranges: dict[str, tuple[int, int]], store_dir: Path) -> tuple[dict[str, tuple[str, dict | None, RowStore | None]], list[str]]:
    """One window of :func:`_fit_windows` (a worker's task): :func:`dpos_ros.products.solve.fit_antennas`
    of the carriers' rows ``ranges`` (name -> ``(i0, i1)``) with ``sess`` (its main POS cut to the
    window); each ``fit`` antenna's rows written to a RowStore under ``store_dir`` (not sent back:
    the main process appends the files).  Returns per fit antenna (status, wing_fit info, its
    rows or None) and the warnings it added."""
    ants: dict[str, AntennaSolution] = {}
    for name, st in carriers.items():
        c = st.rows(*ranges[name])
        s = aircraft.sub_imu(name)
        tr = SubImuTrack(name, s.span_m, np.asarray(s.lever_arm_m, dtype=float), mount_dcm(s.mount_rpy_deg, (0.0, 0.0, 0.0)),
                         c["t_s"], quat_to_dcm(c["q_nb"]), c["vel_n_mps"], c["llh"], c["sigma"], c["flags"])
        ants[f"carrier:{name}"] = AntennaSolution(f"carrier:{name}", name, "estimated", nav_of(c), c["sigma"], carrier=tr)
    warnings: list[str] = []
    out: dict[str, tuple[str, dict | None, RowStore | None]] = {}
    try:
        sol = fit_antennas(dc_replace(sess, warnings=warnings), aircraft, ants)
        del ants
        for a in aircraft.antennas:
            fa = sol.get(a.name)
            if a.sub_imu is not None or fa is None:
                continue
            rows = None
            if fa.traj is not None and fa.sigma is not None and fa.flags is not None:
                rows = RowStore(Path(store_dir) / a.name)
                rows.append(t_s=fa.traj.t_s, q_nb=fa.traj.q_nb, vel_n_mps=fa.traj.vel_n_mps, llh=fa.traj.llh, sigma=fa.sigma, flags=fa.flags)
            out[a.name] = (fa.status, fa.wing_fit, rows)
    finally:
        release_memory()
    return out, warnings


def _fit_windows(sess: RecordedSession, aircraft: AircraftConfig, carriers: dict[str, RowStore],
                 store_dir: Path, pool: cf.Executor | None = None) -> dict[str, StreamedAntenna]:
    """The ``fit`` antennas by :func:`dpos_ros.products.solve.fit_antennas` over consecutive windows of
    :data:`FIT_WINDOW_S` (module docstring), their rows appended window by window; the windows
    fitted on ``pool`` when given (a few at a time, taken in order)."""
    fits = [a for a in aircraft.antennas if a.sub_imu is None]
    cursors = {name: StampCursor(st) for name, st in carriers.items()}
    if not cursors:
        sol = fit_antennas(sess, aircraft, {})
        return {a.name: StreamedAntenna(a.name, None, sol[a.name].status) for a in fits if a.name in sol}
    spans = [c.first_last() for c in cursors.values()]
    t_lo = min(lo for lo, _ in spans)
    t_hi = max(hi for _, hi in spans)
    n_win = max(1, int(np.ceil((t_hi - t_lo) / FIT_WINDOW_S - 1e-9)))
    edges = t_lo + FIT_WINDOW_S * np.arange(n_win + 1)
    edges[-1] = np.inf
    stores = {a.name: RowStore(store_dir / f"ant_{a.name}") for a in fits}
    first: dict[str, tuple[str, dict | None]] = {}
    statuses: dict[str, set[str]] = {a.name: set() for a in fits}

    def task(w: int) -> tuple:
        ranges = {name: (cursors[name].index(edges[w]), cursors[name].index(edges[w + 1])) for name in carriers}
        lo, hi = (edges[w] - 1.0, edges[w + 1] + 1.0)
        m = sess.master.select((sess.master.t_s >= lo) & (sess.master.t_s <= hi))
        return dc_replace(sess, master=m, warnings=[]), aircraft, carriers, ranges, store_dir / f"fit_window{w:05d}"

    pending: deque = deque()
    with _drained(lambda: [f for _, f in pending if isinstance(f, cf.Future)]):
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
                shutil.rmtree(store_dir / f"fit_window{w_done:05d}", ignore_errors=True)
    out: dict[str, StreamedAntenna] = {}
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
        out[a.name] = StreamedAntenna(a.name, None, status if rows is not None else status0, rows, wing_fit=info)
    return out


# ------------------------------------------------------------------------------------ the products


def write_streaming(out_root: Path, sess: RecordedSession, antennas: dict[str, StreamedAntenna], method: str, timing: dict[str, float],
                    *, overwrite: bool = False, pool: cf.Executor | None = None, evaluation: dict[str, dict] | None = None) -> Path:
    """:func:`dpos_ros.products.write.write` of streamed antennas (module docstring): complete or absent.
    ``pool``: each antenna's files (CSV, QC summary and figure) are written by its workers, and the
    antenna bag's batches made and compressed there while this process writes them to the file.
    ``evaluation``: :func:`dpos_ros.products.evaluate_stream.evaluate_streaming`'s result, written
    (metrics.json, report.md, error figures) before status.json."""
    return write_complete(Path(out_root) / sess.session_id, overwrite,
                          lambda out: _write(out, sess, antennas, method, timing, pool, evaluation))


def _write(out: Path, sess: RecordedSession, antennas: dict[str, StreamedAntenna], method: str, timing: dict[str, float],
           pool: cf.Executor | None, evaluation: dict[str, dict] | None = None) -> None:
    est = {name: a for name, a in antennas.items() if a.rows is not None}
    if est:
        qc_dir(out).mkdir(exist_ok=True)
    files = {name: (pool.submit(_antenna_files, out, a, sess.t0_ns, method) if pool is not None else None) for name, a in est.items()}
    summ: dict[str, dict] = {}
    with _drained(lambda: [f for f in files.values() if f is not None]):  # (they write into out)
        if est:
            _write_bag(out / "antennas", sess, est, {"dpos.session_id": sess.session_id, "dpos.method": method}, pool)
        for name, a in antennas.items():
            f = files.get(name)
            summ[name] = {"verdict": a.status} if a.rows is None else (f.result() if f is not None else _antenna_files(out, a, sess.t0_ns, method))
    doc = status_doc(sess, antennas, method, timing, {name for name, a in antennas.items() if a.rows is not None})
    (out / "qc.md").write_text(qc_md(summ, sess.session_id, method))
    if evaluation:  # against the truth (dpos_ros.products.evaluate_stream)
        write_evaluation(out, sess, evaluation, method, timing, pool)
    doc["qc"] = json_safe({"window_s": Q.WINDOW_S, "probability": Q.PROB, "check_fraction": Q.CHECK_FRACTION, "antennas": summ})
    (out / "status.json").write_text(json.dumps(doc, indent=2) + "\n")  # last: its presence says the products are complete


def _antenna_files(out: Path, a: StreamedAntenna, t0_ns: int, method: str) -> dict:
    """One estimated antenna's CSV and QC figure; returns its QC summary (a worker's task)."""
    try:
        return _antenna_files_in(out, a, t0_ns, method)
    finally:
        release_memory()


def _antenna_files_in(out: Path, a: StreamedAntenna, t0_ns: int, method: str) -> dict:
    assert a.rows is not None
    _write_csv_blocks(out / f"{a.name}.csv", t0_ns, a.rows)
    rows = a.rows
    t, flags = rows.read("t_s"), rows.read("flags")
    s = Q.summarize(t, lambda j: rows.column("sigma", j), flags, a.qc, a.wing_fit)  # (a column of the sigmas at a time)
    del t, flags
    s["sub_imu"] = a.sub_imu if a.sub_imu is not None else "fit"
    step = max(1, a.rows.n // (50 * 4000))  # plot_qc strides to 4000 points: every row is not needed
    plot_qc(qc_dir(out) / f"{a.name}_qc.png", a.solution(step=step), method)
    return s


def _write_csv_blocks(path: Path, t0_ns: int, rows: RowStore) -> None:
    """The antenna CSV (as :func:`dpos_ros.products.write.write` writes it), ROW_BLOCK rows at a time."""
    text = CsvRows(CSV_FORMATS)  # one buffer for every block's text
    with path.open("wb") as f:
        f.write(CSV_HEADER.encode() + b"\n")
        for i0 in range(0, rows.n, R.ROW_BLOCK):
            c = rows.rows(i0, i0 + R.ROW_BLOCK)
            text.write(f, t0_ns + np.round(c["t_s"] * 1e9).astype(np.int64), csv_columns(nav_of(c), c["sigma"], c["flags"]))


def bag_ranges(est: dict[str, StreamedAntenna], batch_s: float | None = None) -> Iterator[dict[str, tuple[int, int]]]:
    """Each batch's rows ``(i0, i1)`` per antenna: :data:`BAG_BATCH_S` of poses from the first row
    of all (the last batch to the end), found from the stamps a block at a time (:class:`StampCursor`)."""
    batch_s = BAG_BATCH_S if batch_s is None else batch_s
    cursors = {name: StampCursor(a.rows) for name, a in est.items() if a.rows is not None}
    spans = [c.first_last() for c in cursors.values() if c.rows.n]
    t_lo = min((lo for lo, _ in spans), default=0.0)
    t_hi = max((hi for _, hi in spans), default=t_lo)
    n = max(1, int(np.floor((t_hi - t_lo) / batch_s)) + 1)
    edges = t_lo + batch_s * np.arange(n + 1)
    edges[-1] = np.inf
    i_from = dict.fromkeys(cursors, 0)
    for k in range(n):
        ranges = {}
        for name in est:
            i0 = i_from[name]  # (the first batch from row 0)
            i1 = i_from[name] = cursors[name].index(edges[k + 1])
            ranges[name] = (i0, i1)
        yield ranges


def _bag_batches(sess: RecordedSession, est: dict[str, StreamedAntenna], batch_s: float | None = None):
    """:func:`dpos_ros.products.write.antenna_stream_batches` of the stored rows, :data:`BAG_BATCH_S`
    at a time (the same messages in the same order; a batch's last chunk is closed with it)."""
    for ranges in bag_ranges(est, batch_s):
        yield _bag_streams(sess, est, ranges)


def _bag_streams(sess: RecordedSession, est: dict[str, StreamedAntenna], ranges: dict[str, tuple[int, int]]) -> list:
    return [antenna_stream(sess, name, a.solution(*ranges[name]), slice(None)) for name, a in est.items()]


def encode_bag_batch(sess: RecordedSession, est: dict[str, StreamedAntenna], ranges: dict[str, tuple[int, int]],
                     prefix: bytes) -> EncodedBatch:
    """One batch of the antenna bag (:func:`_bag_batches`'s) made and compressed (a worker's task;
    ``sess`` and ``est`` as :func:`_light`); ``prefix``: the writer's, for the first batch."""
    try:
        return encode_streams(_bag_streams(sess, est, ranges), prefix)
    finally:
        release_memory()


def _light(sess: RecordedSession, est: dict[str, StreamedAntenna]) -> tuple[RecordedSession, dict[str, StreamedAntenna]]:
    """What a bag batch needs, to pickle to a worker: the session without its main POS (one epoch
    kept), the antennas' rows without their per-epoch QC."""
    return (dc_replace(sess, master=sess.master.select(slice(0, 1)), warnings=[]),
            {name: StreamedAntenna(name, a.sub_imu, a.status, a.rows) for name, a in est.items()})


def _write_bag(path: Path, sess: RecordedSession, est: dict[str, StreamedAntenna], custom_data: dict[str, str],
               pool: cf.Executor | None) -> None:
    """The antenna bag of ``est``: batches made and compressed on ``pool`` (:data:`BAG_IN_FLIGHT` at
    a time, appended in order: the same file as made here) or in this process."""
    if pool is None:
        write_stream_batches(path, _bag_batches(sess, est), custom_data=custom_data)
        return
    w = new_writer(path, [(T.antenna_odom(name), T.ODOMETRY) for name in est], custom_data)
    s_l, e_l = _light(sess, est)
    pending: deque[cf.Future] = deque()
    try:
        for k, ranges in enumerate(bag_ranges(est)):
            pending.append(pool.submit(encode_bag_batch, s_l, e_l, ranges, w.prefix if k == 0 else b""))
            while len(pending) > BAG_IN_FLIGHT:
                w.add_encoded(pending.popleft().result())
        while pending:
            w.add_encoded(pending.popleft().result())
        w.close()
    except BaseException:
        for f in pending:
            f.cancel()
        abort_writer(w)
        raise


def scratch_dir(out_root: Path) -> tempfile.TemporaryDirectory:
    """A temporary directory for the rows, beside the products (same file system, likely room)."""
    Path(out_root).mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix=".dpos_rows_", dir=out_root)
