"""``dpos-import --nav``: an installation's logs -> one recording ``dpos-process`` takes as it is.

    dpos-import --nav trajectory.csv --nav-time-form week_sow --nav-week-col 0 --nav-time-col 1 ... \\
        --sub left=left_imu.csv --sub right=right_imu.csv --sub-options 'right=--gyro-cols 7,8,9' \\
        --aircraft my_aircraft.yaml --out out/flight_0707

Inputs: the main navigation solution CSV (``--nav``, column map ``--nav-*``; readers:
dpos_core.imports.navsol) and any number of sub-IMU logs (``--sub NAME=CSV``; the IMU CSV layout
options ``--accel-cols`` ... are every log's defaults, ``--sub-options NAME=OPTIONS`` overrides them
for one log with the same option names).  A sub-IMU clock: ``--time-col`` (GPS or, with
``--time-scale utc``, UTC time), ``--tag`` (counter + RTKLIB time tag) or a counter only: then its
offset (and drift) against the main solution is estimated from the angular rates
(dpos_core.imports.clock); not observable -> exit 2, one line naming the log.  Every sub-IMU's
mounting is estimated from the rates (dpos_core.imports.mounting) and reported; an aircraft file
whose sub-IMU says ``mount_rpy_deg: estimate`` gets the estimate in the recording's embedded copy,
with its ``mount_sigma_deg`` (:func:`mount_prior_sigma_deg`: the transfer alignment's prior of the
misalignment).

Output topics (design.md): /master/nav (nav_msgs/Odometry, as pos_master_node publishes it),
/dpos/datum (latched; the first solution point), /sub_imu/<name>/imu (sensor_msgs/Imu, frame
sub_imu_<name>); stamps GPST on the Unix calendar [ns].
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dpos_core import plausibility
from dpos_core.attitude import dcm_to_quat
from dpos_core.config import ConfigError, load_aircraft
from dpos_core.config.aircraft import MOUNT_ESTIMATE
from dpos_core.errors import ImportFailure
from dpos_core.frames import hpr_sigma_to_rotation_cov
from dpos_core.imports.clock import ClockEstimate, ClockNotObservable, ClockSettings, attitude_rates, estimate_clock
from dpos_core.imports.logs import ImuColumns, ImuLog, read_imu_csv, read_tag
from dpos_core.imports.mounting import MountingEstimate, MountingNotObservable, estimate_mounting
from dpos_core.imports.navsol import (
    VERTICAL_BOUND_SIGMAS,
    VERTICAL_NEIGHBOURHOOD_S,
    VERTICAL_WINDOW_S,
    NavColumns,
    NavSolution,
    read_nav_csv,
    vertical_consistency,
)
from dpos_core.imports.timescales import to_gpst_ns
from dpos_core.units import DEG
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.session import MASTER_SOURCE_KEY, MASTER_SOURCE_SOLUTION
from dpos_ros.io.streams import TopicStream

_NS = 1_000_000_000
#: the IMU CSV layout options a --sub-options value may set (argparse dests)
SUB_LAYOUT = ("accel_cols", "gyro_cols", "counter_col", "counter_unit_s", "time_col", "time_scale", "accel_unit", "gyro_unit",
              "skip_header", "delimiter", "tag", "gyro_sigma_radps", "accel_sigma_mps2")


def add_options(ap: argparse.ArgumentParser, int_triple: Any, positive: Any, non_negative: Any) -> None:
    """The installation options (``--nav*``, ``--sub*``, ``--aircraft``) on the dpos-import parser."""
    g = ap.add_argument_group("installation: main navigation solution (--nav) and sub-IMU logs (--sub)")
    g.add_argument("--nav", type=Path, metavar="CSV", help="main navigation solution CSV -> /master/nav + /dpos/datum (instead of --imu)")
    g.add_argument("--nav-time-col", type=int, default=0, metavar="N", help="time column (default 0)")
    g.add_argument("--nav-time-form", choices=("unix", "gps", "week_sow", "datetime", "elapsed"), default="unix",
                   help="unix: s on the Unix calendar; gps: s since 1980-01-06; week_sow: --nav-week-col + seconds of week; "
                        "datetime: 'YYYY-MM-DD HH:MM:SS.fff'; elapsed: x --nav-time-unit-s since --nav-epoch or --nav-epoch-col (default unix)")
    g.add_argument("--nav-time-scale", choices=("gpst", "utc"), default="gpst", help="scale of unix/datetime/elapsed times (default gpst; utc: leap seconds from the table)")
    g.add_argument("--nav-week-col", type=int, metavar="N", help="GPS week column (week_sow)")
    g.add_argument("--nav-time-unit-s", type=positive, default=1.0, metavar="S", help="seconds per unit of an elapsed time (default 1)")
    g.add_argument("--nav-epoch", metavar="DATETIME", help="date-time of elapsed 0 (elapsed)")
    g.add_argument("--nav-epoch-col", type=int, metavar="N", help="a coarse date-time column the elapsed epoch is estimated from")
    g.add_argument("--nav-llh-cols", type=int_triple, default=(1, 2, 3), metavar="LAT,LON,H", help="latitude, longitude, ellipsoidal height (default 1,2,3)")
    g.add_argument("--nav-latlon-unit", choices=("deg", "rad"), default="deg", help="latitude/longitude unit (default deg)")
    g.add_argument("--nav-vel-cols", type=int_triple, default=(4, 5, 6), metavar="A,B,C", help="velocity columns in --nav-vel-frame order (default 4,5,6)")
    g.add_argument("--nav-vel-frame", choices=("ned", "enu"), default="ned", help="velocity axes (default ned)")
    g.add_argument("--nav-att-cols", type=int_triple, default=(7, 8, 9), metavar="ROLL,PITCH,HEADING", help="attitude columns (default 7,8,9)")
    g.add_argument("--nav-angle-unit", choices=("deg", "rad"), default="deg", help="attitude unit (default deg)")
    g.add_argument("--nav-heading", choices=("north_cw", "east_ccw"), default="north_cw",
                   help="heading clockwise from north (default) or an ENU yaw counter-clockwise from east")
    g.add_argument("--nav-pos-sigma-cols", type=int_triple, metavar="N,E,U", help="position sigma columns [m]")
    g.add_argument("--nav-vel-sigma-cols", type=int_triple, metavar="A,B,C", help="velocity sigma columns [m/s], --nav-vel-frame order")
    g.add_argument("--nav-att-sigma-cols", type=int_triple, metavar="R,P,H", help="attitude sigma columns [--nav-angle-unit]")
    g.add_argument("--nav-pos-sigma-m", type=positive, default=0.1, metavar="S", help="position sigma when the file has none (default 0.1)")
    g.add_argument("--nav-vel-sigma-mps", type=positive, default=0.1, metavar="S", help="velocity sigma when the file has none (default 0.1)")
    g.add_argument("--nav-att-sigma-deg", type=positive, default=0.1, metavar="S", help="roll/pitch/heading sigma when the file has none (default 0.1)")
    g.add_argument("--nav-skip-header", type=int, default=0, metavar="N", help="leading lines of --nav to ignore (default 0; a header line is skipped and listed anyway)")
    g.add_argument("--nav-delimiter", default=",", help="field separator of --nav (default ',')")
    g.add_argument("--sub", action="append", default=[], metavar="NAME=CSV", help="a sub-IMU log -> /sub_imu/NAME/imu (repeatable)")
    g.add_argument("--sub-options", action="append", default=[], metavar="NAME=OPTIONS",
                   help="IMU CSV layout options of one --sub log, e.g. 'left=--gyro-cols 7,8,9 --counter-unit-s 1e-6' (repeatable)")
    g.add_argument("--time-scale", choices=("gpst", "utc"), default="gpst", help="scale of a sub-IMU --time-col (default gpst; utc: leap-second table)")
    g.add_argument("--aircraft", type=Path, metavar="YAML",
                   help="aircraft file embedded in the recording; a sub-IMU's 'mount_rpy_deg: estimate' gets the estimated mounting")
    g.add_argument("--sub-imu-preset", default="consumer_mems", metavar="PRESET",
                   help="without --aircraft: the sub-IMUs' error model in the generated aircraft file (an imu_presets.yaml name; default consumer_mems)")
    g.add_argument("--clock-min-peak", type=non_negative, default=ClockSettings.min_peak, metavar="R",
                   help=f"smallest rate correlation accepted for an estimated clock (default {ClockSettings.min_peak})")


def nav_columns(args: argparse.Namespace) -> NavColumns:
    return NavColumns(time=args.nav_time_col, time_form=args.nav_time_form, time_scale=args.nav_time_scale,
                      time_unit_s=args.nav_time_unit_s, week=args.nav_week_col, epoch=args.nav_epoch, epoch_col=args.nav_epoch_col,
                      llh=args.nav_llh_cols, latlon_unit=args.nav_latlon_unit, vel=args.nav_vel_cols, vel_frame=args.nav_vel_frame,
                      att=args.nav_att_cols, angle_unit=args.nav_angle_unit, heading=args.nav_heading,
                      pos_sigma=args.nav_pos_sigma_cols, vel_sigma=args.nav_vel_sigma_cols, att_sigma=args.nav_att_sigma_cols,
                      skip_header=args.nav_skip_header, delimiter=args.nav_delimiter)


def sub_layouts(ap: argparse.ArgumentParser, lp: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, tuple[Path, argparse.Namespace]]:
    """NAME -> (CSV, its layout options): the global IMU CSV options, then its --sub-options."""
    subs: dict[str, tuple[Path, argparse.Namespace]] = {}
    for item in args.sub:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            ap.error(f"--sub expects NAME=CSV, got {item!r}")
        if not all(ch.isalnum() or ch == "_" for ch in name):
            ap.error(f"--sub {item!r}: NAME must be letters, digits and _ (it names /sub_imu/NAME/imu)")
        if name in subs:
            ap.error(f"--sub {name!r} given twice")
        subs[name] = (Path(path), argparse.Namespace(**{k: getattr(args, k) for k in SUB_LAYOUT}))
    for item in args.sub_options:
        name, sep, text = item.partition("=")
        if not sep or name not in subs:
            ap.error(f"--sub-options {item!r}: expected NAME=OPTIONS for a --sub NAME ({', '.join(subs) or 'none given'})")
        ns = subs[name][1]
        try:
            words = shlex.split(text)
        except ValueError as exc:
            ap.error(f"--sub-options {name}: {exc}")
        parsed, rest = lp.parse_known_args(words, namespace=argparse.Namespace())
        if rest:
            ap.error(f"--sub-options {name}: not an IMU CSV layout option: {' '.join(rest)}")
        for k, v in vars(parsed).items():
            setattr(ns, k, v)
    for name, (_, ns) in subs.items():
        if ns.time_col is not None and ns.tag is not None:
            ap.error(f"--sub {name}: give --tag or --time-col, not both")
        if ns.counter_col is None and ns.time_col is None:
            ns.counter_col = 6
    return subs


def _rates_at(t_s: np.ndarray, C_nb: np.ndarray) -> np.ndarray:
    """Body rate w.r.t. the local level at the samples (N, 3) [rad/s]: the interval rates of
    attitude_rates interpolated from the interval middles (transport and Earth rate neglected)."""
    a, b, w = attitude_rates(t_s, C_nb)
    mid = 0.5 * (a + b)
    return np.column_stack([np.interp(t_s, mid, w[:, j]) for j in range(3)])


def master_nav_streams(nav: NavSolution, args: argparse.Namespace) -> tuple[list[TopicStream], dict[str, Any]]:
    """/dpos/datum (the first point) and /master/nav (conversions.odometry_values_cov); the sigma sources."""
    n = len(nav)
    t0 = int(nav.t_ns[0])
    t_s = (nav.t_ns - t0) * 1e-9
    ones = np.ones((n, 3))
    pos_sig = nav.pos_sigma_m if nav.pos_sigma_m is not None else ones * args.nav_pos_sigma_m
    vel_sig = nav.vel_sigma_mps if nav.vel_sigma_mps is not None else ones * args.nav_vel_sigma_mps
    if nav.hpr_sigma_rad is not None:
        att_cov = np.stack([hpr_sigma_to_rotation_cov(nav.C_nb[i], nav.hpr_sigma_rad[i]) for i in range(n)])
    else:
        att_cov = hpr_sigma_to_rotation_cov(nav.C_nb, np.full(3, args.nav_att_sigma_deg * DEG))
    sources = {
        "position": "columns" if nav.pos_sigma_m is not None else f"option --nav-pos-sigma-m {args.nav_pos_sigma_m:g} (not in the file)",
        "velocity": "columns" if nav.vel_sigma_mps is not None else f"option --nav-vel-sigma-mps {args.nav_vel_sigma_mps:g} (not in the file)",
        "attitude": "columns" if nav.hpr_sigma_rad is not None else f"option --nav-att-sigma-deg {args.nav_att_sigma_deg:g} (not in the file)",
    }
    # the solution against itself: its height against the integral of its vertical speed (navsol.vertical_consistency);
    # where they disagree beyond their sigmas both are widened, and the report says where
    vc = vertical_consistency(np.asarray(t_s, dtype=np.float64), nav.llh[:, 2], nav.vel_n_mps[:, 2], pos_sig[:, 2], vel_sig[:, 2])
    pos_sig, vel_sig = pos_sig.copy(), vel_sig.copy()
    pos_sig[:, 2], vel_sig[:, 2] = vc.sigma_h_m, vc.sigma_vu_mps
    said = []
    if vc.widened.any():
        spans = ", ".join(f"{a:.1f}-{b:.1f}" for a, b in vc.spans_s[:5]) + (" ..." if len(vc.spans_s) > 5 else "")
        said.append(
            f"widened at {int(vc.widened.sum())} of {n} epochs ({spans} s): the height and the integral of the vertical speed "
            f"disagree by up to {vc.max_disagreement_m:.2f} m over {VERTICAL_WINDOW_S:g} s ({vc.max_sigmas:.1f} sigmas; "
            f"beyond {VERTICAL_BOUND_SIGMAS:g} the solution is inconsistent with itself; within a span up to "
            f"{vc.span_disagreement_m:.2f} m, {vc.span_sigmas:.1f} sigmas)")
    rms_factor = vc.rms_factor if vc.rms_factor is not None else np.ones(n)
    if np.any(rms_factor > 1.0):
        wide = rms_factor[rms_factor > 1.0]
        said.append(
            f"widened x{float(wide.min()):.1f}-{float(wide.max()):.1f} at {wide.size} of {n} epochs whose {VERTICAL_WINDOW_S:g} s "
            f"windows within {VERTICAL_NEIGHBOURHOOD_S:g} s disagree by more than 1 sigma rms (its errors are correlated: a "
            f"window that passes near failing ones is no evidence that the sigmas hold there)")
    sources["height and vertical speed"] = "; ".join(said) if said else (
        f"consistent (the height against the integral of the vertical speed over {VERTICAL_WINDOW_S:g} s: at most {vc.max_sigmas:.1f} sigmas)")
    datum = nav.llh[0].copy()
    vals = cv.odometry_values_cov(nav.llh, nav.vel_n_mps, dcm_to_quat(nav.C_nb), datum, _rates_at(t_s, nav.C_nb),
                                  pos_sig[:, :, None] ** 2 * np.eye(3), att_cov, vel_sig[:, :, None] ** 2 * np.eye(3))
    t_ns = nav.t_ns.copy()
    streams = [
        TopicStream(T.DATUM, T.NAVSATFIX, t_ns[:1].copy(), blobs=(cv.datum_blob(t0, datum),), qos="datum"),
        TopicStream(T.MASTER_NAV, T.ODOMETRY, t_ns, rows=cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, t_ns, vals), qos="nav"),
    ]
    return streams, sources


def refuse_implausible_imu(what: str, log: ImuLog, cols: ImuColumns) -> None:
    """ImportFailure in one line when the log's values show a unit mistake (dpos_core.plausibility):
    specific force not near g in the quietest seconds, angular rates no vehicle has."""
    found = plausibility.check_imu(what, np.asarray((log.t_ns - log.t_ns[0]) * 1e-9, dtype=np.float64), log.omega_radps, log.f_mps2)
    if found:
        units = f"(read with --accel-unit {cols.accel_unit} --gyro-unit {cols.gyro_unit})"
        raise ImportFailure(f"{found[0]} {units}")


def read_sub(name: str, path: Path, ns: argparse.Namespace) -> tuple[ImuLog, str, int]:
    """Read one sub-IMU log; returns the log (stamps: GPST, or device seconds from 0 for a counter only),
    its clock kind and the count of samples removed because all six values were 0."""
    if not path.is_file():
        raise ImportFailure(f"--sub {name}: {path}: {'is a directory' if path.is_dir() else 'no such file'}")
    try:
        cols = ImuColumns(accel=ns.accel_cols, gyro=ns.gyro_cols, accel_unit=ns.accel_unit, gyro_unit=ns.gyro_unit,
                          counter=None if ns.time_col is not None else ns.counter_col, counter_unit_s=ns.counter_unit_s,
                          time=ns.time_col, skip_header=ns.skip_header, delimiter=ns.delimiter)
    except ValueError as exc:
        raise ImportFailure(f"--sub {name}: IMU columns: {exc}") from None
    tag = None if ns.tag is None else read_tag(ns.tag)
    log = read_imu_csv(path, cols, tag)
    zero = np.all(log.omega_radps == 0.0, axis=1) & np.all(log.f_mps2 == 0.0, axis=1)
    if zero.any():  # a logger's placeholder (e.g. an Xsens DOT's first line): no specific force is 0 under gravity
        log = ImuLog(log.t_ns[~zero], log.omega_radps[~zero], log.f_mps2[~zero], log.skipped, log.repeated, log.clock_scale)
    refuse_implausible_imu(f"--sub {name} ({path})", log, cols)
    if ns.time_col is not None:
        if ns.time_scale == "utc":
            log.t_ns = to_gpst_ns(log.t_ns, "utc")
        return log, f"time column ({ns.time_scale.upper()})", int(zero.sum())
    if tag is not None:
        return log, "counter mapped onto the time tag", int(zero.sum())
    return log, "counter only: offset estimated from the angular rates", int(zero.sum())


def _clock_dict(c: ClockEstimate) -> dict[str, Any]:
    return {"offset_s": c.offset_s, "offset_sigma_ms": c.offset_sigma_s * 1e3, "at_device_s": c.t_ref_dev_s,
            "drift_ppm": c.drift * 1e6 if c.drift_sigma is not None else None,
            "drift_sigma_ppm": None if c.drift_sigma is None else c.drift_sigma * 1e6,
            "correlation_peak": c.peak, "second_peak": None if not np.isfinite(c.second_peak) else c.second_peak,
            "refined_peak": c.refined_peak, "windows": len(c.windows), "main_rate_std_dps": c.rate_std_dps}


def _mount_dict(m: MountingEstimate) -> dict[str, Any]:
    return {"rpy_deg": [round(float(x), 4) for x in m.rpy_deg], "rpy_sigma_deg": [round(float(x), 4) for x in m.rpy_sigma_deg],
            "gyro_bias_dps": [round(float(x), 4) for x in m.bias_dps], "residual_rms_dps": m.residual_dps, "intervals": m.samples,
            "residual_correlation_factor": m.corr_factor}


#: the smallest ``mount_sigma_deg`` dpos-import writes [deg] (:func:`mount_prior_sigma_deg`)
MOUNT_SIGMA_MIN_DEG = 0.01


def mount_prior_sigma_deg(m: MountingEstimate, att_sigma_deg: float) -> float:
    """``mount_sigma_deg`` [deg] written beside an estimated mounting ``m``: the prior 1 sigma per axis
    of the misalignment rho the transfer alignment estimates against the main solution's attitude.
    Rho is the mounting's error plus the main solution's attitude error that is constant over the
    flight: the rates the mounting is estimated from do not see a constant attitude error (their
    differences drop it), the alignment's attitude match does, and only rho can take it (the
    filter's main-POS noise is white, averaged over the epochs).  So: the root sum square of the
    estimate's largest 1 sigma (the square root of the largest eigenvalue of its rotation covariance:
    any axis, no Euler singularity) and ``att_sigma_deg``, the main solution's attitude 1 sigma (its
    file's or ``--nav-att-sigma-deg``, 0.1 deg by default: one step of a 0.1 deg rounding).  Never
    below the solution's sigma, never below 0.01 deg (a solution claiming a perfect attitude)."""
    rot_deg = float(np.sqrt(max(float(np.linalg.eigvalsh(m.phi_cov_rad2).max()), 0.0))) / DEG
    return round(max(float(np.hypot(rot_deg, att_sigma_deg)), MOUNT_SIGMA_MIN_DEG), 3)


