"""``dpos-ifa``: the main POS's in-flight alignment on a recording, offline, through the same core
and the same parameters as the live graph (ifa_node's parameter file, pos_master_node's start
rule), with a report and plots against a reference solution when one is given.

    dpos-ifa out/walk_0827_1hz --params-file data/real/walk_0827/ifa_node.yaml --min-course-speed 0 \\
        --reference data/real/walk_0827/gnss_1730_sf.pos --outage 60:75 --out out/walk_ifa

Topics: the product's (``/master/imu``, ``/gnss/fix``, ``/gnss/vel``: a recorded live graph) when
the bag has them, else real drivers' (``/imu/data``, ``/fix``, ``/vel``: ``dpos-import``); the
``--*-topic`` options name others.  Times in the report are seconds after the first IMU sample.
Writes ``OUT/nav.csv`` (the navigation at the IMU rate with its 1-sigma), ``OUT/report.md``,
``OUT/report.json`` and ``OUT/ifa.png``.  With ``--smooth`` also the forward-backward (RTS)
navigation of :mod:`dpos_core.ifa.smoother`, scored as the forward one: ``OUT/nav_smoothed.csv``
(nav.csv's columns, each row's smoothed 1-sigma) and ``OUT/nav_smoothed.pos`` (RTKLIB ``.pos``
columns, :mod:`dpos_core.ifa.pos_file`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np

from dpos_core import earth, plausibility
from dpos_core.attitude import quat_to_dcm
from dpos_core.config.aircraft import AircraftConfig
from dpos_core.frames import hpr_from_C_nb
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.ifa.pipeline import IfaResult, run
from dpos_core.ifa.pos_file import gnss_support, write_pos
from dpos_core.ifa.reference import Reference, compare, start, track_sigmas
from dpos_core.ifa.smoother import as_result, smooth
from dpos_core.ifa.time_offset import estimate_time_offset
from dpos_core.imports.logs import LogFormatError, read_pos
from dpos_core.series import GnssSeries, ImuSeries
from dpos_core.units import DEG, FloatArray
from dpos_ros.cli.options import finite_float, float_in, one_line_errors
from dpos_ros.contract import conversions as cv
from dpos_ros.devices.relay import rotation_from_rpy_deg
from dpos_ros.io.bag import read_raw
from dpos_ros.io.gnss_ins import DRIVER_TOPICS, PRODUCT_TOPICS, InputError, _topics, deserialize, read_recording
from dpos_ros.io.outdir import atomic_path

#: --gnss-time-offset and --estimate-time-offset bounds [ms]: a receiver's clock is off the IMU's by
#: far less than a minute; the candidates are one IFA run each
MAX_OFFSET_MS = 60_000.0
MAX_OFFSET_CANDIDATES = 2001


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="dpos-ifa", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="rosbag2 directory")
    ap.add_argument("--params-file", type=Path, required=True, help="ifa_node's ROS parameter file (ifa_node: ros__parameters:)")
    ap.add_argument("--min-course-speed", type=float_in(0.0, unit=" m/s"), default=5.0, metavar="MPS",
                    help="pos_master_node's min_course_speed_mps: the start is the first fix at least this fast (default 5)")
    ap.add_argument("--initial-heading", type=finite_float, metavar="DEG", help="pos_master_node's initial_state heading below that speed")
    ap.add_argument("--input-rotation-rpy-deg", metavar="R,P,Y", default="0,0,0",
                    help="pos_master_node's input_rotation_rpy_deg: the driver's IMU axes in the body's FLU axes")
    ap.add_argument("--imu-topic")
    ap.add_argument("--fix-topic")
    ap.add_argument("--vel-topic")
    ap.add_argument("--reference", type=Path, help="reference solution (RTKLIB .pos) to compare with; default: the bag's own fixes")
    ap.add_argument("--outage", metavar="START:END", help="report before / during / after this GNSS outage [s after the first IMU sample]")
    ap.add_argument("--method", choices=("add2", "dd2", "aekf"), help="override the parameter file's method")
    ap.add_argument("--live", type=Path, metavar="REC",
                    help="a dpos-record recording of the live graph on this bag (/master/nav, /dpos/datum, /ifa/status, "
                         "/pos_master/status): its navigation against the offline one and the reference, its counters")
    ap.add_argument("--estimate-time-offset", metavar="MIN:MAX:STEP",
                    help="estimate the GNSS-IMU time offset [ms] over these candidates (dpos_core.ifa.time_offset: the "
                         "fixed-noise filter's innovations; says when the data do not make it observable)")
    ap.add_argument("--gnss-time-offset", type=float_in(-MAX_OFFSET_MS, MAX_OFFSET_MS, unit=" ms"), metavar="MS",
                    help="override the parameter file's gnss_time_offset_s [ms]: GNSS stamps minus the IMU time of the same "
                         "instant (a receiver stamping 50 ms late: +50); the value --estimate-time-offset prints is this one")
    ap.add_argument("--start-level", choices=("raw", "auto"), default="auto",
                    help="raw: level on the mean specific force before the start fix (pos_master_node's live rule); "
                         "auto (default): as raw at rest (standstill test), in motion with the GNSS acceleration removed and the level "
                         "sigma widened to what is left (dpos_core.ifa.standstill)")
    ap.add_argument("--standstill-updates", choices=("on", "off"),
                    help="the zero-angular-rate update about the vertical (ZARU) at the epochs detected at rest (ifa_node's "
                         "standstill_updates; default: as the parameter file, on unless it says otherwise; docs/ifa.md)")
    ap.add_argument("--nhc", action="store_true",
                    help="the non-holonomic constraint of a wheeled ground vehicle (ifa_node's nhc true): no sideways or vertical "
                         "body velocity; only with the IMU's axes the vehicle's (--input-rotation-rpy-deg)")
    ap.add_argument("--smooth", action="store_true",
                    help="also the forward-backward (RTS) smoothed navigation, post-processing: OUT/nav_smoothed.csv and "
                         "OUT/nav_smoothed.pos (RTKLIB .pos columns), scored against the reference as the forward one")
    ap.add_argument("--out", type=Path, required=True)
    return ap


def _write_nav(path: Path, res: IfaResult, origin_ns: int, title: str | None = None) -> None:
    """nav.csv's columns; ``title``: a ``#`` line before the column names (what the solution is)."""
    tt, sig = track_sigmas(res)
    j = np.clip(np.searchsorted(tt, res.t_s, side="right") - 1, 0, max(tt.size - 1, 0))
    s = sig[j] if tt.size else np.full((res.t_s.size, 9), np.nan)
    hpr = hpr_from_C_nb(quat_to_dcm(res.q_nb)) / DEG
    cols = np.column_stack([origin_ns + np.round(res.t_s * 1e9).astype(np.int64), res.t_s, res.llh[:, 0] / DEG, res.llh[:, 1] / DEG,
                            res.llh[:, 2], res.vel_n_mps, hpr, s[:, 0:6], s[:, 6:9] / DEG])
    head = ("t_ns,t_s,lat_deg,lon_deg,h_m,vE_mps,vN_mps,vU_mps,heading_deg,pitch_deg,roll_deg,sE_m,sN_m,sU_m,svE_mps,svN_mps,svU_mps,"
            "s_attE_deg,s_attN_deg,s_attU_deg")
    if title is not None:
        head = f"# {title}\n{head}"
    with atomic_path(path) as tmp:  # a full disk leaves no partial nav.csv
        np.savetxt(tmp, cols, delimiter=",", header=head, comments="", fmt=["%d", "%.6f", "%.9f", "%.9f"] + ["%.6f"] * 16)


