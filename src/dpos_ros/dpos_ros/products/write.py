"""The session products of a transfer alignment (design.md "Session products"), written complete
or not at all.  ``output_dir/<session id>/``:

  ``antennas/``            rosbag2 (MCAP) with ``/antenna/<name>/odom`` (pose in ``enu``, twist in the
                           antenna frame, covariances from the smoother), ``/antenna/<name>/fix``
                           (sensor_msgs/NavSatFix: WGS-84, ENU sigmas) and the latched ``/dpos/datum``;
                           each topic's QoS stored (a replay latches the datum again)
  ``<antenna>.csv``        time, lat, lon, h, vE, vN, vU, heading, pitch, roll and their 1-sigma
  ``tracks.geojson``       one track per antenna a GIS opens (:mod:`dpos_ros.products.track`)
  ``metrics.json``         when truth is in the recording: RMSE/STD ([Gong2018] eq. 21) per antenna
  ``report.md`` + PNGs     the papers' table layout and error plots (:mod:`dpos_ros.products.report`)
  ``qc.md``, ``qc/``       quality control without truth, every session (:mod:`dpos_ros.products.qc`)
  ``status.json``          the antennas' status, warnings, timing; written last
"""

from __future__ import annotations

import concurrent.futures as cf
import errno
import functools
import json
import os
import shutil
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from dpos_core.errors import ProductsExistError
from dpos_core.frames import hpr_from_C_nb
from dpos_core.geoid import GeoidGrid
from dpos_core.imports.timescales import GPS_EPOCH_UNIX_S, WEEK_S, gpst_to_utc_ns
from dpos_core.series import NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import qc as Q
from dpos_core.units import FloatArray
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.bag import EncodedBatch, abort_writer, encode_streams, new_writer, write_stream_batches
from dpos_ros.io.outdir import PRODUCTS_MARKER, child_dir, is_products_dir, mark_products, safe_name
from dpos_ros.io.session import RecordedSession
from dpos_ros.io.streams import TopicStream

from . import _csv_kernel as K
from . import rows as R
from .antenna import AntennaSolution
from .evaluate import write_evaluation
from .progress import NO_PROGRESS, ProductProgress
from .qc import MAX_PLOT_POINTS, json_safe, plot_qc, qc_dir, qc_md
from .rows import RowBlock, RowStore, StampCursor, drained, nav_of, release_memory
from .track import TrackWriter

#: the environment variable that sets the default of :attr:`WriteOptions.figures` (``on`` / ``off``)
FIGURES_ENV = "DPOS_FIGURES"
_SWITCH = {"on": True, "1": True, "true": True, "yes": True, "off": False, "0": False, "false": False, "no": False}


def figures_switch(value: str, what: str = FIGURES_ENV) -> bool:
    """``value`` (``on`` / ``off``, also 1 / 0, true / false, yes / no, any case) as a bool;
    ValueError naming ``what`` and the value otherwise."""
    v = _SWITCH.get(value.strip().lower())
    if v is None:
        raise ValueError(f"{what}={value!r}: expected on or off")
    return v


def figures_default() -> bool:
    """Whether the products include their figures when the caller does not say: ``$DPOS_FIGURES``
    (:func:`figures_switch`), else on. A value that is neither is warned about, naming it, and the
    figures are on (a typo must not cost a session's products at its end)."""
    v = os.environ.get(FIGURES_ENV, "").strip()
    if not v:
        return True
    try:
        return figures_switch(v)
    except ValueError as e:
        warnings.warn(f"{e}; the figures are written", stacklevel=2)
        return True


@dataclass(frozen=True)
class WriteOptions:
    """How :func:`write` writes: ``overwrite`` the products of an earlier run (else
    :class:`ProductsExistError`); ``geoid``: the antenna CSVs' heights above it too (:func:`csv_header`);
    ``figures``: the PNG figures (``qc/<antenna>_qc.png``, ``errors_<antenna>.png``; about a second
    of CPU each, whatever the flight's length), default :func:`figures_default`: a batch that needs
    only the numbers (CSV, bag, qc.md, metrics) sets them off, e.g. with ``DPOS_FIGURES=off``."""

    overwrite: bool = False
    geoid: GeoidGrid | None = None
    figures: bool = field(default_factory=figures_default)


