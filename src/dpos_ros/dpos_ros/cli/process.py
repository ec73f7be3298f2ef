"""``dpos-process``: transfer alignment of a recorded session, offline, through the same code as
transfer_align_node; writes the session products (design.md) and metrics when truth is recorded.

    dpos-process /tmp/paper_su_s1 --out /tmp/products                 # UPS (the default)
    dpos-process /tmp/paper_su_s1 --method ups --particles 100 --out /tmp/products
    dpos-process BAG --method ups --aircraft my_aircraft.yaml --out DIR
    dpos-process BAG --out DIR --overwrite                            # replace DIR/<session id>/
    dpos-process BAG --out DIR --workers 1                            # the sub-IMUs one after the other
    dpos-process BAG --out DIR --master-reference smoothed            # main POS: the IFA re-run and RTS-smoothed
    dpos-process BAG --out DIR --stream on                            # a long flight: the rows spilled to disk
    dpos-process BAG --out DIR --geoid egm96-5.pgm                    # the antenna CSVs' heights above the geoid too

The recording is read, aligned and written a part of the flight at a time (docs/long_flights.md):
each worker reads its own sub-IMU's topic and the main POS only; the wing fit is made over
5-minute windows; the truth, when recorded, is evaluated against a part at a time
(dpos_ros.products.evaluate).  ``--stream`` says only where the antennas' rows are held between
the alignment and the products: ``off`` in memory, ``on`` in files beside the products (memory
that does not grow with the flight), ``auto`` (the default) ``on`` for a recording of more than
an hour; the products are the same either way.

``--geoid FILE``: a geoid grid (GeographicLib ``.pgm``, e.g. egm96-5.pgm, or NOAA/PROJ ``.gtx``;
docs/transfer_alignment.md "Heights above the geoid"): each antenna CSV gains ``h_geoid_m``, the height above that geoid, and its first
line names the model; without it the CSV says its heights are ellipsoidal.  A file that is not
such a grid, or a grid that does not cover the main POS's track, is exit 2 before any work.

Progress (stages, a line per sub-IMU and per antenna) is drawn on stderr when it is a terminal,
not with ``--quiet`` nor into a file or a pipe; the results (stdout) are the same either way.

``--master-reference``: the main-POS reference of the transfer alignment - ``recorded`` (default,
the recording's /master/nav), ``forward`` (the in-flight alignment re-run from /master/imu,
/gnss/fix and /gnss/vel with the aircraft file's GNSS lever arm and main IMU model) or
``smoothed`` (that run, RTS-smoothed forward-backward); with /truth/master its accuracy is printed.

Exit status: 0 when every antenna of the aircraft is estimated; 1 when some (or all) are not
(named, with why; the products are written); 2 for unusable input or output (a bad option, an
unreadable recording or aircraft file, an existing DIR/<session id>/ without --overwrite, an
output that cannot be written) - then nothing partial is left, and with --overwrite the earlier
products are kept.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import sys
from functools import partial
from pathlib import Path

import numpy as np

from dpos_core.config import AircraftConfig, ConfigError, load_aircraft
from dpos_core.errors import InputError
from dpos_core.geoid import GeoidGrid, load_geoid
from dpos_core.ta.pipeline import METHODS, TASettings
from dpos_core.ta.warmup import warm_up
from dpos_ros.cli.options import MAX_PARTICLES, MAX_RATE_HZ, one_line_errors
from dpos_ros.cli.progress import Stages
from dpos_ros.io.bag import topics_and_duration
from dpos_ros.io.outdir import PRODUCTS_MARKER, OutputError, OutputTarget, child_dir, is_products_dir, os_error_text
from dpos_ros.io.session import MASTER_SOURCE_KEY, MASTER_SOURCE_SOLUTION, RecordedSession, SessionError, read_session
from dpos_ros.products.antenna import AntennaSolution
from dpos_ros.products.evaluate import evaluate
from dpos_ros.products.master_reference import (
    AUTO_TAU,
    GNSS_INS_ERROR_TAU_S,
    REFERENCES,
    accuracy,
    aligned_since,
    master_error_tau,
    master_reference,
)
from dpos_ros.products.rows import scratch_dir
from dpos_ros.products.solve import SubImuSource, solve
from dpos_ros.products.write import ProductsExistError, WriteOptions, write
from dpos_ros.runtime.pool import default_workers, max_workers, warm_pool

#: --stream auto: the rows spilled to disk for recordings longer than this [s]
STREAM_AUTO_S = 3600.0

EXIT_OK = 0
EXIT_NOT_ESTIMATED = 1
EXIT_ERROR = 2


def parser() -> argparse.ArgumentParser:
    """The command line of dpos-process (its ``--method`` choices are the core's METHODS)."""
    ap = argparse.ArgumentParser(prog="dpos-process", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="rosbag2 directory of the session")
    ap.add_argument("--method", choices=METHODS, default="ups",
                    help="default ups ([Gong2018]'s unscented particle smoother); urtss is the Gaussian smoother")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0, help="random seed of the particle methods")
    ap.add_argument("--filter-rate", type=float, default=1.0, metavar="HZ", help="filter update rate (default 1 Hz, [Gong2018])")
    ap.add_argument("--no-position-matching", dest="position_matching", action="store_false",
                    help="match attitude and velocity only ([Gong2018]); default: the lever-arm-compensated main-POS position too")
    ap.add_argument("--master-error-tau", type=_tau, default=AUTO_TAU, metavar="S|auto",
                    help="correlation time of the main POS's position and velocity errors: > 0 estimates them as states and the "
                         "antennas follow the main POS (docs/mismatch.md 'Installation states'); 0 = white noise; auto (default) "
                         f"= {GNSS_INS_ERROR_TAU_S:g} s for a GNSS/INS main POS (pos_master_node's, --master-reference forward or "
                         "smoothed), 0 for the simulator's reference main POS")
    ap.add_argument("--no-sigma-inflation", dest="inflate_sigma", action="store_false",
                    help="report the smoother's own 1-sigma, without the innovations' variance factor (docs/qc.md)")
    ap.add_argument("--output-rate", type=float, default=0.0, metavar="HZ", help="rate of the antenna poses (default 0 = the sub-IMU rate)")
    ap.add_argument("--workers", type=int, default=0, metavar="N",
                    help="worker processes aligning the sub-IMUs in parallel (default 0 = one per core, or $DPOS_WORKERS; 1 = serial); "
                         "they start, and load the filters, while the recording is read; the results do not depend on it")
    ap.add_argument("--aircraft", help="aircraft configuration (default: the one embedded in the recording)")
    ap.add_argument("--initial-attitude-error", type=float, metavar="DEG",
                    help="initial sub-IMU attitude error per axis (default: the recording's transfer_alignment setting, else 0)")
    ap.add_argument("--master-reference", choices=REFERENCES, default="recorded",
                    help="main-POS reference: recorded /master/nav (default), forward = the in-flight alignment re-run from "
                         "/master/imu + /gnss/*, smoothed = that run RTS-smoothed")
    ap.add_argument("--stream", choices=("auto", "on", "off"), default="auto",
                    help="where the rows are held: on = spilled to files beside the products (long flights), off = in memory; "
                         f"auto (default) = on above {STREAM_AUTO_S / 3600:g} h of recording; the products are the same")
    ap.add_argument("--out", type=Path, required=True, help="output directory (products go to OUT/<session id>/, a new directory)")
    ap.add_argument("--geoid", type=Path, metavar="FILE",
                    help="geoid grid (GeographicLib .pgm or NOAA/PROJ .gtx): the antenna CSVs get h_geoid_m, the height above it "
                         "(default: none; the CSV says its heights are ellipsoidal, WGS-84)")
    ap.add_argument("--figures", choices=("on", "off"),
                    help="the PNG figures (qc/<antenna>_qc.png, errors_<antenna>.png; about a second of CPU each): "
                         "default on, or $DPOS_FIGURES (on/off)")
    ap.add_argument("--quiet", action="store_true", help="no progress on the terminal (none is shown when stderr is not one)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an existing OUT/<session id>/: the new products are swapped in when complete "
                         "(the old ones are kept if the run fails)")
    return ap