def aircraft_text(path: Path | None, names: list[str], mounts: dict[str, MountingEstimate], preset: str = "consumer_mems",
                  mount_sigmas: dict[str, float] | None = None) -> tuple[str, list[str]]:
    """The aircraft YAML to embed: --aircraft with ``mount_rpy_deg: estimate`` replaced by the estimates
    (ImportFailure when one is not estimated), or, without --aircraft, a starting point: each sub-IMU
    at the master IMU (lever arm 0, to be surveyed) with its estimated mounting and an antenna at it.
    An estimated mounting gets ``mount_sigma_deg`` from ``mount_sigmas`` (per sub-IMU,
    :func:`mount_prior_sigma_deg`) unless the --aircraft file states one."""
    replaced: list[str] = []
    sig = mount_sigmas or {}
    if path is None:
        d: dict[str, Any] = {"name": "imported", "description": "written by dpos-import: lever arms unknown (0), mountings estimated",
                             "gnss_lever_arm_m": [0.0, 0.0, 0.0],
                             # a rigid airframe: the flexure model's smallest variance (edit for a wing)
                             "flexure": {"tau_s": [5.0, 2.0, 2.0], "variance_deg2": [0.001, 0.001, 0.001]},
                             "sub_imus": [], "antennas": []}
        for n in names:
            rpy = [round(float(x), 3) for x in mounts[n].rpy_deg] if n in mounts else [0.0, 0.0, 0.0]
            entry: dict[str, Any] = {"name": n, "span_m": 0.0, "lever_arm_m": [0.0, 0.0, 0.0], "mount_rpy_deg": rpy}
            if n in mounts and n in sig:
                entry["mount_sigma_deg"] = sig[n]
            d["sub_imus"].append({**entry, "imu": {"preset": preset}})
            d["antennas"].append({"name": n, "span_m": 0.0, "sub_imu": n, "lever_arm_m": [0.0, 0.0, 0.0]})
            if n in mounts:
                replaced.append(n)
    else:
        try:
            d = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ImportFailure(f"--aircraft {path}: {exc}") from None
        for s in d.get("sub_imus") or []:
            if isinstance(s, dict) and s.get("mount_rpy_deg") == MOUNT_ESTIMATE:
                n = str(s.get("name"))
                if n not in mounts:
                    raise ImportFailure(f"--aircraft {path}: sub-IMU {n!r} says 'mount_rpy_deg: estimate' but "
                                        + ("no --sub gives its log" if n not in names else "its mounting is not observable (see above)"))
                s["mount_rpy_deg"] = [round(float(x), 3) for x in mounts[n].rpy_deg]
                if n in sig and s.get("mount_sigma_deg") is None:
                    s["mount_sigma_deg"] = sig[n]
                replaced.append(n)
    text = yaml.safe_dump(d, sort_keys=False)
    try:
        ac = load_aircraft("recording", text=text)
    except ConfigError as exc:
        raise ImportFailure(f"--aircraft {path}: {exc}") from None
    missing = [n for n in names if n not in {s.name for s in ac.sub_imus}]
    if missing:
        raise ImportFailure(f"--aircraft {path}: no sub-IMU {missing} (the --sub names must be the aircraft's)")
    return text, replaced