def write(out_root: Path, sess: RecordedSession, antennas: dict[str, AntennaSolution], method: str, timing: dict[str, float],
          evaluation: dict[str, dict] | None = None, *, pool: cf.Executor | None = None,
          options: WriteOptions | None = None, progress: ProductProgress = NO_PROGRESS) -> Path:
    """Write the products under ``out_root/<session id>/`` (module docstring) from the antennas'
    rows, a block of rows at a time; returns that directory.

    The directory is new: when it exists, :class:`ProductsExistError` (a FileExistsError) is raised
    before anything is written, unless ``options.overwrite``; then the products are written into a
    temporary sibling ``.<session id>.new-<pid>`` and swapped in only when complete (the old
    products are kept when writing fails). On any exception while writing, what this call created
    (the new directory or the temporary one) is removed and the exception re-raised: the
    products are complete or absent, never mixed or partial. ``out_root`` is created if needed.
    ``pool``: each antenna's files (CSV, QC summary and figure, error figure) are written by its
    workers, and the antenna bag's batches (:data:`BAG_BATCH_S` of poses each) made and compressed
    there while this process writes them to the file in order.  ``evaluation``:
    :func:`dpos_ros.products.evaluate.evaluate`'s result, written (metrics.json, report.md, error
    figures) before status.json.  ``options``: :class:`WriteOptions` (default: ``WriteOptions()`` made at
    the call, so that ``$DPOS_FIGURES`` is read then).  ``progress``
    (:class:`~dpos_ros.products.progress.ProductProgress`): ``antenna(name)`` as each antenna's files
    are written, ``bag(done, total)`` after each batch of the antenna bag."""
    opts = options if options is not None else WriteOptions()
    return write_complete(child_dir(Path(out_root), safe_name(sess.session_id)), opts.overwrite,
                          lambda out: _write_products(out, sess, antennas, method, timing, pool, evaluation, opts,
                                                      progress))


def write_complete(final: Path, overwrite: bool, fill: Callable[[Path], None]) -> Path:
    """The products directory ``final``, complete or absent: ``fill(out)`` writes into a new
    directory (:func:`new_products_dir`), which is removed on any exception (re-raised) and swapped
    in for ``final`` (:func:`swap_in`) when it is a temporary sibling. Returns ``final``."""
    out = new_products_dir(final, overwrite)
    try:
        fill(out)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    if out != final:
        swap_in(out, final)
    return final


def new_products_dir(final: Path, overwrite: bool) -> Path:
    """The new directory to write the products into, marked as dpos's (:func:`mark_products`):
    ``final`` itself when it does not exist, else (``overwrite``) a temporary sibling;
    :class:`ProductsExistError` otherwise, and also with ``overwrite`` when ``final`` is not a dpos
    products directory (:func:`is_products_dir`: only what dpos wrote is ever replaced)."""

    final.parent.mkdir(parents=True, exist_ok=True)
    if not final.exists() and not final.is_symlink():
        final.mkdir()
        mark_products(final)
        return final
    if not overwrite:
        raise ProductsExistError(errno.EEXIST, "products of an earlier run exist (they are not mixed with new ones; "
                                 "overwrite replaces them)", str(final))
    if not is_products_dir(final):
        raise ProductsExistError(errno.EEXIST, "exists and is not a dpos products directory (no "
                                 f"{PRODUCTS_MARKER}): not replacing it", str(final))
    tmp = final.with_name(f".{final.name}.new-{os.getpid()}")
    if tmp.exists():  # left by a killed run of the same pid
        shutil.rmtree(tmp)
    tmp.mkdir()
    mark_products(tmp)
    return tmp


def swap_in(tmp: Path, final: Path) -> None:
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


def status_doc(sess: RecordedSession, antennas: dict, method: str, timing: dict[str, float], estimated: set[str]) -> dict:
    """status.json without its ``qc`` (design.md "Products"): the antennas' status, the warnings,
    the timing, the jitter repairs of the ``estimated`` antennas, the wing fits and each sub-IMU's
    installation states (aircraft file: lever_arm_sigma_m, time_offset_sigma_ms, axis_error_states)
    and how the main POS's errors were modelled (``sess.master_error_model``: tau_s, why).
    ``antennas``: :class:`~dpos_ros.products.antenna.AntennaSolution` s."""
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
    if sess.data_lost:  # what the recording held that could not be read (skipped chunks, corrupt spill records)
        doc["data_lost"] = dict(sess.data_lost)
    return doc


