"""A main navigation solution exported as CSV (a POS's real-time output or its post-processed
trajectory) -> time-stamped positions, velocities, attitudes and sigmas.

Columns (0-based) and conventions come from :class:`NavColumns`.  Output frames are the
product's (design.md): geodetic latitude/longitude [rad] and ellipsoidal height [m]; velocity in
local-level ENU [m/s]; attitude ``C_nb`` of the FLU body in ENU (from aviation roll/pitch and a
heading either clockwise from north or an ENU yaw counter-clockwise from east); stamps [ns GPST on
the Unix calendar] (:mod:`dpos_core.imports.timescales`, leap seconds from the table).

Time forms: ``unix`` (seconds on the Unix calendar in ``time_scale``), ``gps`` (seconds since the
GPS epoch 1980-01-06), ``week_sow`` (a week column and a seconds-of-week column), ``datetime``
(``YYYY-MM-DD HH:MM:SS[.fff]`` strings in ``time_scale``) and ``elapsed`` (seconds x
``time_unit_s`` since an epoch: ``epoch`` given, or estimated from a coarse date-time column
``epoch_col``, e.g. a flight log's whole-second UTC stamps).

Bad lines are never fatal: they are skipped and listed (line number, reason).
"""

from __future__ import annotations

import csv
import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.errors import LogFormatError
from dpos_core.frames import C_nb_from_hpr

from ..units import DEG, FloatArray
from .logs import data_fields, first_reasons
from .timescales import GPS_EPOCH_UNIX_S, TIME_SCALES, datetime_ns, decimal_ns, to_gpst_ns, week_sow_ns

TIME_FORMS = ("unix", "gps", "week_sow", "datetime", "elapsed")
HEADINGS = ("north_cw", "east_ccw")
VEL_FRAMES = ("ned", "enu")
ANGLE_UNITS = {"deg": DEG, "rad": 1.0}
_NS = 1_000_000_000


@dataclass(frozen=True)
class NavColumns:
    """Where the fields of a navigation-solution CSV are (0-based columns) and their conventions.

    Attributes:
        time: time column; ``week``: the GPS-week column (``time_form`` ``week_sow``).
        time_form: one of :data:`TIME_FORMS`; time_scale: ``gpst`` or ``utc`` (``unix``,
            ``datetime``, ``elapsed``); time_unit_s: seconds per unit of an ``elapsed`` column.
        epoch: date-time of elapsed 0 (``elapsed``), or None; epoch_col: a date-time column (coarse,
            truncated to its resolution) the epoch is estimated from, or None.
        llh: latitude, longitude, ellipsoidal height columns; latlon_unit ``deg`` or ``rad``.
        vel: velocity columns in ``vel_frame`` order (``ned``: north, east, down; ``enu``).
        att: roll, pitch, heading columns (aviation roll/pitch); angle_unit ``deg`` or ``rad``;
            heading ``north_cw`` (true heading) or ``east_ccw`` (ENU yaw).
        pos_sigma / vel_sigma / att_sigma: optional sigma columns (north, east, up [m]; the velocity
            frame's order [m/s]; roll, pitch, heading [angle_unit]); None = take them from options.
        skip_header: leading lines to ignore; delimiter: field separator (blank = any whitespace).
    """

    time: int = 0
    time_form: str = "unix"
    time_scale: str = "gpst"
    time_unit_s: float = 1.0
    week: int | None = None
    epoch: str | None = None
    epoch_col: int | None = None
    llh: tuple[int, int, int] = (1, 2, 3)
    latlon_unit: str = "deg"
    vel: tuple[int, int, int] = (4, 5, 6)
    vel_frame: str = "ned"
    att: tuple[int, int, int] = (7, 8, 9)
    angle_unit: str = "deg"
    heading: str = "north_cw"
    pos_sigma: tuple[int, int, int] | None = None
    vel_sigma: tuple[int, int, int] | None = None
    att_sigma: tuple[int, int, int] | None = None
    skip_header: int = 0
    delimiter: str = ","

    def __post_init__(self) -> None:
        for name, val, allowed in (("time_form", self.time_form, TIME_FORMS), ("time_scale", self.time_scale, TIME_SCALES),
                                   ("heading", self.heading, HEADINGS), ("vel_frame", self.vel_frame, VEL_FRAMES),
                                   ("angle_unit", self.angle_unit, tuple(ANGLE_UNITS)), ("latlon_unit", self.latlon_unit, tuple(ANGLE_UNITS))):
            if val not in allowed:
                raise ValueError(f"{name} must be one of {list(allowed)}, got {val!r}")
        if self.time_form == "week_sow" and self.week is None:
            raise ValueError("time_form week_sow needs the week column")
        if self.time_form == "elapsed" and (self.epoch is None) == (self.epoch_col is None):
            raise ValueError("time_form elapsed needs the epoch or an epoch column (one of the two)")
        if not self.time_unit_s > 0:
            raise ValueError(f"time_unit_s must be > 0, got {self.time_unit_s}")
        if self.epoch is not None:
            datetime_ns(self.epoch)  # ValueError naming it
        cols = [c for c in self.columns if c is not None]
        if min(cols) < 0:
            raise ValueError(f"columns must be >= 0, got {cols}")

    @property
    def columns(self) -> list[int | None]:
        return [self.time, self.week, self.epoch_col, *self.llh, *self.vel, *self.att,
                *(self.pos_sigma or ()), *(self.vel_sigma or ()), *(self.att_sigma or ())]

    @property
    def width(self) -> int:
        return 1 + max(c for c in self.columns if c is not None)