@dataclass(frozen=True)
class _MainSolution:
    """What the --sub logs are placed against (:func:`_import_sub`): the --nav solution ``nav``,
    its epochs ``tm`` (N,) [s from ``t0_ns``, its first stamp, ns GPST] and the clock estimation's
    ``settings``."""

    nav: NavSolution
    tm: np.ndarray
    t0_ns: int
    settings: ClockSettings


@dataclass(frozen=True)
class _SubImport:
    """One imported --sub log: its stream, its report entry and its mounting (None: not observable)."""

    stream: TopicStream
    entry: dict[str, Any]
    mounting: MountingEstimate | None


def _import_sub(name: str, path: Path, ns: argparse.Namespace, main: _MainSolution) -> _SubImport:
    """One --sub log (:func:`run_installation`): read, placed on GPS time, its mounting estimated."""
    nav, tm, t0, settings = main.nav, main.tm, main.t0_ns, main.settings
    log, kind, n_zero = read_sub(name, path, ns)
    entry: dict[str, Any] = {"file": str(path), "samples_read": len(log) + n_zero, "lines_skipped": len(log.skipped),
                             "skipped_first": [{"line": n, "reason": why} for n, why in log.skipped[:5]],
                             "repeated_samples": log.repeated,
                             "removed_all_zero": n_zero,  # all six values 0: a placeholder, not a measurement
                             "clock": {"source": kind}}
    if kind.startswith("counter only"):
        td = np.asarray(log.t_ns * 1e-9, dtype=np.float64)
        try:
            c = estimate_clock(tm, nav.C_nb, td, log.omega_radps, settings, name=f"--sub {name} ({path})")
        except ClockNotObservable as exc:
            raise ImportFailure(str(exc)) from None
        log.t_ns = c.to_gpst_ns(td, t0)
        entry["clock"].update(_clock_dict(c))
    t_sub = np.asarray((log.t_ns - t0) * 1e-9, dtype=np.float64)
    inside = (t_sub >= tm[0]) & (t_sub <= tm[-1])
    entry["samples_outside_nav"] = int((~inside).sum())  # removed: the transfer alignment needs the main solution
    if not inside.any():
        raise ImportFailure(f"--sub {name} ({path}): no sample within the main solution's span ({tm[-1]:.3f} s)")
    if not inside.all():
        log = ImuLog(log.t_ns[inside], log.omega_radps[inside], log.f_mps2[inside], log.skipped, log.repeated, log.clock_scale)
        t_sub = t_sub[inside]
    rates = np.linalg.norm(_rates_at(tm, nav.C_nb), axis=1)[(tm >= t_sub[0]) & (tm <= t_sub[-1])]  # over the log's span
    scale = plausibility.check_rate_scale(f"--sub {name} ({path})", log.omega_radps, rates, "the --nav solution's attitude")
    if scale is not None:
        raise ImportFailure(f"{scale} (read with --gyro-unit {ns.gyro_unit})")
    m: MountingEstimate | None = None
    try:
        m = estimate_mounting(tm, nav.C_nb, t_sub, log.omega_radps, name=f"--sub {name}")
        entry["mounting"] = _mount_dict(m)
    except MountingNotObservable as exc:
        entry["mounting"] = {"not_observable": str(exc)}
    entry["samples_written"] = len(log)
    stream = TopicStream(T.sub_imu(name), T.IMU, log.t_ns.copy(),
                         rows=cv.imu_rows(cv.sub_imu_frame(name), log.t_ns, log.omega_radps, log.f_mps2,
                                          ns.gyro_sigma_radps, ns.accel_sigma_mps2))
    return _SubImport(stream, entry, m)