#: the title line of nav_smoothed.csv
SMOOTHED_TITLE = ("dpos-ifa --smooth: forward-backward (RTS) smoothed navigation of the final heading hypothesis, "
                  "each row's smoothed 1-sigma (post-processing: uses the fixes after the row)")


def _write_smoothed(out: Path, res: IfaResult, smoothed: IfaResult, origin_ns: int, predict_interval_s: float, what: str) -> None:
    """``nav_smoothed.csv`` and ``nav_smoothed.pos`` of a smoothed run (``as_result``)."""
    _write_nav(out / "nav_smoothed.csv", smoothed, origin_ns, SMOOTHED_TITLE)
    P = np.array([p for _, p in smoothed.track])
    support = gnss_support(smoothed.t_s, res.epochs_s, predict_interval_s, smoothed=True)
    t_ns = origin_ns + np.round(smoothed.t_s * 1e9).astype(np.int64)
    with atomic_path(out / "nav_smoothed.pos") as tmp:  # a full disk leaves no partial file
        write_pos(tmp, t_ns, smoothed.llh, P[:, 0:3, 0:3], smoothed.vel_n_mps, P[:, 3:6, 3:6], support,
                  comments=[f"dpos-ifa --smooth: {what}", "forward-backward (RTS) smoothed main POS at the IMU, IMU rate; "
                            f"Q 1: a GNSS update within {predict_interval_s:g} s on both sides, Q 5: bridged across a longer gap; "
                            "ns: GNSS updates within that time (0-2); age: time to the nearest one [s]",
                            "columns: dpos_core.ifa.pos_file"])