@dataclass
class NavSolution:
    """A navigation solution read from a log.

    Attributes:
        t_ns: (N,) stamps [ns GPST, Unix calendar], strictly increasing.
        llh: (N, 3) latitude, longitude [rad], ellipsoidal height [m].
        vel_n_mps: (N, 3) velocity, local-level ENU [m/s].
        C_nb: (N, 3, 3) FLU body -> local ENU.
        hpr_rad: (N, 3) heading (clockwise from north), pitch, roll [rad] as read.
        pos_sigma_m: (N, 3) east, north, up 1 sigma [m], or None (not in the file).
        vel_sigma_mps: (N, 3) east, north, up [m/s], or None.
        hpr_sigma_rad: (N, 3) heading, pitch, roll [rad], or None.
        skipped: (line number, reason) of every line not used.
        epoch_note: how the time was made absolute (for the report).
    """

    t_ns: NDArray[np.int64]
    llh: FloatArray
    vel_n_mps: FloatArray
    C_nb: FloatArray
    hpr_rad: FloatArray
    pos_sigma_m: FloatArray | None = None
    vel_sigma_mps: FloatArray | None = None
    hpr_sigma_rad: FloatArray | None = None
    skipped: list[tuple[int, str]] = field(default_factory=list)
    epoch_note: str = ""

    def __len__(self) -> int:
        return int(self.t_ns.size)


def _split(line: str, delimiter: str) -> list[str]:
    if delimiter.strip():
        return next(csv.reader([line], delimiter=delimiter))
    return line.split()


def _stamp(parts: list[str], c: NavColumns) -> int:
    """The line's time in ns: absolute in ``time_scale`` (not yet GPST), or elapsed ns (``elapsed``)."""
    t = parts[c.time]
    if c.time_form == "unix":
        return decimal_ns(t)
    if c.time_form == "gps":
        return GPS_EPOCH_UNIX_S * _NS + decimal_ns(t)
    if c.time_form == "week_sow":
        assert c.week is not None
        return week_sow_ns(int(parts[c.week]), t)
    if c.time_form == "datetime":
        return datetime_ns(t)
    return int(round(decimal_ns(t) * c.time_unit_s))