def _sub_line(entry: dict[str, Any]) -> str:
    """A sub-IMU's progress line: samples, clock, mounting."""
    c, m = entry["clock"], entry.get("mounting", {})
    clock = c["source"] + (f", offset {c['offset_s']:+.4f} s +- {c['offset_sigma_ms']:.1f} ms" if "offset_s" in c else "")
    mount = ("mounting " + "/".join(f"{v:.2f}" for v in m["rpy_deg"]) + " deg") if "rpy_deg" in m else "mounting not observable"
    return f"{entry['samples_written']} samples, clock {clock}, {mount}"


def run_installation(args: argparse.Namespace) -> tuple[list[TopicStream], dict[str, str], dict[str, Any]]:
    """Read the navigation solution and the sub-IMU logs, place the logs on GPS time, estimate the
    mountings; returns (streams, custom metadata, report).  Raises ImportFailure, LogFormatError."""
    subs: dict[str, tuple[Path, argparse.Namespace]] = args.layouts
    if not args.nav.is_file():
        raise ImportFailure(f"--nav {args.nav}: {'is a directory' if args.nav.is_dir() else 'no such file'}")
    try:
        cols = nav_columns(args)
    except ValueError as exc:
        raise ImportFailure(f"--nav columns: {exc}") from None
    st = getattr(args, "stages", None)  # the progress (dpos_ros.cli.progress.Stages), when dpos-import runs
    if st is not None:
        st.stage(f"reading the main navigation solution {args.nav}")
    nav = read_nav_csv(args.nav, cols)
    if len(nav) < 3:
        raise ImportFailure(f"--nav {args.nav}: {len(nav)} usable line(s), at least 3 needed")
    streams, sources = master_nav_streams(nav, args)
    t0 = int(nav.t_ns[0])
    tm = np.asarray((nav.t_ns - t0) * 1e-9, dtype=np.float64)
    rep_subs: dict[str, Any] = {}
    mounts: dict[str, MountingEstimate] = {}
    main = _MainSolution(nav, tm, t0, ClockSettings(min_peak=args.clock_min_peak))
    if st is not None:
        st.stage(f"{len(subs)} sub-IMU log(s): reading, clocks, mountings")
    with contextlib.ExitStack() as stack:
        bar = stack.enter_context(st.items("sub-IMU", len(subs))) if st is not None else None
        for name, (path, ns) in subs.items():
            sub = _import_sub(name, path, ns, main)
            streams.append(sub.stream)
            rep_subs[name] = sub.entry
            if sub.mounting is not None:
                mounts[name] = sub.mounting
            if bar is not None:
                bar.done(name, _sub_line(rep_subs[name]))
    att_sigma_deg = float(args.nav_att_sigma_deg)  # the main solution's attitude 1 sigma: its columns' median (largest axis) or the option
    rows = None if nav.hpr_sigma_rad is None else nav.hpr_sigma_rad[np.isfinite(nav.hpr_sigma_rad).all(axis=1)]
    if rows is not None and rows.size:
        att_sigma_deg = float(np.median(rows.max(axis=1))) / DEG
    mount_sigmas = {n: mount_prior_sigma_deg(m, att_sigma_deg) for n, m in mounts.items()}
    text, replaced = aircraft_text(args.aircraft, list(subs), mounts, args.sub_imu_preset, mount_sigmas)
    written = {s.name: s.mount_sigma_deg for s in load_aircraft("recording", text=text).sub_imus if s.name in replaced}
    report: dict[str, Any] = {
        "out": str(args.out),
        "nav": {"file": str(args.nav), "lines_read": len(nav), "lines_skipped": len(nav.skipped),
                "skipped_first": [{"line": n, "reason": why} for n, why in nav.skipped[:5]], "time": nav.epoch_note,
                "sigmas": sources, "first_ns": t0, "duration_s": round(float(tm[-1]), 6),
                "datum_deg_m": [float(np.rad2deg(nav.llh[0, 0])), float(np.rad2deg(nav.llh[0, 1])), float(nav.llh[0, 2])]},
        "subs": rep_subs,
        "aircraft": {"source": str(args.aircraft) if args.aircraft else "generated (lever arms 0: survey them)",
                     "mountings_from_estimate": replaced, "mount_sigma_deg": written},
        "topics": {s.topic: {"type": s.msgtype, "messages": len(s)} for s in streams},
    }
    custom = {"dpos.session_id": args.out.name, "dpos.start_time_s": repr(t0 * 1e-9), "dpos.aircraft_yaml": text,
              MASTER_SOURCE_KEY: MASTER_SOURCE_SOLUTION}
    return streams, custom, report