def _plot(path: Path, res: IfaResult, ref: Reference, outage: tuple[float, float] | None, smoothed: IfaResult | None = None) -> None:
    """ifa.png: horizontal and up error against the reference with the reported 3 sigma, heading
    sigma and NIS; ``smoothed`` (``--smooth``): its horizontal error and 3 sigma too."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    inside = (ref.t_s > res.t_s[0]) & (ref.t_s < res.t_s[-1])
    tr = ref.t_s[inside]
    k = np.clip(np.searchsorted(res.t_s, tr), 0, res.t_s.size - 1)
    err = np.array([earth.enu_between(a, b) for a, b in zip(res.llh[k], ref.llh[inside])])
    tt, sig = track_sigmas(res)
    fig, ax = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    ax[0].plot(tr, np.hypot(err[:, 0], err[:, 1]), label="horizontal error vs reference")
    ax[0].plot(tt, 3 * np.hypot(sig[:, 0], sig[:, 1]), label="3 sigma (reported)")
    if smoothed is not None:
        ks = np.clip(np.searchsorted(smoothed.t_s, tr), 0, smoothed.t_s.size - 1)
        es = np.array([earth.enu_between(a, b) for a, b in zip(smoothed.llh[ks], ref.llh[inside])])
        ts, ss = track_sigmas(smoothed)
        ax[0].plot(tr, np.hypot(es[:, 0], es[:, 1]), label="smoothed: horizontal error")
        ax[0].plot(ts, 3 * np.hypot(ss[:, 0], ss[:, 1]), label="smoothed: 3 sigma")
    ax[0].set_ylabel("m")
    ax[0].set_yscale("log")
    ax[1].plot(tr, err[:, 2], label="up error")
    ax[1].plot(tt, 3 * sig[:, 2], "k--", tt, -3 * sig[:, 2], "k--", lw=0.8)
    ax[1].set_ylabel("m")
    ax[2].plot(res.epochs_s, res.heading_sigma_deg, label="heading sigma")
    ax[2].plot(res.epochs_s, res.nis_window, label="window-mean NIS")
    ax[2].set_yscale("log")
    ax[2].set_xlabel("s after the first IMU sample")
    for a in ax:
        if outage:
            a.axvspan(*outage, color="0.9")
        a.legend(loc="upper right")
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _check_plausible(bag: Path, topics: tuple[str, str, str], imu: ImuSeries, gnss: GnssSeries) -> None:
    """InputError in one line when the recording's values show a unit mistake (dpos_core.plausibility,
    as dpos-import and read_session check theirs): the IMU in m/s^2 read as g or the reverse, in rad/s
    read as deg/s or the reverse (its own values, then its rates against the course of the fixes),
    or fixes whose position sigmas are all zero."""
    found = plausibility.check_imu_with_track(f"{bag}: {topics[0]}", imu.t_s, imu.omega_radps, imu.f_mps2, gnss.t_s, gnss.llh,
                                              topics[1])
    sig = plausibility.check_fix_sigmas(f"{bag}: {topics[1]}", gnss.pos_sigma_m)
    found += [sig] if sig is not None else []
    if found:
        raise InputError(str(found[0]))


#: ``(params_file, method override) -> (filter configuration, aircraft, method, GNSS lever arm [m] (3,))``:
#: how the node's parameter file becomes the core's settings (``ifa_node.offline``, which owns the
#: node's configuration class); raises :class:`~dpos_core.errors.InputError` naming the file
ConfigLoader = Callable[[Path, str | None], tuple[IfaFilterConfig, AircraftConfig, str, FloatArray]]


@one_line_errors("dpos-ifa")
def main(argv: list[str] | None, load_config: ConfigLoader) -> int:
    """Run ``dpos-ifa`` with ``argv`` (None: the command line), the parameter file read by
    ``load_config``; the exit status (2: unusable input).  The console script is ``ifa_node.offline:main``."""
    ap = parser()
    args = ap.parse_args(argv)
    try:
        rpy = [float(v) for v in args.input_rotation_rpy_deg.split(",")]
        if len(rpy) != 3:
            raise ValueError
    except ValueError:
        ap.error(f"--input-rotation-rpy-deg takes 'R,P,Y' [deg], got {args.input_rotation_rpy_deg!r}")
    outage = None
    if args.outage:
        try:
            a, b = (float(v) for v in args.outage.split(":"))
        except ValueError:
            ap.error(f"--outage takes START:END [s], got {args.outage!r}")
        if not (np.isfinite(a) and np.isfinite(b) and b > a):
            ap.error(f"--outage END must be after START (finite seconds), got {args.outage!r}")
        outage = (a, b)
    if args.out.exists() and not args.out.is_dir():
        ap.error(f"--out {args.out} is a file, not a directory")
    offsets = None
    if args.estimate_time_offset:
        try:
            lo, hi, step = (float(v) for v in args.estimate_time_offset.split(":"))
        except ValueError:
            ap.error(f"--estimate-time-offset takes MIN:MAX:STEP [ms], got {args.estimate_time_offset!r}")
        if not (np.isfinite([lo, hi, step]).all() and step > 0 and hi >= lo + 2 * step):
            ap.error(f"--estimate-time-offset needs finite values, STEP > 0 and at least 3 candidates, got {args.estimate_time_offset!r}")
        if max(abs(lo), abs(hi)) > MAX_OFFSET_MS or (hi - lo) / step > MAX_OFFSET_CANDIDATES:
            ap.error(f"--estimate-time-offset allows offsets within +-{MAX_OFFSET_MS:g} ms and at most "
                     f"{MAX_OFFSET_CANDIDATES} candidates (one IFA run each), got {args.estimate_time_offset!r}")
        offsets = np.arange(lo, hi + 0.5 * step, step) * 1e-3

    try:
        cfg, aircraft, method, lever = load_config(args.params_file, args.method)
        if args.gnss_time_offset is not None:
            cfg = dc_replace(cfg, gnss_time_offset_s=args.gnss_time_offset * 1e-3)
        if args.standstill_updates is not None:
            cfg = dc_replace(cfg, standstill_updates=args.standstill_updates == "on")
        if args.nhc:
            cfg = dc_replace(cfg, nhc=True)
        offset_s = cfg.gnss_time_offset_s
        avail = _topics(args.bag)
        default = PRODUCT_TOPICS if PRODUCT_TOPICS[0] in avail else DRIVER_TOPICS
        topics = (args.imu_topic or default[0], args.fix_topic or default[1], args.vel_topic or default[2])
        origin, imu, gnss, notes = read_recording(args.bag, topics, rotation_from_rpy_deg(rpy))
        _check_plausible(args.bag, topics, imu, gnss)
        heading = None if args.initial_heading is None else args.initial_heading * DEG
        init, lv = start(imu, gnss, args.min_course_speed, heading_rad=heading, lever_arm_m=lever, gnss_time_offset_s=offset_s,
                         level=args.start_level, imu_model=cfg.imu)
        if lv is not None and lv.sigma_rad is not None and lv.sigma_rad / DEG > cfg.level_sigma_deg:
            cfg = dc_replace(cfg, level_sigma_deg=lv.sigma_rad / DEG)  # what the motion can leave in the level
        # the reference is a GNSS solution stamped on the receiver's clock: onto the IMU's, as the fixes
        ref = Reference.from_gnss(read_pos(args.reference).series(origin) if args.reference is not None else gnss, offset_s)
    except (InputError, LogFormatError, ValueError) as e:
        print(f"dpos-ifa: error: {e}", file=sys.stderr)
        return 2
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run(imu, gnss, lever, cfg, method, init, record_smoother=args.smooth)
    rep = compare(res, ref, outage)
    args.out.mkdir(parents=True, exist_ok=True)
    _write_nav(args.out / "nav.csv", res, origin)
    smoothed_json = None
    smoothed_lines: list[str] = []
    sres: IfaResult | None = None
    if args.smooth:
        t_sm = time.perf_counter()
        sm = smooth(res, imu)
        sres = as_result(res, sm.nav)
        smoothing_s = time.perf_counter() - t_sm
        rep_s = compare(sres, ref, outage)
        _write_smoothed(args.out, res, sres, origin, cfg.predict_interval_s, f"{args.bag} ({method.upper()}, {args.params_file})")
        smoothed_lines = [f"smoothed (forward-backward, {len(sm.segments)} chain(s) of {sm.steps_s.size} filter steps; "
                          f"smoothing {smoothing_s:.2f} s): nav_smoothed.csv, nav_smoothed.pos"]
        smoothed_lines += [f"smoothed {x}" for x in rep_s.lines()[2:]]  # aligned / DIVERGED: the forward run's
        smoothed_json = {"horizontal_error_m": rep_s.horizontal_error_m, "inside_3sigma": rep_s.inside_3sigma,
                         "heading_minus_course_deg": rep_s.heading_minus_course_deg, "smoothing_s": smoothing_s,
                         "filter_steps": int(sm.steps_s.size), "chains": len(sm.segments)}
    _plot(args.out / "ifa.png", res, ref, outage, sres)
    data_s = float(imu.t_s[-1] - imu.t_s[0])
    lines = [f"# In-flight alignment of {args.bag} ({method.upper()}, {args.params_file})", "",
             f"- topics {', '.join(topics)}: {len(imu.t_s)} IMU samples, {len(gnss.t_s)} fixes; {'; '.join(notes) or 'nothing dropped'}",
             f"- start: {init.t_s:.3f} s after the first IMU sample (heading {np.degrees(init.hpr_rad[0]):.1f}, pitch "
             f"{np.degrees(init.hpr_rad[1]):.2f}, roll {np.degrees(init.hpr_rad[2]):.2f} deg); fixes before it: {res.before_start}"
             + ("" if lv is None else f"; level {lv.how}" + ("" if lv.standstill is None else
                f" (standstill T {lv.standstill.statistic:.3g}, threshold {lv.standstill.threshold:.3g})")
                + ("" if lv.sigma_rad is None else f", level sigma {lv.sigma_rad / DEG:.2f} deg")),
             f"- standstill: {int(np.nansum(res.at_rest))} of {res.at_rest.size} epochs at rest; constraint updates "
             f"{' + '.join(n for n, on in (('ZUPT', cfg.zupt), ('ZARU', cfg.zaru)) if on) + ' at rest' if cfg.standstill_updates else 'off'}"
             f"{', NHC in motion' if cfg.nhc else ''}",
             f"- rejected fixes: {len(res.rejected)}; warnings: {len(caught)}; processing {res.runtime_s:.2f} s for {data_s:.1f} s "
             f"of data (ratio {res.runtime_s / max(data_s, 1e-9):.4f})",
             f"- reference: {args.reference or 'the bag fixes'}; gnss_time_offset_s {offset_s * 1e3:+.1f} ms (GNSS stamps minus "
             "IMU time: fixes and reference taken onto the IMU's clock)", ""]
    lines += [f"- {x}" for x in rep.lines()]
    if smoothed_lines:
        lines += [""] + [f"- {x}" for x in smoothed_lines]
    offset_json = None
    if offsets is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # each run's skipped fixes are the main run's, reported above
            est = estimate_time_offset(imu, gnss, lever, cfg, init, offsets)
        lines += [""] + [f"- {x}" for x in est.lines()]
        offset_json = {"offset_s": est.offset_s, "sigma_s": est.sigma_s, "observable": est.observable,
                       "epochs_used": est.epochs_used, "reduced_chi2": est.reduced_chi2,
                       "offsets_s": est.offsets_s.tolist(), "cost": est.cost.tolist()}
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    (args.out / "report.json").write_text(json.dumps({
        "aligned_t_s": rep.aligned_t_s, "diverged_epochs": rep.diverged, "restarts": rep.restarts,
        "rejected_fixes": len(res.rejected), "heading_minus_course_deg": rep.heading_minus_course_deg,
        "horizontal_error_m": rep.horizontal_error_m, "inside_3sigma": rep.inside_3sigma, "processing_s": res.runtime_s,
        "data_s": data_s, "start_t_s": init.t_s, "before_start": res.before_start, "time_offset": offset_json,
        "smoothed": smoothed_json}, indent=2) + "\n")
    if args.live is not None:
        try:
            counters, live_lines = live_report(args.live, origin, res, ref, outage)
        except InputError as e:
            print(f"dpos-ifa: error: {e}", file=sys.stderr)
            return 2
        lines += [""] + [f"- {x}" for x in live_lines]
        (args.out / "report.md").write_text("\n".join(lines) + "\n")
        (args.out / "live.json").write_text(json.dumps(counters, indent=2) + "\n")
    print("\n".join(lines))
    print(f"wrote {args.out / 'nav.csv'}, report.md, report.json, ifa.png" + (", nav_smoothed.csv, nav_smoothed.pos" if args.smooth else ""))
    return 0


def _status_values(raws: Sequence[bytes], msgtype: str) -> list[tuple[str, dict[str, str]]]:
    """(message, key/values) of each DiagnosticArray's first status, in order."""
    out = []
    for m in deserialize(raws, msgtype):
        if m.status:
            st = m.status[0]
            out.append((st.message, {kv.key: kv.value for kv in st.values}))
    return out