def read_nav_csv(path: str | Path, c: NavColumns) -> NavSolution:
    """Read a navigation-solution CSV (module docstring).  Lines with too few fields, a field that
    is not a finite number (or date), or a stamp not after the previous are skipped and listed.
    Raises :class:`LogFormatError` when no line is usable."""
    p = Path(path)
    rows: list[list[float]] = []
    stamps: list[int] = []
    coarse: list[int] = []
    skipped: list[tuple[int, str]] = []
    num_cols = [*c.llh, *c.vel, *c.att, *(c.pos_sigma or ()), *(c.vel_sigma or ()), *(c.att_sigma or ())]
    last: int | None = None
    for lineno, parts in data_fields(p, c.skip_header, c.width, lambda s: _split(s, c.delimiter), skipped):
        try:
            vals = [float(parts[k]) for k in num_cols]
            t = _stamp(parts, c)
            ep = datetime_ns(parts[c.epoch_col]) if c.epoch_col is not None else 0
        except (ValueError, ArithmeticError, IndexError):
            skipped.append((lineno, "a field is not a number (or not a date)"))
            continue
        if not all(np.isfinite(vals)):
            skipped.append((lineno, "a field is not finite"))
            continue
        if last is not None and t <= last:
            skipped.append((lineno, f"time {t * 1e-9:.3f} s not after the previous {last * 1e-9:.3f} s"))
            continue
        last = t
        rows.append(vals)
        stamps.append(t)
        coarse.append(ep)
    if not rows:
        first = first_reasons(skipped)
        raise LogFormatError(f"{p}: no usable navigation line ({len(skipped)} skipped{': ' + first if first else ''})")
    a = np.array(rows)
    t_ns = np.array(stamps, dtype=np.int64)
    note = {"unix": f"seconds on the Unix calendar ({c.time_scale})", "gps": "seconds since the GPS epoch (GPST)",
            "week_sow": "GPS week and seconds of week (GPST)", "datetime": f"date-time strings ({c.time_scale})"}.get(c.time_form, "")
    if c.time_form == "elapsed":
        if c.epoch is not None:
            epoch_ns = datetime_ns(c.epoch)
            note = f"elapsed x {c.time_unit_s:g} s since the epoch {c.epoch} ({c.time_scale})"
        else:
            # a truncated date-time d_i <= epoch + elapsed_i: the epoch is at least max(d_i - elapsed_i),
            # and within the sample interval of it when the log is longer than the column's resolution;
            # over the lines before the first jump of d_i - elapsed_i (a logger whose elapsed time pauses)
            dd = np.array(coarse, dtype=np.int64) - t_ns
            jumps = np.flatnonzero(np.abs(dd - dd[0]) > 2 * _NS)
            head = dd if jumps.size == 0 else dd[:jumps[0]]
            epoch_ns = int(np.max(head))
            note = (f"elapsed x {c.time_unit_s:g} s since an epoch from column {c.epoch_col} ({c.time_scale}): "
                    f"the latest of (date-time - elapsed), {_iso(epoch_ns)}")
            if jumps.size:
                steps = np.flatnonzero(np.abs(np.diff(dd)) > 2 * _NS) + 1
                note += (f"; over the first {jumps[0]} lines: the date-time jumps against the elapsed time by "
                         + ", ".join(f"{(dd[k] - dd[k - 1]) * 1e-9:+.1f} s at elapsed {t_ns[k] * 1e-9:.1f} s" for k in steps[:5]))
        t_ns = t_ns + epoch_ns
    if c.time_form in ("unix", "datetime", "elapsed"):
        t_ns = to_gpst_ns(t_ns, c.time_scale)
    k = 0
    lat_lon = a[:, 0:2] * ANGLE_UNITS[c.latlon_unit]
    llh = np.column_stack([lat_lon, a[:, 2]])
    k = 3
    v = a[:, k:k + 3]
    k += 3
    vel_enu = np.column_stack([v[:, 1], v[:, 0], -v[:, 2]]) if c.vel_frame == "ned" else v.copy()
    ang = a[:, k:k + 3] * ANGLE_UNITS[c.angle_unit]  # roll, pitch, heading
    k += 3
    heading = ang[:, 2] if c.heading == "north_cw" else np.pi / 2 - ang[:, 2]
    heading = np.mod(heading, 2 * np.pi)
    hpr = np.column_stack([heading, ang[:, 1], ang[:, 0]])
    C_nb = C_nb_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2])
    pos_sig = vel_sig = att_sig = None
    if c.pos_sigma is not None:
        s = np.abs(a[:, k:k + 3])
        pos_sig = np.column_stack([s[:, 1], s[:, 0], s[:, 2]])  # north, east, up -> east, north, up
        k += 3
    if c.vel_sigma is not None:
        s = np.abs(a[:, k:k + 3])
        vel_sig = np.column_stack([s[:, 1], s[:, 0], s[:, 2]]) if c.vel_frame == "ned" else s
        k += 3
    if c.att_sigma is not None:
        s = np.abs(a[:, k:k + 3]) * ANGLE_UNITS[c.angle_unit]
        att_sig = np.column_stack([s[:, 2], s[:, 1], s[:, 0]])
        k += 3
    return NavSolution(t_ns, llh, vel_enu, C_nb, hpr, pos_sig, vel_sig, att_sig, sorted(skipped), note)