def _write_products(out: Path, sess: RecordedSession, antennas: dict[str, AntennaSolution], method: str, timing: dict[str, float],
                    pool: cf.Executor | None, evaluation: dict[str, dict] | None, options: WriteOptions,
                    progress: ProductProgress = NO_PROGRESS) -> None:
    """The products (module docstring) into the new, empty directory ``out``; ``options`` and
    ``progress``: :func:`write`'s."""
    est = {name: a for name, a in antennas.items() if a.rows is not None}
    if est:
        qc_dir(out).mkdir(exist_ok=True)
    files = {name: (pool.submit(_antenna_files, out, a, sess.t0_ns, method, options) if pool is not None else None) for name, a in est.items()}
    summ: dict[str, dict] = {}
    with drained(lambda: [f for f in files.values() if f is not None]):  # (they write into out)
        if est:
            _write_bag(out / "antennas", sess, est, {"dpos.session_id": sess.session_id, "dpos.method": method}, pool, progress.bag)
        for name, a in antennas.items():
            f = files.get(name)
            summ[name] = {"verdict": a.status} if a.rows is None else (f.result() if f is not None else _antenna_files(out, a, sess.t0_ns, method, options))
            if a.rows is not None:
                progress.antenna(name)
    _write_tracks(out / "tracks.geojson", sess, est)
    doc = status_doc(sess, antennas, method, timing, set(est))
    (out / "qc.md").write_text(qc_md(summ, sess.session_id, method))  # never reads truth
    if evaluation:  # against the truth (dpos_ros.products.evaluate)
        write_evaluation(out, sess, evaluation, method, timing, pool, figures=options.figures)
    doc["qc"] = json_safe({"window_s": Q.WINDOW_S, "probability": Q.PROB, "check_fraction": Q.CHECK_FRACTION, "antennas": summ})
    (out / "status.json").write_text(json.dumps(doc, indent=2) + "\n")  # last: its presence says the products are complete


#: one point of the antennas' GeoJSON tracks per this many seconds
TRACK_INTERVAL_S = 1.0


def _write_tracks(path: Path, sess: RecordedSession, est: dict[str, AntennaSolution]) -> None:
    """``tracks.geojson``: each estimated antenna's track (:class:`~dpos_ros.products.track.TrackWriter`),
    its rows read a block at a time (stamps and positions only)."""
    w = TrackWriter(TRACK_INTERVAL_S)
    for name, a in est.items():
        assert a.rows is not None
        for i0 in range(0, a.rows.n, R.ROW_BLOCK):
            w.add(name, antenna_stamps_ns(sess, a.rows.read("t_s", i0, i0 + R.ROW_BLOCK)), a.rows.read("llh", i0, i0 + R.ROW_BLOCK))
    w.write(path)


def _antenna_files(out: Path, a: AntennaSolution, t0_ns: int, method: str, options: WriteOptions) -> dict:
    """One estimated antenna's CSV and QC figure (``options``: :class:`WriteOptions`); returns its QC
    summary (a worker's task)."""
    try:
        return _antenna_files_in(out, a, t0_ns, method, options)
    finally:
        release_memory()