def live_report(rec: Path, origin_ns: int, offline: IfaResult, ref: Reference, outage: tuple[float, float] | None) -> tuple[dict, list[str]]:
    """The live graph's /master/nav (a recording) against the offline run of the same data and the
    reference: max position difference live - offline at common IMU stamps, the report of
    :func:`~dpos_core.ifa.reference.compare` with the covariance /master/nav carried, and the
    counters of /ifa/status and /pos_master/status (rejected fixes, lost corrections, the largest
    ``nav_discrepancy_m``)."""
    raw = read_raw(rec, ["/master/nav", "/dpos/datum", "/ifa/status", "/pos_master/status"])
    if "/master/nav" not in raw or "/dpos/datum" not in raw:
        raise InputError(f"{rec}: needs /master/nav and /dpos/datum (has {sorted(raw)})")
    datum = cv.datum_from_msg(deserialize(raw["/dpos/datum"][2][:1], raw["/dpos/datum"][0])[0])
    t_ns, vals = cv.decode_raw_batch(raw["/master/nav"][2], "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
    order = np.argsort(t_ns, kind="stable")
    t_ns, vals = t_ns[order], vals[order]
    blk = cv.odometry_from_values(t_ns, vals, datum)
    t = np.asarray((t_ns - origin_ns) * 1e-9, dtype=np.float64)
    # live minus offline at the same IMU stamps
    k = np.clip(np.searchsorted(offline.t_s, t - 1e-7), 0, offline.t_s.size - 1)
    same = np.abs(offline.t_s[k] - t) < 1e-6
    # the message at an epoch's sample carries the state before that epoch's correction (pos_master_node):
    # compare the others, where both are the closed-loop strapdown after every correction
    ep = np.searchsorted(offline.t_s, np.asarray(offline.epochs_s) + 1e-6, side="right") - 1
    same &= ~np.isin(k, ep)
    diff = np.array([np.linalg.norm(earth.enu_between(a, b)) for a, b in zip(blk.llh[same], offline.llh[k[same]])])
    P = np.zeros((t.size, 9, 9))
    P[:, 0:3, 0:3] = blk.pose_cov[:, 0:3, 0:3]
    P[:, 6:9, 6:9] = blk.pose_cov[:, 3:6, 3:6]
    P[:, 3:6, 3:6] = np.eye(3)  # not used by the report
    ifa = _status_values(raw["/ifa/status"][2], raw["/ifa/status"][0]) if "/ifa/status" in raw else []
    pm = _status_values(raw["/pos_master/status"][2], raw["/pos_master/status"][0]) if "/pos_master/status" in raw else []
    last_ifa = ifa[-1][1] if ifa else {}
    start_s = float(t[0])  # the first /master/nav is the initial state (the ifa_node's origin)
    aligned = last_ifa.get("aligned_t_s")
    aligned_t = start_s + float(aligned) if aligned not in (None, "", "None", "none", "nan") else None
    live = dc_replace(offline, t_s=t, llh=blk.llh, vel_n_mps=blk.vel_n_mps, q_nb=blk.q_nb,
                      track=[(float(a), b) for a, b in zip(t, P)], status=np.zeros(0, dtype=int),  # the covariance each message carried
                      aligned_t_s=aligned_t, restarts=int(float(last_ifa.get("restarts", 0) or 0)))
    rep = compare(live, ref, outage)
    disc = [float(v.get("nav_discrepancy_m", "nan")) for _, v in ifa if v.get("nav_discrepancy_m") not in (None, "")]
    last_pm = pm[-1][1] if pm else {}
    counters = {"master_nav_messages": int(t.size), "common_stamps_with_offline": int(same.sum()),
                "max_live_minus_offline_m": float(diff.max()) if diff.size else None,
                "ifa_status_final": ifa[-1][0] if ifa else None,
                "diverged_messages": sum(1 for m, _ in ifa if m == "DIVERGED"),
                "rejected_fixes": last_ifa.get("rejected_fixes"), "ifa_epochs": last_ifa.get("epochs"),
                "max_nav_discrepancy_m": float(np.nanmax(disc)) if disc else None,
                "corrections_lost": last_pm.get("corrections_lost"), "corrections_applied": last_pm.get("corrections"),
                "report": {"aligned_t_s": rep.aligned_t_s, "heading_minus_course_deg": rep.heading_minus_course_deg,
                           "horizontal_error_m": rep.horizontal_error_m, "inside_3sigma": rep.inside_3sigma}}
    lines = [f"live graph ({rec}): {t.size} /master/nav messages, {int(same.sum())} at the offline stamps (epoch samples aside), "
             f"max |live - offline| {counters['max_live_minus_offline_m']:.3g} m" if diff.size else f"live graph ({rec}): no common stamp",
             f"live /ifa/status: final {counters['ifa_status_final']}, epochs {counters['ifa_epochs']}, rejected fixes "
             f"{counters['rejected_fixes']}, DIVERGED messages {counters['diverged_messages']}, max nav_discrepancy_m "
             f"{counters['max_nav_discrepancy_m']}; /pos_master/status: corrections {counters['corrections_applied']}, "
             f"lost {counters['corrections_lost']}"]
    lines += ["live " + x for x in rep.lines() if not x.startswith("DIVERGED")]
    return counters, lines