#: :func:`vertical_consistency`: the window [s] over which the height is checked against the integral
#: of the vertical speed, and the bound in sigmas of the difference beyond which the two disagree
VERTICAL_WINDOW_S = 2.0
VERTICAL_BOUND_SIGMAS = 3.0
#: :func:`vertical_consistency`: the half-width [s] of the neighbourhood over which the windows'
#: differences give an epoch's variance factor (their rms in sigmas)
VERTICAL_NEIGHBOURHOOD_S = 10.0


@dataclass(frozen=True)
class VerticalCheck:
    """:func:`vertical_consistency`'s result.

    Attributes:
        sigma_h_m: (N,) the height 1 sigma [m], widened where the check fails.
        sigma_vu_mps: (N,) the vertical-speed 1 sigma [m/s], widened where it fails.
        widened: (N,) the epochs widened.
        max_disagreement_m: the largest ``|dh - int v_up dt|`` over a window [m].
        max_sigmas: that disagreement's largest ratio to its sigma.
        spans_s: the widened spans (start, end) [s of ``t_s``].
        span_disagreement_m: the largest ``|dh - int v_up dt|`` between two epochs of one widened
            span [m] (0 when none is widened), and span_sigmas its ratio to its sigma.
        rms_factor: (N,) the variance factor of each epoch's neighbourhood (the windows' rms in
            sigmas within ``VERTICAL_NEIGHBOURHOOD_S``; at least 1), the least each epoch's sigmas
            were multiplied by (``None``: 1 everywhere).
    """

    sigma_h_m: FloatArray
    sigma_vu_mps: FloatArray
    widened: NDArray[np.bool_]
    max_disagreement_m: float
    max_sigmas: float
    spans_s: list[tuple[float, float]]
    span_disagreement_m: float = 0.0
    span_sigmas: float = 0.0
    rms_factor: FloatArray | None = None

    @property
    def max_rms_factor(self) -> float:
        """The largest neighbourhood variance factor (1: no epoch widened by it)."""
        return 1.0 if self.rms_factor is None or self.rms_factor.size == 0 else float(self.rms_factor.max())