def _write_options(args: argparse.Namespace) -> WriteOptions:
    """The products' :class:`WriteOptions` of the command line (``--figures`` over ``$DPOS_FIGURES``)."""
    if args.figures is None:
        return WriteOptions(overwrite=args.overwrite, geoid=args.geoid_grid)
    return WriteOptions(overwrite=args.overwrite, geoid=args.geoid_grid, figures=args.figures == "on")


def _tau(text: str) -> float:
    """``--master-error-tau``: ``auto`` or seconds >= 0."""
    if text == "auto":
        return AUTO_TAU
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds nor 'auto': {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be >= 0 s or 'auto', got {text}")
    return v


def _master_error(args: argparse.Namespace, sess: RecordedSession, which: str) -> float:
    """The main POS's error model of ``--master-error-tau`` (:func:`master_error_tau`): printed, and
    kept for status.json (``sess.master_error_model``)."""
    tau, why = master_error_tau(args.master_error_tau, sess.master_mechanized, which,
                                imported=sess.custom.get(MASTER_SOURCE_KEY) == MASTER_SOURCE_SOLUTION)
    sess.master_error_model = {"tau_s": tau, "why": why}
    print(f"dpos-process: main POS errors: {'white noise' if tau == 0 else f'correlated, {tau:g} s, estimated as states'} ({why})")
    return tau


def settings(args: argparse.Namespace, sess: RecordedSession, master_error_tau_s: float) -> TASettings:
    """The transfer alignment's settings of the command line (the core's names; transfer_align_node
    makes the same object from its parameters, ``TransferAlignConfig.core_config()``): the initial
    attitude error ``--initial-attitude-error``, else the recording's transfer_alignment setting,
    else 0; ``master_error_tau_s`` resolved from ``--master-error-tau`` (:func:`_master_error`)."""
    return TASettings(method=args.method, particles=args.particles, seed=args.seed, filter_rate_hz=args.filter_rate,
                      use_position=args.position_matching, master_error_tau_s=master_error_tau_s, initial_attitude_error_deg=_initial_error(args, sess),
                      inflate_sigma=args.inflate_sigma, output_rate_hz=args.output_rate)


def _initial_error(args: argparse.Namespace, sess: RecordedSession) -> float:
    """The initial sub-IMU attitude error [deg] (:func:`settings`)."""
    ta = json.loads(sess.custom.get("dpos.transfer_alignment", "{}") or "{}")
    return float(args.initial_attitude_error) if args.initial_attitude_error is not None else float(ta.get("initial_attitude_error_deg", 0.0))


def _check_numbers(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.particles < 1:
        ap.error(f"--particles must be >= 1, got {args.particles}")
    if args.particles > MAX_PARTICLES:
        ap.error(f"--particles must be <= {MAX_PARTICLES} (the filter's arrays grow with it), got {args.particles}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    if args.workers < 0:
        ap.error(f"--workers must be >= 0 (0 = one per core), got {args.workers}")
    if args.workers > max_workers():
        ap.error(f"--workers must be <= {max_workers()} (4 per core), got {args.workers}")
    if not (math.isfinite(args.filter_rate) and 0 < args.filter_rate <= MAX_RATE_HZ):
        ap.error(f"--filter-rate must be > 0 and <= {MAX_RATE_HZ:g} Hz, got {args.filter_rate:g}")
    if not (math.isfinite(args.output_rate) and 0 <= args.output_rate <= MAX_RATE_HZ):
        ap.error(f"--output-rate must be >= 0 (0 = the sub-IMU rate) and <= {MAX_RATE_HZ:g} Hz, got {args.output_rate:g}")
    if args.initial_attitude_error is not None and not math.isfinite(args.initial_attitude_error):
        ap.error(f"--initial-attitude-error must be a finite number of degrees, got {args.initial_attitude_error:g}")


def not_estimated(antennas: dict[str, AntennaSolution], aircraft_name: str, sub_imus: list[str]) -> str | None:
    """Why the run's exit status is 1 (one line), or None when every configured antenna is estimated."""
    if not antennas:
        return f"no antenna was estimated: the aircraft {aircraft_name!r} configures no antenna"
    missing = {name: a.status for name, a in antennas.items() if a.rows is None}
    n_antennas = len(antennas)
    if not missing:
        return None
    why = "; ".join(f"{name}: {status}" for name, status in missing.items())
    if len(missing) < n_antennas:
        return f"{len(missing)} of {n_antennas} antennas not estimated ({why})"
    text = f"no antenna was estimated ({why})"
    if not sub_imus:
        text += "; the recording has no /sub_imu/<name>/imu topic"
    return text


@one_line_errors("dpos-process")
def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    _check_numbers(ap, args)
    try:
        args.geoid_grid = None if args.geoid is None else load_geoid(args.geoid)
    except InputError as e:
        print(f"dpos-process: error: --geoid {e}", file=sys.stderr)
        return EXIT_ERROR
    try:
        target = OutputTarget(args.out)
    except OutputError as e:
        print(f"dpos-process: error: --out {e}", file=sys.stderr)
        return EXIT_ERROR
    # the workers start and load the filters while the recording is read (runtime.pool.warm_pool)
    try:
        n_workers = args.workers or default_workers()
    except ValueError as e:
        print(f"dpos-process: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    pool = warm_pool(n_workers, partial(warm_up, args.method))[0] if n_workers != 1 else None
    try:
        return _process(args, target, pool)
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _aircraft(args: argparse.Namespace, sess: RecordedSession) -> AircraftConfig:
    """The aircraft: ``--aircraft``, else the one embedded in the recording; SessionError without either."""
    if args.aircraft:
        return load_aircraft(args.aircraft)
    if "dpos.aircraft_yaml" in sess.custom:
        return load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
    raise SessionError(f"{args.bag} carries no aircraft configuration: pass --aircraft")


def _refuse_existing(final: Path) -> int:
    print(f"dpos-process: error: {final} exists (products of an earlier run): pass --overwrite to replace them, "
          "or choose another --out", file=sys.stderr)
    return EXIT_ERROR


def _spilled(args: argparse.Namespace, meta: tuple | None) -> bool:
    """Whether ``--stream`` (module docstring) spills the rows to disk for this recording."""
    if args.stream != "auto":
        return args.stream == "on"
    return meta is not None and meta[1] > STREAM_AUTO_S


def _read_error(e: Exception, bag: Path) -> int:
    """Exit 2 for an unusable recording or aircraft, with its one-line error."""
    what = f"cannot read the recording: {os_error_text(e, bag)}" if isinstance(e, OSError) else str(e)
    print(f"dpos-process: error: {what}", file=sys.stderr)
    return EXIT_ERROR


def _write_error(e: OSError, target: OutputTarget, final: Path, had_products: bool) -> int:
    """Exit 2 when the products could not be written: they appeared while processing
    (:class:`ProductsExistError`), or the disk refused them (the partial products are removed)."""
    if isinstance(e, ProductsExistError):
        print(f"dpos-process: error: {final} appeared while processing: pass --overwrite to replace it", file=sys.stderr)
        return EXIT_ERROR
    target.cleanup()
    kept = f"; the earlier products in {final} are kept" if had_products else ""
    print(f"dpos-process: error: writing the products to {final} failed: {os_error_text(e, final)}; "
          f"the partial products were removed{kept}", file=sys.stderr)
    return EXIT_ERROR


def _summary(antennas: dict, timing: dict[str, float], out: Path) -> None:
    for name, a in antennas.items():
        print(f"  {name}: {a.status}")
    print(f"processing {timing['processing_s']:.1f} s for {timing['data_s']:.0f} s of sub-IMU data "
          f"(ratio {timing['processing_s'] / max(timing['data_s'], 1e-9):.4f})")
    print(f"products in {out}")


def _process(args: argparse.Namespace, target: OutputTarget, pool: cf.Executor | None) -> int:
    """:func:`main` once the output target is checked: read the main POS, align the sub-IMUs (each
    worker of ``pool`` reading its own from the recording), evaluate, write."""
    st = Stages("dpos-process", quiet=args.quiet)
    st.stage(f"reading the main POS of {args.bag}")
    try:
        meta = topics_and_duration(args.bag)
        source: SubImuSource | None = None
        if meta is None:  # (not a rosbag2 recording with its metadata: read whole)
            sess = read_session(args.bag)
            topics, subs = None, sorted(sess.sub_imus)
        else:
            topics = meta[0]
            subs = sorted(t.split("/")[2] for t in topics if t.startswith("/sub_imu/") and t.endswith("/imu") and t.count("/") == 3)
            if args.master_reference == "recorded":
                sess = read_session(args.bag, keep=lambda t: False)  # the main POS only
            else:  # the main POS's inputs (/master/imu, /gnss/*) and truth too
                sess = read_session(args.bag, keep=lambda t: not t.startswith(("/sub_imu/", "/truth/antenna/")))
            source = SubImuSource(bag=str(args.bag), read_master=args.master_reference == "recorded")
        aircraft = _aircraft(args, sess)
        ref = master_reference(sess, aircraft, args.master_reference)
    except (SessionError, ConfigError, OSError) as e:
        return _read_error(e, args.bag)
    if args.geoid_grid is not None and (why := _geoid_gap(args.geoid_grid, sess)) is not None:
        print(f"dpos-process: error: --geoid {args.geoid}: {why}", file=sys.stderr)
        return EXIT_ERROR
    for w in sess.warnings:
        print(f"dpos-process: warning: {w}", file=sys.stderr)
    try:  # the session id is a safe name (RecordedSession); the directory must stay under --out
        final = child_dir(args.out, sess.session_id)
    except OutputError as e:
        print(f"dpos-process: error: --out {e}", file=sys.stderr)
        return EXIT_ERROR
    had_products = final.exists() or final.is_symlink()
    if had_products and not args.overwrite:
        return _refuse_existing(final)
    if had_products and not is_products_dir(final):
        print(f"dpos-process: error: {final} exists and is not a dpos products directory (no {PRODUCTS_MARKER}): "
              "--overwrite replaces only products dpos wrote; choose another --out", file=sys.stderr)
        return EXIT_ERROR
    err0 = _initial_error(args, sess)
    if ref.which != "recorded":
        _print_reference(ref, sess)
    n_read = len(sess.warnings)
    spill = _spilled(args, meta)
    print(f"dpos-process: session {sess.session_id}: {len(subs)} sub-IMU(s), {sess.master.t_s[-1] - sess.master.t_s[0]:.0f} s, "
          f"method {args.method}, initial attitude error {err0:g} deg{' (rows spilled to disk)' if spill else ''}")
    try:
        with scratch_dir(args.out) as tmp:
            ta = settings(args, sess, _master_error(args, sess, ref.which))
            n_subs = sum(s.name in subs for s in aircraft.sub_imus)
            st.stage(f"aligning {n_subs} sub-IMU(s) with {args.method} on {getattr(pool, 'n_workers', 1)} worker(s)")
            with st.solving(n_subs) as progress:
                antennas, timing = solve(sess, aircraft, ta, source=source, store_dir=Path(tmp) if spill else None, pool=pool,
                                         sub_imus=subs, progress=progress)
            if topics is None or any(tp.startswith("/truth/") for tp in topics):
                st.stage("evaluating against the recorded truth")
            ev = evaluate(sess, antennas, topics)  # against the truth, a part at a time (none without it)
            for w in sess.warnings[n_read:]:  # (the workers' reading of the sub-IMUs, the alignment, the evaluation)
                print(f"dpos-process: warning: {w}", file=sys.stderr)
            n_est = sum(a.rows is not None for a in antennas.values())
            st.stage(f"writing the products of {n_est} antenna(s) (CSV, QC, antenna bag, tracks)")
            with st.writing(n_est) as progress:
                out = write(args.out, sess, antennas, args.method, timing, ev or None, pool=pool,
                            options=_write_options(args), progress=progress)
            st.stage("done")
    except OSError as e:  # (ProductsExistError: appeared while processing) ENOSPC, EACCES, EROFS, EIO: partial products removed
        return _write_error(e, target, final, had_products)
    _summary(antennas, timing, out)
    if ev:
        print((out / "report.md").read_text())
    problem = not_estimated(antennas, aircraft.name, subs)
    if problem is not None:
        print(f"dpos-process: {problem}", file=sys.stderr)
        return EXIT_NOT_ESTIMATED
    return EXIT_OK


def _geoid_gap(geoid: GeoidGrid, sess: RecordedSession) -> str | None:
    """Why ``geoid`` cannot give the heights above it along the main POS's track (one line), or None."""
    llh = sess.master.llh
    bad = ~np.isfinite(geoid.undulation(llh[:, 0], llh[:, 1]))
    if not bad.any():
        return None
    k = int(np.flatnonzero(bad)[0])
    return (f"the grid ({geoid.extent_text()}) does not cover the track: {int(bad.sum())} of {bad.size} main-POS epochs "
            f"outside it or on nodes without value, the first at latitude {np.rad2deg(llh[k, 0]):.4f}, longitude "
            f"{np.rad2deg(llh[k, 1]):.4f} deg")


def _print_reference(ref, sess: RecordedSession) -> None:
    """The main-POS reference re-run (``--master-reference forward | smoothed``): its summary, its
    notes as warnings and, with /truth/master, its accuracy; ``sess.master`` becomes it."""
    i = ref.info
    print(f"dpos-process: main POS: {i['source']}: start {i['start_s']:.1f} s, aligned "
          f"{'never' if i['aligned_s'] is None else format(i['aligned_s'], '.1f') + ' s'}, {i['fixes']} fixes "
          f"({i['rejected_fixes']} rejected), {i['runtime_s']:.1f} s")
    for note in i["notes"]:
        print(f"dpos-process: warning: main POS: {note}", file=sys.stderr)
    sess.master = ref.nav
    if "master" in sess.truth:
        since = aligned_since(sess.master)
        try:
            acc = accuracy(sess.master, sess.truth["master"], since)
            print(f"dpos-process: main POS ({ref.which}) against /truth/master from {since:.1f} s (attitude 1-sigma < 0.1 deg): RMSE heading/pitch/roll "
                  f"{', '.join(f'{v:.4f}' for v in acc['hpr_deg'])} deg, velocity {', '.join(f'{v:.4f}' for v in acc['vel_mps'])} m/s, "
                  f"position {', '.join(f'{v:.3f}' for v in acc['pos_m'])} m")
        except ValueError:
            pass


if __name__ == "__main__":
    raise SystemExit(main())
