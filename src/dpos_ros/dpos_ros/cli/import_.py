"""``dpos-import``: real sensor logs -> a rosbag2 (MCAP, zstd chunks) shaped like real drivers' output.

    dpos-import --imu data/real/walk_0827/imu_1730.csv --tag data/real/walk_0827/imu_1730.csv.tag \\
        --pos data/real/walk_0827/gnss_1730_sf.pos --gnss-rate 1 --outage 60:75 --out out/walk_0827_1hz

Inputs (readers: dpos_core.imports.logs): an IMU CSV log (any column layout, --accel-cols ...)
whose counter is mapped onto an RTKLIB time tag (--tag) or that has a GPS-time column
(--time-col); optionally an RTKLIB .pos solution (--pos; llh in degrees, with or without
velocities). Cut or malformed lines are skipped and reported.

Output topics (defaults name them like common drivers; the bag plays into pos_master_node
`device: ros` with -r imu_in:=/imu/data -r fix_in:=/fix -r vel_in:=/vel):
  /imu/data  sensor_msgs/Imu: angular_velocity [rad/s], linear_acceleration [m/s^2] in the IMU's
             own axes; orientation_covariance[0] = -1; the other covariances diagonal
             --gyro-sigma-radps^2 / --accel-sigma-mps2^2 (default 0 = unknown)
  /fix       sensor_msgs/NavSatFix: lat/lon [deg], ellipsoidal height [m], position_covariance
             ENU row-major [m^2] (REP 145) from sdn/sde/sdu/sdne/sdeu/sdun, COVARIANCE_TYPE_KNOWN;
             status GBAS_FIX for RTKLIB Q1 (fix) / Q2 (float), SBAS_FIX for Q3, FIX otherwise;
             service GPS
  /vel       geometry_msgs/TwistWithCovarianceStamped: twist.linear = ENU velocity [m/s] (as GNSS
             drivers publish), linear covariance ENU [m^2/s^2], angular block diagonal -1 (unknown);
             only when the .pos has velocity columns
Header stamps = GPS time (GPST on the Unix calendar, no leap seconds) [ns]; log (receive) time =
the header stamp. Times of --outage, --start and --end are seconds after the first IMU sample
of the log. GNSS selection, in this order: --gnss-rate, --min-quality, --outage, --start/--end.

An installation instead (--nav: a main navigation solution CSV and --sub NAME=CSV sub-IMU logs,
each on its own clock -> /master/nav, /dpos/datum, /sub_imu/<name>/imu, one recording dpos-process
takes as it is; clocks and mountings estimated from the data): dpos_ros.cli.import_install,
docs/import.md "An installation".

Progress (stages, a line per sub-IMU, the bag being written) is drawn on stderr when it is a
terminal, not with --quiet nor into a file or a pipe.

Prints a summary and writes it to <out>/import_report.json. Exit status 0; 2 on bad options, an
unreadable log or an existing --out (without --overwrite); nothing is left behind on error.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from numpy.typing import NDArray

from dpos_core import plausibility
from dpos_core.errors import ImportFailure
from dpos_core.imports.logs import (
    ACCEL_UNITS,
    GPS_EPOCH_UNIX_S,
    GYRO_UNITS,
    ImuColumns,
    ImuLog,
    LogFormatError,
    PosLog,
    grid_offset_ns,
    outage_mask,
    read_imu_csv,
    read_pos,
    read_tag,
)
from dpos_core.imports.timescales import to_gpst_ns
from dpos_ros.cli import import_install as install
from dpos_ros.cli.options import finite_float, int_in, one_line_errors
from dpos_ros.cli.progress import Stages
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.bag import typestore, write_streams
from dpos_ros.io.streams import TopicStream

PROG = "dpos-import"
EXIT_OK = 0
EXIT_ERROR = 2
#: largest column index of a log's line accepted on the command line
MAX_COLUMN = 10_000
REPORT_NAME = "import_report.json"
#: skipped lines listed by name in the summary and the report
SHOWN_SKIPPED = 5
_NS = 1_000_000_000
_WEEK_S = 604_800
#: RTKLIB Q (the .pos file's quality flag) -> name
Q_NAMES = {1: "fix", 2: "float", 3: "sbas", 4: "dgps", 5: "single", 6: "ppp"}


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``dpos-import: error: ... (see --help)``), status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f"{self.prog}: error: {message} (see --help)\n")


# ----------------------------------------------------------------------------- options


def _int_triple(text: str) -> tuple[int, int, int]:
    try:
        vals = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three column indices like 0,1,2, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected three column indices like 0,1,2, got {text!r}")
    if not all(0 <= v <= MAX_COLUMN for v in vals):
        raise argparse.ArgumentTypeError(f"column indices must be in [0, {MAX_COLUMN}], got {text!r}")
    return vals[0], vals[1], vals[2]


def _interval(text: str) -> tuple[float, float]:
    """``START:END`` [s] -> (start, end) with end > start."""
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        start_s, end_s = float(a), float(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:END in seconds, got {text!r}") from None
    if not (np.isfinite(start_s) and np.isfinite(end_s)) or not end_s > start_s:
        raise argparse.ArgumentTypeError(f"{text!r}: END must be after START")
    return start_s, end_s


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (np.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def add_layout(col: Any, suppress: bool = False) -> None:
    """The IMU CSV layout options (also a --sub-options value's, with ``suppress``: only the given ones are set)."""
    def d(v: Any) -> Any:
        return argparse.SUPPRESS if suppress else v

    col.add_argument("--accel-cols", type=_int_triple, default=d((0, 1, 2)), metavar="X,Y,Z", help="specific force columns (default 0,1,2)")
    col.add_argument("--gyro-cols", type=_int_triple, default=d((3, 4, 5)), metavar="X,Y,Z", help="angular rate columns (default 3,4,5)")
    col.add_argument("--counter-col", type=int_in(0, MAX_COLUMN), default=d(None), metavar="N", help="IMU clock counter column (default 6; none with --time-col)")
    col.add_argument("--counter-unit-s", type=_positive, default=d(1e-3), metavar="S", help="seconds per counter unit (default 0.001)")
    col.add_argument("--time-col", type=int_in(0, MAX_COLUMN), default=d(None), metavar="N",
                     help="column of GPS time [s on the Unix calendar; --time-scale utc: UTC] (instead of counter + --tag)")
    col.add_argument("--tag", type=Path, default=d(None), metavar="TAG",
                     help="RTKLIB time tag of the IMU log: the IMU counter is mapped onto its GPS-time span (or give --time-col)")
    col.add_argument("--accel-unit", choices=sorted(ACCEL_UNITS), default=d("g"), help="specific force unit (default g = 9.80665 m/s^2)")
    col.add_argument("--gyro-unit", choices=sorted(GYRO_UNITS), default=d("deg_s"), help="angular rate unit (default deg_s)")
    col.add_argument("--skip-header", type=int_in(0), default=d(0), metavar="N", help="leading lines to ignore (default 0)")
    col.add_argument("--delimiter", default=d(","), help="field separator (default ','; ' ' = any whitespace)")
    col.add_argument("--gyro-sigma-radps", type=_non_negative, default=d(0.0), metavar="SIGMA",
                     help="per-sample gyro noise [rad/s] for angular_velocity_covariance (default 0 = unknown)")
    col.add_argument("--accel-sigma-mps2", type=_non_negative, default=d(0.0), metavar="SIGMA",
                     help="per-sample accelerometer noise [m/s^2] for linear_acceleration_covariance (default 0 = unknown)")

def parser() -> argparse.ArgumentParser:
    ap = _Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    io = ap.add_argument_group("inputs and output")
    io.add_argument("--imu", type=Path, metavar="CSV", help="IMU CSV log (a driver-style bag; or --nav for an installation)")
    io.add_argument("--pos", type=Path, metavar="POS", help="RTKLIB .pos solution (llh, degrees); without it the bag holds the IMU only")
    io.add_argument("--out", type=Path, required=True, metavar="DIR", help="rosbag2 directory to write (must not exist)")
    io.add_argument("--overwrite", action="store_true", help="replace --out when it is an existing rosbag2 directory")
    io.add_argument("--quiet", action="store_true", help="no progress on the terminal (none is shown when stderr is not one)")

    col = ap.add_argument_group("IMU CSV layout (0-based column indices; every --sub log's too)")
    add_layout(col)

    sel = ap.add_argument_group("selection (times in seconds after the first IMU sample of the log)")
    sel.add_argument("--gnss-rate", type=_positive, metavar="HZ",
                     help="keep the fixes on this grid of GPS time (1 = whole GPS seconds); default: every fix")
    sel.add_argument("--grid-tol-ms", type=_positive, default=5.0, metavar="MS",
                     help="--gnss-rate: largest distance of a kept fix from its grid epoch [ms] (default 5; the nearest fix per epoch is kept)")
    sel.add_argument("--min-quality", type=int, choices=sorted(Q_NAMES), metavar="Q",
                     help="keep fixes with RTKLIB Q <= this (1 fix, 2 float, 3 sbas, 4 dgps, 5 single, 6 ppp); default: all")
    sel.add_argument("--outage", type=_interval, action="append", default=[], metavar="START:END",
                     help="GNSS outage: no fix in [START, END) seconds after the first IMU sample (repeatable)")
    sel.add_argument("--start", type=finite_float, metavar="S", help="crop: drop IMU samples and fixes before START seconds after the first IMU sample")
    sel.add_argument("--end", type=finite_float, metavar="S", help="crop: drop IMU samples and fixes after END seconds after the first IMU sample")

    names = ap.add_argument_group("topics and frames (defaults like common drivers)")
    names.add_argument("--imu-topic", default="/imu/data", help="sensor_msgs/Imu topic (default /imu/data)")
    names.add_argument("--fix-topic", default="/fix", help="sensor_msgs/NavSatFix topic (default /fix)")
    names.add_argument("--vel-topic", default="/vel", help="geometry_msgs/TwistWithCovarianceStamped topic (default /vel)")
    names.add_argument("--imu-frame", default="imu_link", help="frame_id of the IMU messages (default imu_link)")
    names.add_argument("--gnss-frame", default="gps", help="frame_id of the GNSS messages (default gps)")
    install.add_options(ap, _int_triple, _positive, _non_negative)
    return ap


def layout_parser() -> argparse.ArgumentParser:
    """The parser of a --sub-options value: the IMU CSV layout options, only the given ones set."""
    lp = _Parser(prog=f"{PROG} --sub-options", add_help=False)
    add_layout(lp, suppress=True)
    lp.add_argument("--time-scale", choices=("gpst", "utc"), default=argparse.SUPPRESS)
    return lp


def _check_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Cross-option checks (one-line errors through ``ap.error``)."""
    if (args.imu is None) == (args.nav is None):
        ap.error("give --imu (an IMU log, a driver-style bag) or --nav (an installation: a navigation solution and --sub logs)")
    if args.nav is not None:
        if args.pos is not None:
            ap.error("--pos goes with --imu, not --nav")
        if not args.sub:
            ap.error("--nav needs at least one --sub NAME=CSV (a sub-IMU log)")
        return
    if args.sub or args.sub_options or args.aircraft:
        ap.error("--sub, --sub-options and --aircraft go with --nav")
    if args.time_col is None and args.tag is None:
        ap.error("the IMU stamps need GPS time: give --tag (RTKLIB time tag of the log) or --time-col")
    if args.time_col is not None and args.tag is not None:
        ap.error("give --tag or --time-col, not both")
    if args.counter_col is None and args.time_col is None:
        args.counter_col = 6
    if args.skip_header < 0:
        ap.error(f"--skip-header must be >= 0, got {args.skip_header}")
    if args.pos is None:
        given = [o for o, v in (("--gnss-rate", args.gnss_rate), ("--min-quality", args.min_quality), ("--outage", args.outage or None))
                 if v is not None]
        if given:
            ap.error(f"{', '.join(given)} need --pos (they select GNSS fixes)")
    if args.gnss_rate is not None:
        try:
            grid_offset_ns(np.zeros(1, dtype=np.int64), args.gnss_rate)
        except ValueError as exc:
            ap.error(f"--gnss-rate: {exc}")
    if args.start is not None and args.end is not None and not args.end > args.start:
        ap.error(f"--end {args.end:g} must be after --start {args.start:g}")
    topics = [args.imu_topic, args.fix_topic, args.vel_topic]
    bad = [t for t in topics if not t.startswith("/") or t.endswith("/") or " " in t]
    if bad:
        ap.error(f"topic names must be absolute ROS names: {', '.join(repr(t) for t in bad)}")
    if len(set(topics)) != len(topics):
        ap.error(f"--imu-topic, --fix-topic and --vel-topic must differ: {topics}")
    if not args.imu_frame or not args.gnss_frame:
        ap.error("--imu-frame and --gnss-frame must not be empty")


# ----------------------------------------------------------------------------- selection


@dataclass
class GnssSelection:
    """The fixes as read, the fixes written, and how many each step removed (steps in this order)."""

    read: PosLog
    pos: PosLog
    removed_by_rate: int = 0
    removed_by_quality: int = 0
    removed_by_outage: int = 0
    removed_by_crop: int = 0
    #: (min, max) signed distance [ms] of the written fixes from their --gnss-rate grid epoch
    grid_offset_ms: tuple[float, float] | None = None


def nearest_on_grid(t_ns: NDArray[np.int64], rate_hz: float, tol_s: float) -> NDArray[np.bool_]:
    """True for the epoch nearest to each ``rate_hz`` grid epoch of GPS time, if within ``tol_s``
    (one epoch per grid epoch even when the tolerance reaches two)."""
    off_ns = grid_offset_ns(t_ns, rate_hz)
    idx = np.flatnonzero(np.abs(off_ns) <= int(round(tol_s * 1e9)))
    keep = np.zeros(t_ns.shape, dtype=bool)
    if idx.size:
        grid_ns = (t_ns - off_ns)[idx]
        order = np.lexsort((np.abs(off_ns[idx]), grid_ns))  # by grid epoch, the nearest first
        first = np.ones(order.size, dtype=bool)
        first[1:] = grid_ns[order][1:] != grid_ns[order][:-1]
        keep[idx[order][first]] = True
    return keep


def crop_mask(t_ns: NDArray[np.int64], origin_ns: int, start_s: float | None, end_s: float | None) -> NDArray[np.bool_]:
    """True for the stamps within [start_s, end_s] seconds after ``origin_ns`` (None = open)."""
    rel_ns = t_ns - origin_ns
    keep = np.ones(t_ns.shape, dtype=bool)
    if start_s is not None:
        keep &= rel_ns >= int(round(start_s * 1e9))
    if end_s is not None:
        keep &= rel_ns <= int(round(end_s * 1e9))
    return keep


def select_gnss(pos: PosLog, origin_ns: int, args: argparse.Namespace) -> GnssSelection:
    """--gnss-rate, then --min-quality, --outage, --start/--end (times after ``origin_ns``, the first IMU stamp)."""
    sel = GnssSelection(read=pos, pos=pos)
    cur = pos
    if args.gnss_rate is not None:
        keep = nearest_on_grid(cur.t_ns, args.gnss_rate, args.grid_tol_ms * 1e-3)
        sel.removed_by_rate, cur = int((~keep).sum()), cur.select(keep)
    if args.min_quality is not None:
        keep = cur.quality <= args.min_quality
        sel.removed_by_quality, cur = int((~keep).sum()), cur.select(keep)
    if args.outage:
        keep = outage_mask(cur.t_ns, list(args.outage), origin_ns)
        sel.removed_by_outage, cur = int((~keep).sum()), cur.select(keep)
    if args.start is not None or args.end is not None:
        keep = crop_mask(cur.t_ns, origin_ns, args.start, args.end)
        sel.removed_by_crop, cur = int((~keep).sum()), cur.select(keep)
    sel.pos = cur
    if args.gnss_rate is not None and len(cur):
        off_ms = grid_offset_ns(cur.t_ns, args.gnss_rate) * 1e-6
        sel.grid_offset_ms = (float(off_ms.min()), float(off_ms.max()))
    return sel


def crop_imu(imu: ImuLog, origin_ns: int, start_s: float | None, end_s: float | None) -> ImuLog:
    """The samples within --start/--end (the counts of the log stay those of the whole log)."""
    keep = crop_mask(imu.t_ns, origin_ns, start_s, end_s)
    if keep.all():
        return imu
    return ImuLog(imu.t_ns[keep], imu.omega_radps[keep], imu.f_mps2[keep], imu.skipped, imu.repeated, imu.clock_scale)


# ----------------------------------------------------------------------------- messages


def navsat_status(quality: int) -> int:
    """RTKLIB Q -> NavSatStatus.status: GBAS_FIX for RTK fix / float (Q1, Q2), SBAS_FIX for Q3, else FIX."""
    st = typestore().types["sensor_msgs/msg/NavSatStatus"]
    if quality in (1, 2):
        return int(st.STATUS_GBAS_FIX)
    if quality == 3:
        return int(st.STATUS_SBAS_FIX)
    return int(st.STATUS_FIX)


def imu_stream(imu: ImuLog, topic: str, frame_id: str, gyro_sigma_radps: float, accel_sigma_mps2: float) -> TopicStream:
    """sensor_msgs/Imu rows (vectorized CDR, :func:`dpos_ros.contract.conversions.imu_rows`)."""
    rows = cv.imu_rows(frame_id, imu.t_ns, imu.omega_radps, imu.f_mps2, gyro_sigma_radps, accel_sigma_mps2)
    return TopicStream(topic, T.IMU, imu.t_ns, rows=rows)


def _header(ts: Any, t_ns: int, frame_id: str) -> Any:
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=int(t_ns // _NS), nanosec=int(t_ns % _NS))
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def fix_stream(pos: PosLog, topic: str, frame_id: str) -> TopicStream:
    """sensor_msgs/NavSatFix per fix: degrees, ellipsoidal height, full ENU covariance [m^2] (REP 145)."""
    ts = typestore()
    NavSatFix, NavSatStatus = ts.types[T.NAVSATFIX], ts.types["sensor_msgs/msg/NavSatStatus"]
    status_of = {int(q): navsat_status(int(q)) for q in np.unique(pos.quality)}
    blobs = []
    for i in range(len(pos)):
        msg = NavSatFix(
            header=_header(ts, int(pos.t_ns[i]), frame_id),
            status=NavSatStatus(status=status_of[int(pos.quality[i])], service=NavSatStatus.SERVICE_GPS),
            latitude=float(np.rad2deg(pos.llh[i, 0])), longitude=float(np.rad2deg(pos.llh[i, 1])), altitude=float(pos.llh[i, 2]),
            position_covariance=np.array(pos.pos_cov_enu_m2[i], dtype=np.float64).reshape(9),
            position_covariance_type=NavSatFix.COVARIANCE_TYPE_KNOWN,
        )
        blobs.append(bytes(ts.serialize_cdr(msg, T.NAVSATFIX)))
    return TopicStream(topic, T.NAVSATFIX, pos.t_ns.copy(), blobs=tuple(blobs))


def vel_stream(pos: PosLog, topic: str, frame_id: str) -> TopicStream:
    """geometry_msgs/TwistWithCovarianceStamped per fix with a velocity: ENU velocity [m/s] and its
    covariance [m^2/s^2] in the linear block, angular block diagonal -1 (unknown)."""
    ts = typestore()
    Vector3, Twist = ts.types["geometry_msgs/msg/Vector3"], ts.types["geometry_msgs/msg/Twist"]
    TwistCov, Msg = ts.types["geometry_msgs/msg/TwistWithCovariance"], ts.types[T.TWIST_COV]
    have = np.all(np.isfinite(pos.vel_n_mps), axis=1) & np.all(np.isfinite(pos.vel_cov_enu), axis=(1, 2))
    blobs = []
    for i in np.flatnonzero(have):
        v_enu_mps = pos.vel_n_mps[i]
        cov = np.zeros((6, 6))
        cov[:3, :3] = pos.vel_cov_enu[i]
        np.fill_diagonal(cov[3:, 3:], -1.0)
        linear = Vector3(x=float(v_enu_mps[0]), y=float(v_enu_mps[1]), z=float(v_enu_mps[2]))
        msg = Msg(header=_header(ts, int(pos.t_ns[i]), frame_id),
                  twist=TwistCov(twist=Twist(linear=linear, angular=Vector3(x=0.0, y=0.0, z=0.0)), covariance=cov.reshape(36)))
        blobs.append(bytes(ts.serialize_cdr(msg, T.TWIST_COV)))
    return TopicStream(topic, T.TWIST_COV, pos.t_ns[have].copy(), blobs=tuple(blobs))


# ----------------------------------------------------------------------------- report


def gpst_text(t_ns: int) -> str:
    """``2025-08-28 17:30:40.961`` (GPST on the Unix calendar, millisecond resolution, truncated)."""
    sec, ns = divmod(int(t_ns), _NS)
    d = dt.datetime.fromtimestamp(sec, tz=dt.UTC)
    return f"{d:%Y-%m-%d %H:%M:%S}.{ns // 1_000_000:03d}"


def gps_week_tow(t_ns: int) -> tuple[int, float]:
    """(GPS week, time of week [s]) of a GPST stamp on the Unix calendar."""
    week, tow_ns = divmod(int(t_ns) - GPS_EPOCH_UNIX_S * _NS, _WEEK_S * _NS)
    return int(week), tow_ns * 1e-9


def _span(t_ns: NDArray[np.int64]) -> dict[str, Any] | None:
    if t_ns.size == 0:
        return None
    week, tow_s = gps_week_tow(int(t_ns[0]))
    return {"first_ns": int(t_ns[0]), "last_ns": int(t_ns[-1]), "first_gpst": gpst_text(int(t_ns[0])),
            "last_gpst": gpst_text(int(t_ns[-1])), "first_gps_week": week, "first_tow_s": round(tow_s, 6),
            "duration_s": round((int(t_ns[-1]) - int(t_ns[0])) * 1e-9, 6)}


def _skipped(skipped: list[tuple[int, str]]) -> dict[str, Any]:
    return {"count": len(skipped), "first": [{"line": n, "reason": why} for n, why in skipped[:SHOWN_SKIPPED]]}


def _q_hist(quality: NDArray[np.int64]) -> dict[str, int]:
    vals, counts = np.unique(quality, return_counts=True)
    return {str(int(v)): int(c) for v, c in zip(vals, counts)}


def build_report(args: argparse.Namespace, imu_read: ImuLog, imu: ImuLog, sel: GnssSelection | None,
                 streams: dict[str, TopicStream]) -> dict[str, Any]:
    """The import report (printed, and ``import_report.json``): durations [s], intervals [ms], stamps [ns GPST]."""
    d_ms = np.diff(imu.t_ns) * 1e-6
    rep: dict[str, Any] = {
        "out": str(args.out),
        "inputs": {"imu": str(args.imu), "tag": None if args.tag is None else str(args.tag),
                   "pos": None if args.pos is None else str(args.pos)},
        "imu": {
            "samples_read": len(imu_read), "samples_written": len(imu), "removed_by_crop": len(imu_read) - len(imu),
            "lines_skipped": _skipped(imu_read.skipped), "repeated_samples": imu_read.repeated,
            "time_source": "time column" if args.time_col is not None else "counter mapped onto the time tag",
            "clock_scale": imu_read.clock_scale,
            "interval_ms": None if d_ms.size == 0 else {"median": float(np.median(d_ms)), "mean": float(d_ms.mean()),
                                                        "min": float(d_ms.min()), "max": float(d_ms.max())},
            "span": _span(imu.t_ns),
        },
        "gnss": None,
        "first_imu_to_first_fix_s": None,
        "crop_s": {"start": args.start, "end": args.end},
        "topics": {topic: {"type": s.msgtype, "messages": len(s)} for topic, s in streams.items()},
        "frames": {"imu": args.imu_frame, "gnss": args.gnss_frame},
    }
    if sel is not None:
        pos = sel.pos
        rep["gnss"] = {
            "fixes_read": len(sel.read), "lines_skipped": _skipped(sel.read.skipped), "lines_reordered": sel.read.reordered,
            "q_histogram_read": _q_hist(sel.read.quality), "has_velocity": sel.read.has_velocity,
            "gnss_rate_hz": args.gnss_rate, "kept_after_rate": len(sel.read) - sel.removed_by_rate,
            "removed_by_rate": sel.removed_by_rate, "removed_by_quality": sel.removed_by_quality,
            "removed_by_outage": sel.removed_by_outage, "removed_by_crop": sel.removed_by_crop,
            "fixes_written": len(pos), "q_histogram_written": _q_hist(pos.quality),
            "grid_offset_ms": None if sel.grid_offset_ms is None else {"min": sel.grid_offset_ms[0], "max": sel.grid_offset_ms[1]},
            "outages_s": [list(o) for o in args.outage], "min_quality": args.min_quality,
            "span": _span(pos.t_ns),
        }
        if len(pos) and len(imu):
            rep["first_imu_to_first_fix_s"] = round((int(pos.t_ns[0]) - int(imu.t_ns[0])) * 1e-9, 6)
    return rep


def _q_text(hist: dict[str, int]) -> str:
    return ", ".join(f"Q{q} ({Q_NAMES.get(int(q), '?')}) {n}" for q, n in hist.items()) or "none"


def summary_lines(rep: dict[str, Any]) -> list[str]:
    """The printed summary of a report (:func:`build_report`)."""
    im = rep["imu"]
    topics = rep["topics"]
    imu_topic = next(t for t, v in topics.items() if v["type"] == T.IMU)
    out = [f"{PROG}: {rep['inputs']['imu']}" + "".join(f" + {rep['inputs'][k]}" for k in ("tag", "pos") if rep["inputs"][k])
           + f" -> {rep['out']}"]
    sk = im["lines_skipped"]
    out.append(f"IMU   {im['samples_written']} samples written to {imu_topic} (sensor_msgs/Imu, frame {rep['frames']['imu']}) "
               f"of {im['samples_read']} read" + (f", {im['removed_by_crop']} removed by crop" if im["removed_by_crop"] else ""))
    out.append(f"      lines skipped: {sk['count']}")
    out += [f"        line {e['line']}: {e['reason']}" for e in sk["first"]]
    if sk["count"] > len(sk["first"]):
        out.append(f"        ... and {sk['count'] - len(sk['first'])} more")
    out.append(f"      repeated samples (all six values equal the previous; kept): {im['repeated_samples']}")
    out.append(f"      time: {im['time_source']}, clock scale {im['clock_scale']:.6f} GPST s per IMU s")
    iv = im["interval_ms"]
    if iv:
        out.append(f"      intervals: median {iv['median']:.3f} ms, min {iv['min']:.3f} ms, max {iv['max']:.3f} ms "
                   f"(mean {iv['mean']:.3f} ms = {1e3 / iv['mean']:.1f} Hz)")
    if im["span"]:
        sp = im["span"]
        out.append(f"      GPST {sp['first_gpst']} .. {sp['last_gpst']} ({sp['duration_s']:.3f} s; week {sp['first_gps_week']}, "
                   f"tow {sp['first_tow_s']:.3f} s)")
    g = rep["gnss"]
    if g is None:
        out.append("GNSS  none (no --pos)")
    else:
        gs = g["lines_skipped"]
        out.append(f"GNSS  {g['fixes_read']} fixes read ({gs['count']} lines skipped{'' if g['has_velocity'] else ', no velocity columns'}): "
                   f"{_q_text(g['q_histogram_read'])}")
        out += [f"        line {e['line']}: {e['reason']}" for e in gs["first"]]
        if gs["count"] > len(gs["first"]):
            out.append(f"        ... and {gs['count'] - len(gs['first'])} more")
        if g["lines_reordered"]:
            out.append(f"      warning: {g['lines_reordered']} line(s) out of stamp order in the .pos: sorted by stamp")
        if g["gnss_rate_hz"] is not None:
            off = g["grid_offset_ms"]
            where = f"; kept fixes {off['min']:+.3f} .. {off['max']:+.3f} ms from the grid" if off else ""
            out.append(f"      --gnss-rate {g['gnss_rate_hz']:g} Hz: {g['kept_after_rate']} kept, {g['removed_by_rate']} removed{where}")
        outages = (", ".join(f"[{a:g}, {b:g})" for a, b in g["outages_s"]) + " s") if g["outages_s"] else "no --outage"
        quality = "no --min-quality" if g["min_quality"] is None else f"--min-quality {g['min_quality']}"
        out.append(f"      removed: {g['removed_by_quality']} by quality ({quality}), "
                   f"{g['removed_by_outage']} by outage ({outages}), {g['removed_by_crop']} by crop")
        fix_vel = [f"{t} ({v['type'].split('/')[-1]}, {v['messages']})" for t, v in topics.items() if v["type"] != T.IMU]
        out.append(f"      {g['fixes_written']} fixes written, frame {rep['frames']['gnss']}: {', '.join(fix_vel)}")
        out.append(f"      written: {_q_text(g['q_histogram_written'])}")
        if g["span"]:
            sp = g["span"]
            out.append(f"      GPST {sp['first_gpst']} .. {sp['last_gpst']} ({sp['duration_s']:.3f} s)")
        if rep["first_imu_to_first_fix_s"] is not None:
            out.append(f"first fix - first IMU sample: {rep['first_imu_to_first_fix_s']:+.3f} s")
    return out


# ----------------------------------------------------------------------------- output


def _check_out(out: Path, overwrite: bool) -> None:
    """An existing --out: refused without --overwrite, and never replaced unless it is a rosbag2 directory or empty."""
    if not out.exists() and not out.is_symlink():
        return
    if not overwrite:
        raise ImportFailure(f"--out {out} exists (pass --overwrite to replace it)")
    if not out.is_dir() or out.is_symlink() or not ((out / "metadata.yaml").is_file() or not any(out.iterdir())):
        raise ImportFailure(f"--out {out} exists and is not a rosbag2 directory: not replacing it")


def write_bag(out: Path, streams: list[TopicStream], custom_data: dict[str, str], report: dict[str, Any], overwrite: bool,
              stages: Stages | None = None) -> int:
    """Write the bag and its report into a temporary directory next to ``out`` and rename it to
    ``out`` at the end (replacing an existing one with ``overwrite``); nothing is left on failure.
    ``stages``: the progress (a stage line and a bar of the messages written)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    bar = None
    if stages is not None:
        stages.stage(f"writing {sum(len(s) for s in streams)} messages on {len(streams)} topics to {out}")
        bar = stages.bar("writing")
    try:
        bag_dir = tmp / out.name  # the bag's file names follow its directory name
        n = write_streams(bag_dir, streams, progress=bar, custom_data=custom_data)
        (bag_dir / REPORT_NAME).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
        replaced = None
        if out.exists():
            _check_out(out, overwrite)
            replaced = tmp / "replaced"
            out.rename(replaced)
        try:
            bag_dir.rename(out)
        except OSError:
            if replaced is not None:
                replaced.rename(out)  # put the old bag back
            raise
    finally:
        if bar is not None:
            bar.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return n


# ----------------------------------------------------------------------------- main


def _read_logs(args: argparse.Namespace) -> tuple[ImuLog, PosLog | None]:
    def missing(path: Path, what: str) -> None:
        if not path.is_file():
            raise ImportFailure(f"{what} {path}: {'is a directory' if path.is_dir() else 'no such file'}")

    missing(args.imu, "--imu")
    if args.tag is not None:
        missing(args.tag, "--tag")
    if args.pos is not None:
        missing(args.pos, "--pos")
    try:
        columns = ImuColumns(accel=args.accel_cols, gyro=args.gyro_cols, accel_unit=args.accel_unit, gyro_unit=args.gyro_unit,
                             counter=args.counter_col, counter_unit_s=args.counter_unit_s, time=args.time_col,
                             skip_header=args.skip_header, delimiter=args.delimiter)
    except ValueError as exc:
        raise ImportFailure(f"IMU columns: {exc}") from None
    tag = None if args.tag is None else read_tag(args.tag)
    imu = read_imu_csv(args.imu, columns, tag)
    install.refuse_implausible_imu(f"--imu {args.imu}", imu, columns)
    if args.time_col is not None and args.time_scale == "utc":
        imu.t_ns = to_gpst_ns(imu.t_ns, "utc")  # the leap seconds of the date
    pos = None if args.pos is None else read_pos(args.pos)
    return imu, pos


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Read, select, write; returns the report. Raises :class:`ImportFailure`, LogFormatError, OSError."""
    _check_out(args.out, args.overwrite)
    st: Stages | None = getattr(args, "stages", None)
    if st is not None:
        st.stage(f"reading {args.imu}" + (f" and {args.pos}" if args.pos is not None else ""))
    imu_read, pos_read = _read_logs(args)
    origin_ns = int(imu_read.t_ns[0])
    if pos_read is not None:
        apart = plausibility.check_overlap(f"--imu {args.imu} and --pos {args.pos}", (imu_read.t_ns[0] * 1e-9, imu_read.t_ns[-1] * 1e-9),
                                           (pos_read.t_ns[0] * 1e-9, pos_read.t_ns[-1] * 1e-9))
        if apart is not None:
            raise ImportFailure(str(apart))
        within = (pos_read.t_ns >= imu_read.t_ns[0]) & (pos_read.t_ns <= imu_read.t_ns[-1])  # the course while the IMU logged
        course = plausibility.course_rate_radps(np.asarray((pos_read.t_ns[within] - origin_ns) * 1e-9, dtype=np.float64),
                                                pos_read.llh[within])
        scale = plausibility.check_rate_scale(f"--imu {args.imu}", imu_read.omega_radps, course, f"the course of --pos {args.pos}")
        if scale is not None:
            raise ImportFailure(f"{scale} (read with --gyro-unit {args.gyro_unit})")
    imu = crop_imu(imu_read, origin_ns, args.start, args.end)
    if len(imu) == 0:
        raise ImportFailure(f"no IMU sample within --start/--end (the log spans {(imu_read.t_ns[-1] - origin_ns) * 1e-9:.3f} s)")
    sel = None if pos_read is None else select_gnss(pos_read, origin_ns, args)
    if sel is not None and len(sel.pos) == 0:
        raise ImportFailure(f"{args.pos}: no fix left of {len(sel.read)} (removed: {sel.removed_by_rate} by --gnss-rate, "
                            f"{sel.removed_by_quality} by --min-quality, {sel.removed_by_outage} by --outage, {sel.removed_by_crop} by crop)")
    streams = {args.imu_topic: imu_stream(imu, args.imu_topic, args.imu_frame, args.gyro_sigma_radps, args.accel_sigma_mps2)}
    if sel is not None:
        streams[args.fix_topic] = fix_stream(sel.pos, args.fix_topic, args.gnss_frame)
        vel = vel_stream(sel.pos, args.vel_topic, args.gnss_frame)
        if len(vel):
            streams[args.vel_topic] = vel
    report = build_report(args, imu_read, imu, sel, streams)
    custom = {"dpos.import_sources": json.dumps(report["inputs"]),
              "dpos.import_command": " ".join([PROG, *getattr(args, "argv", [])])}
    write_bag(args.out, list(streams.values()), custom, report, args.overwrite, st)
    return report


def run_installation(ap: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, Any]:
    """--nav: the installation's recording (dpos_ros.cli.import_install); returns the report."""
    _check_out(args.out, args.overwrite)
    streams, custom, report = install.run_installation(args)
    custom["dpos.import_command"] = " ".join([PROG, *getattr(args, "argv", [])])
    write_bag(args.out, streams, custom, report, args.overwrite, getattr(args, "stages", None))
    return report


@one_line_errors(PROG)
def main(argv: list[str] | None = None) -> int:
    ap = parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = ap.parse_args(argv)
    _check_args(ap, args)
    args.argv = argv
    args.stages = Stages(PROG, quiet=args.quiet)  # the progress (stderr, on a terminal)
    try:
        if args.nav is not None:
            args.layouts = install.sub_layouts(ap, layout_parser(), args)
            report = run_installation(ap, args)
        else:
            report = run(args)
    except (ImportFailure, LogFormatError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{PROG}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_ERROR
    for line in (install.summary_lines(report, PROG) if args.nav is not None else summary_lines(report)):
        print(line)
    size_mb = sum(f.stat().st_size for f in args.out.iterdir()) / 1e6
    n = sum(v["messages"] for v in report["topics"].values())
    print(f"wrote {args.out}: {n} messages on {len(report['topics'])} topics, {size_mb:.1f} MB; report {args.out / REPORT_NAME}")
    return EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