def vertical_consistency(t_s: FloatArray, h_m: FloatArray, v_up_mps: FloatArray, sigma_h_m: FloatArray, sigma_vu_mps: FloatArray,
                         window_s: float = VERTICAL_WINDOW_S, bound_sigmas: float = VERTICAL_BOUND_SIGMAS,
                         neighbourhood_s: float = VERTICAL_NEIGHBOURHOOD_S) -> VerticalCheck:
    """A navigation solution checked against itself: over every window of ``window_s`` (from each
    epoch to the first one ``window_s`` later) the height change against the trapezoid integral of
    the vertical speed, ``r = h_j - h_i - int_i^j v_up dt``, whose 1 sigma from the solution's own
    sigmas is ``s = sqrt(sigma_h,i^2 + sigma_h,j^2 + sum_k (sigma_vu,k dt_k)^2)`` (the vertical
    speed's errors white at the solution's epochs, as the sigmas per epoch say).  Where
    ``|r| > bound_sigmas s`` the solution is inconsistent with itself - its height and its vertical
    speed cannot both be right - and both sigmas over the window's epochs are multiplied by
    ``|r| / (2 s)`` (the largest over the failing windows holding an epoch): the difference is then
    2 sigmas, which does not say which of the two is wrong.  Within a widened span the disagreement
    may accumulate beyond one window (quad_mimu's path 1: 1 m over 2 s, 2 m over 6 s), and a filter
    or smoother integrates the speed over the whole span: the span's largest difference, between
    its epochs where ``h - int v_up dt`` is highest and lowest, is made 2 sigmas too (the larger
    factor wins).  And the windows that pass are no evidence that the stated sigmas hold near
    failing ones: the solution's vertical errors are correlated over seconds (path 1's spans: 4-6 s,
    1-2 s apart; its last 3 s pass and still pulled the transfer alignment's misalignment by about
    0.3 deg, docs/real.md "Path 1's DOT2").  So
    every epoch's sigmas are also multiplied by its neighbourhood's variance factor, the rms of
    ``r / s`` over the windows starting within ``neighbourhood_s`` of it, where above 1 (a
    consistent solution's windows have an rms of 0.2-0.5 sigmas: quad_mimu's paths 2-4 and raw log;
    path 1: 3.4); the largest factor wins.  ``t_s`` (N,) [s], the others (N,)."""
    t = np.asarray(t_s, dtype=float)
    h = np.asarray(h_m, dtype=float)
    vu = np.asarray(v_up_mps, dtype=float)
    sh = np.asarray(sigma_h_m, dtype=float).copy()
    sv = np.asarray(sigma_vu_mps, dtype=float).copy()
    n = t.size
    if n < 2:
        return VerticalCheck(sh, sv, np.zeros(n, dtype=bool), 0.0, 0.0, [])
    dt_ = np.diff(t)
    integ = np.concatenate([[0.0], np.cumsum(0.5 * (vu[1:] + vu[:-1]) * dt_)])
    # the integral's variance: each epoch's speed enters with the weight (dt_left + dt_right) / 2
    w = np.concatenate([[0.0], 0.5 * dt_]) + np.concatenate([0.5 * dt_, [0.0]])
    var_int = np.concatenate([[0.0], np.cumsum((sv * w) ** 2)])
    j = np.searchsorted(t, t + window_s - 1e-9)
    i = np.flatnonzero(j < n)
    j = j[i]
    if i.size == 0:
        return VerticalCheck(sh, sv, np.zeros(n, dtype=bool), 0.0, 0.0, [])
    r = (h[j] - h[i]) - (integ[j] - integ[i])
    s = np.sqrt(sh[i] ** 2 + sh[j] ** 2 + (var_int[j + 1] - var_int[i]))
    z = np.abs(r) / s
    # each epoch's neighbourhood variance factor: the rms of z over the windows starting within neighbourhood_s of it
    cz2 = np.concatenate([[0.0], np.cumsum(z**2)])
    lo = np.searchsorted(t[i], t - neighbourhood_s - 1e-9)
    hi = np.searchsorted(t[i], t + neighbourhood_s + 1e-9)
    rms = np.sqrt((cz2[hi] - cz2[lo]) / np.maximum(hi - lo, 1))
    rms_factor = np.where(hi > lo, np.maximum(rms, 1.0), 1.0)
    factor = np.ones(n)
    for k in np.flatnonzero(z > bound_sigmas):
        a, b = i[k], j[k]
        factor[a:b + 1] = np.maximum(factor[a:b + 1], z[k] / 2.0)
    widened = factor > 1.0
    spans: list[tuple[float, float]] = []
    span_r, span_z = 0.0, 0.0
    if widened.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], widened.astype(int), [0]])))
        # within a widened span the disagreement accumulates beyond one window (a filter integrates the speed
        # over the whole span): its largest, between the span's two epochs where D = h - int v_up dt is
        # highest and lowest, against its sigma, sets the span's factor too
        D = h - integ
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            p, q = sorted((a + int(np.argmax(D[a:b])), a + int(np.argmin(D[a:b]))))
            if q > p:
                r_pq = abs(float(D[q] - D[p]))
                z_pq = r_pq / float(np.sqrt(sh[p] ** 2 + sh[q] ** 2 + (var_int[q + 1] - var_int[p])))
                factor[a:b] = np.maximum(factor[a:b], z_pq / 2.0)
                span_r, span_z = max(span_r, r_pq), max(span_z, z_pq)
        spans = [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    factor = np.maximum(factor, rms_factor)
    return VerticalCheck(sh * factor, sv * factor, widened, float(np.abs(r).max()), float(z.max()), spans, span_r, span_z, rms_factor)


def _iso(t_ns: int) -> str:
    sec, ns = divmod(int(t_ns), _NS)
    return f"{dt.datetime.fromtimestamp(sec, tz=dt.UTC):%Y-%m-%d %H:%M:%S}.{ns // 1_000_000:03d}"


__all__ = ["ANGLE_UNITS", "HEADINGS", "NavColumns", "NavSolution", "TIME_FORMS", "VEL_FRAMES", "VERTICAL_BOUND_SIGMAS",
           "VERTICAL_NEIGHBOURHOOD_S", "VERTICAL_WINDOW_S", "VerticalCheck", "read_nav_csv", "vertical_consistency"]