def _antenna_files_in(out: Path, a: AntennaSolution, t0_ns: int, method: str, options: WriteOptions) -> dict:
    assert a.rows is not None
    _write_csv_blocks(out / f"{a.name}.csv", t0_ns, a.rows, options.geoid)
    rows = a.rows
    t, flags = rows.read("t_s"), rows.read("flags")
    s = Q.summarize(t, lambda j: rows.column("sigma", j), flags, a.qc, a.wing_fit)  # (a column of the sigmas at a time)
    del t, flags
    s["sub_imu"] = a.sub_imu if a.sub_imu is not None else "fit"
    if options.figures:
        step = max(1, a.rows.n // (50 * MAX_PLOT_POINTS))  # plot_qc strides to MAX_PLOT_POINTS points: every row is not needed
        plot_qc(qc_dir(out) / f"{a.name}_qc.png", a, a.block(step=step), method)
    return s


def _write_csv_blocks(path: Path, t0_ns: int, rows: RowStore, geoid: GeoidGrid | None = None) -> None:
    """The antenna CSV (design.md "Session products"): its header (:func:`csv_header`), then per
    row stamp, position, velocity, attitude, their 1-sigma, flags, the time scales and, with a
    ``geoid``, the height above it (``h_m`` - N), ROW_BLOCK rows at a time."""
    text = CsvRows(CSV_FORMATS + ((GEOID_FORMAT,) if geoid is not None else ()))  # one buffer for every block's text
    with path.open("wb") as f:
        f.write(csv_header(geoid).encode() + b"\n")
        for i0 in range(0, rows.n, R.ROW_BLOCK):
            c = rows.rows(i0, i0 + R.ROW_BLOCK)
            t_ns = t0_ns + np.round(c["t_s"] * 1e9).astype(np.int64)
            cols = csv_columns(nav_of(c), c["sigma"], c["flags"], t_ns)
            if geoid is not None:
                llh = c["llh"]
                cols = np.column_stack([cols, llh[:, 2] - geoid.undulation(llh[:, 0], llh[:, 1])])
            text.write(f, t_ns, cols)


_NS = 1_000_000_000

#: seconds of antenna poses per batch of the antenna bag (~0.2 GB of messages and their values for
#: twelve antennas at 200 Hz in memory at once)
BAG_BATCH_S = 20.0
#: antenna-bag batches made on the workers ahead of the one being written (~12 MB each compressed)
BAG_IN_FLIGHT = 4


def bag_ranges(est: dict[str, AntennaSolution], batch_s: float | None = None) -> Iterator[dict[str, tuple[int, int]]]:
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


def antenna_stream_batches(sess: RecordedSession, est: dict[str, AntennaSolution], batch_s: float | None = None):
    """The ``/antenna/<name>/odom`` streams (:func:`antenna_stream`) of the estimated antennas
    ``est``, :data:`BAG_BATCH_S` of poses at a time (each batch a list with every antenna's
    stream, empty where it has no row): what transfer_align_node publishes."""
    for ranges in bag_ranges(est, batch_s):
        yield [antenna_stream(sess, name, a.block(*ranges[name])) for name, a in est.items()]


def bag_channels(est: dict[str, AntennaSolution]) -> list[tuple[str, str]]:
    """The antenna bag's channels, in the order of every batch's streams: each antenna's
    ``/antenna/<name>/odom`` and ``/antenna/<name>/fix``, then ``/dpos/datum``."""
    return [ch for name in est for ch in ((T.antenna_odom(name), T.ODOMETRY), (T.antenna_fix(name), T.NAVSATFIX))] + [(T.DATUM, T.NAVSATFIX)]


def _bag_streams(sess: RecordedSession, est: dict[str, AntennaSolution], ranges: dict[str, tuple[int, int]]) -> list:
    """One batch's streams (:func:`bag_channels`' order); the datum in the batch that holds the first
    rows (stamped at the first antenna row), an empty stream in the others."""
    out: list[TopicStream] = []
    first_ns: list[int] = []
    for name, a in est.items():
        b = a.block(*ranges[name])
        out += antenna_streams(sess, name, b)
        if ranges[name][0] == 0 and b.traj.t_s.size:
            first_ns.append(int(antenna_stamps_ns(sess, b.traj.t_s[:1])[0]))
    t_datum = np.array([min(first_ns)] if first_ns and all(r[0] == 0 for r in ranges.values()) else [], dtype=np.int64)
    out.append(TopicStream(T.DATUM, T.NAVSATFIX, t_datum, blobs=tuple(cv.datum_blob(int(t), sess.datum_llh) for t in t_datum),
                           qos="datum"))
    return out


def encode_bag_batch(sess: RecordedSession, est: dict[str, AntennaSolution], ranges: dict[str, tuple[int, int]],
                     prefix: bytes) -> EncodedBatch:
    """One batch of the antenna bag (:func:`antenna_stream_batches`'s) made and compressed (a
    worker's task; ``sess`` and ``est`` as :func:`_light`); ``prefix``: the writer's, for the first batch."""
    try:
        return encode_streams(_bag_streams(sess, est, ranges), prefix)
    finally:
        release_memory()


def _light(sess: RecordedSession, est: dict[str, AntennaSolution]) -> tuple[RecordedSession, dict[str, AntennaSolution]]:
    """What a bag batch needs, to pickle to a worker: the session without its main POS (one epoch
    kept), the antennas' rows without their per-epoch QC."""
    return (dc_replace(sess, master=sess.master.select(slice(0, 1)), sub_imus={}, truth={}, warnings=[]),
            {name: AntennaSolution(name, a.sub_imu, a.status, a.rows) for name, a in est.items()})


def _write_bag(path: Path, sess: RecordedSession, est: dict[str, AntennaSolution], custom_data: dict[str, str],
               pool: cf.Executor | None, on_bag: Callable[[int, int], None] | None = None) -> None:
    """The antenna bag of ``est``: batches made and compressed on ``pool`` (:data:`BAG_IN_FLIGHT` at
    a time, appended in order: the same file as made here) or in this process; ``on_bag(done,
    total)`` after each batch written."""
    batches = list(bag_ranges(est))  # (a few hundred dicts of row ranges for hours of flight)
    written = 0

    def tick() -> None:
        nonlocal written
        written += 1
        if on_bag is not None:
            on_bag(written, len(batches))

    if pool is None:
        def streams() -> Iterator[list]:
            for ranges in batches:
                yield _bag_streams(sess, est, ranges)
                tick()

        write_stream_batches(path, streams(), custom_data=custom_data)
        return
    w = new_writer(path, bag_channels(est), custom_data)
    s_l, e_l = _light(sess, est)
    pending: deque[cf.Future] = deque()
    try:
        for k, ranges in enumerate(batches):
            pending.append(pool.submit(encode_bag_batch, s_l, e_l, ranges, w.prefix if k == 0 else b""))
            while len(pending) > BAG_IN_FLIGHT:
                w.add_encoded(pending.popleft().result())
                tick()
        while pending:
            w.add_encoded(pending.popleft().result())
            tick()
        w.close()
    except BaseException:
        for f in pending:
            f.cancel()
        abort_writer(w)
        raise


def antenna_stamps_ns(sess: RecordedSession, t_s: FloatArray) -> NDArray[np.int64]:
    """The ROS stamps [ns] of the products' rows at session times ``t_s`` [s]."""
    return sess.t0_ns + np.round(t_s * 1e9).astype(np.int64)


def antenna_stream(sess: RecordedSession, name: str, b: RowBlock) -> TopicStream:
    """The ``/antenna/<name>/odom`` stream of an antenna's rows ``b`` (pose in ``enu`` with the
    smoother's covariance; twist in the antenna frame with the velocity covariance; angular rate
    not estimated)."""
    t_ns = antenna_stamps_ns(sess, b.traj.t_s)
    vals = cv.antenna_odometry_values(b.traj.llh, b.traj.vel_n_mps, b.traj.C_nb, b.sigma, sess.datum_llh)
    return TopicStream(T.antenna_odom(name), T.ODOMETRY, t_ns, rows=cv.odometry_rows(cv.WORLD_FRAME, cv.antenna_frame(name), t_ns, vals), qos="nav")


def antenna_streams(sess: RecordedSession, name: str, b: RowBlock) -> list[TopicStream]:
    """An antenna's two streams of rows ``b``: :func:`antenna_stream` and ``/antenna/<name>/fix``
    (sensor_msgs/NavSatFix: WGS-84 latitude / longitude [deg], ellipsoidal height, the rows'
    ENU position sigmas as a diagonal covariance; frame ``antenna_<name>``)."""
    t_ns = antenna_stamps_ns(sess, b.traj.t_s)
    fix = cv.navsatfix_rows(cv.antenna_frame(name), t_ns, b.traj.llh, b.sigma[:, 6:9])
    return [antenna_stream(sess, name, b), TopicStream(T.antenna_fix(name), T.NAVSATFIX, t_ns, rows=fix, qos="nav")]


def csv_columns(tr: NavSeries, s: FloatArray, flags: ta_flags.FlagArray | None, t_ns: NDArray[np.int64]) -> FloatArray:
    """The antenna CSV's columns after the stamp (N, 22), as :data:`CSV_FORMATS` formats them; the
    last three the rows' stamps ``t_ns`` (N,) [ns, GPS time] as GPS week, seconds of week and UTC
    (seconds since 1970, the leap seconds of the date)."""
    hpr = np.rad2deg(hpr_from_C_nb(tr.C_nb))
    fl = ta_flags.none(tr.t_s.size) if flags is None else flags
    t_ns = np.asarray(t_ns, dtype=np.int64)
    week, sow_ns = np.divmod(t_ns - GPS_EPOCH_UNIX_S * _NS, WEEK_S * _NS)
    return np.column_stack([
        np.rad2deg(tr.llh[:, 0]), np.rad2deg(tr.llh[:, 1]), tr.llh[:, 2], tr.vel_n_mps, hpr,
        s[:, 7], s[:, 6], s[:, 8], s[:, 3:6], np.rad2deg(s[:, 2]), np.rad2deg(s[:, 0]), np.rad2deg(s[:, 1]), fl,
        week, sow_ns / 1e9, gpst_to_utc_ns(t_ns) / 1e9,
    ])


#: the antenna CSV's header
CSV_HEADER = ("stamp_s,lat_deg,lon_deg,h_m,vel_e_mps,vel_n_mps,vel_u_mps,heading_deg,pitch_deg,roll_deg,"
              "sigma_north_m,sigma_east_m,sigma_h_m,sigma_vel_e_mps,sigma_vel_n_mps,sigma_vel_u_mps,"
              "sigma_heading_deg,sigma_rot_e_deg,sigma_rot_n_deg,flags,gps_week,gps_sow_s,utc_unix_s")


#: the column of the height above the geoid (``--geoid``), after :data:`CSV_HEADER`'s
GEOID_COLUMN = "h_geoid_m"
#: what the first line of the antenna CSV says without a geoid model
NO_GEOID_TEXT = "no geoid model given: heights are ellipsoidal (WGS-84)"


def csv_header(geoid: GeoidGrid | None = None) -> str:
    """The antenna CSV's header: a comment line (``#``) naming the datum, the time scales and the
    geoid model (its file name, or :data:`NO_GEOID_TEXT`), then the column names (:data:`CSV_HEADER`,
    and :data:`GEOID_COLUMN` with a ``geoid``)."""
    model = NO_GEOID_TEXT if geoid is None else f"geoid model {geoid.name}: {GEOID_COLUMN} = h_m - N, N bilinear in its grid"
    return (f"# dpos antenna poses; datum WGS-84 (the GNSS frame), h_m ellipsoidal; stamp_s GPS time on the Unix calendar "
            f"(no leap seconds), gps_week/gps_sow_s GPS time, utc_unix_s UTC; {model}\n"
            + CSV_HEADER + ("," + GEOID_COLUMN if geoid is not None else ""))


#: the format of :data:`GEOID_COLUMN`
GEOID_FORMAT = ("f", 4)

#: the antenna CSV's columns after the stamp (``%.10f`` = ("f", 10), ``%.4e`` = ("e", 4), ``%d`` = ("d", 0))
CSV_FORMATS: tuple[tuple[str, int], ...] = (
    (("f", 10),) * 2 + (("f", 4),) + (("f", 5),) * 3 + (("f", 6),) * 3 + (("e", 4),) * 9 + (("d", 0),) * 2 + (("f", 9),) + (("f", 6),))


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
    return K.pow10_table(), K.log10_floor_starts()


class CsvRows:
    """The rows of :func:`write_csv_rows` block after block (``formats`` (m,) as there), written
    into one byte buffer kept between the blocks (grown when a block needs more)."""

    #: rows formatted at a time by :meth:`write` (their text, ~1 MB, stays in the CPU's cache
    #: until written: 65 536 rows at a time cost ~1.4x the CPU)
    WRITE_ROWS = 4096

    def __init__(self, formats: tuple[tuple[str, int], ...]) -> None:
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