def summary_lines(rep: dict[str, Any], prog: str) -> list[str]:
    nv = rep["nav"]
    out = [f"{prog}: {nv['file']} + {len(rep['subs'])} sub-IMU log(s) -> {rep['out']}",
           f"NAV   {nv['lines_read']} solutions -> /master/nav, /dpos/datum ({nv['duration_s']:.3f} s); lines skipped: {nv['lines_skipped']}"]
    out += [f"        line {e['line']}: {e['reason']}" for e in nv["skipped_first"]]
    out.append(f"      time: {nv['time']}")
    out += [f"      {k} sigma: {v}" for k, v in nv["sigmas"].items()]
    for name, s in rep["subs"].items():
        out.append(f"SUB   {name}: {s['file']}: {s['samples_written']} samples -> /sub_imu/{name}/imu; lines skipped: {s['lines_skipped']}, "
                   f"repeated samples: {s['repeated_samples']}, removed outside the solution's span: {s['samples_outside_nav']}")
        if s["removed_all_zero"]:
            out.append(f"      removed: {s['removed_all_zero']} sample(s) with all six values 0 (a logger's placeholder, not a measurement)")
        out += [f"        line {e['line']}: {e['reason']}" for e in s["skipped_first"]]
        c = s["clock"]
        if "offset_s" in c:
            drift = "" if c["drift_ppm"] is None else f", drift {c['drift_ppm']:+.1f} +- {c['drift_sigma_ppm']:.1f} ppm"
            out.append(f"      clock: {c['source']}: offset {c['offset_s']:+.4f} s +- {c['offset_sigma_ms']:.1f} ms{drift}, "
                       f"correlation peak {c['correlation_peak']:.2f} (next {c['second_peak'] or 0:.2f})")
        else:
            out.append(f"      clock: {c['source']}")
        m = s["mounting"]
        if "rpy_deg" in m:
            r, sg = m["rpy_deg"], m["rpy_sigma_deg"]
            out.append(f"      mounting roll/pitch/yaw {r[0]:+.2f} +- {sg[0]:.2f}, {r[1]:+.2f} +- {sg[1]:.2f}, {r[2]:+.2f} +- {sg[2]:.2f} deg "
                       f"(gyro bias {m['gyro_bias_dps']} deg/s, residual {m['residual_rms_dps']:.2f} deg/s rms)")
        else:
            out.append(f"      mounting: {m['not_observable']}")
    ac = rep["aircraft"]
    sig = ac.get("mount_sigma_deg") or {}
    est = [f"{n} (mount_sigma_deg {sig[n]:g})" if sig.get(n) is not None else n for n in ac["mountings_from_estimate"]]
    out.append(f"AIRCRAFT {ac['source']}; mountings from the estimate: {', '.join(est) or 'none'}")
    return out
