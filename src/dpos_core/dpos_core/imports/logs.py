"""Real sensor logs -> time-stamped series: IMU CSV (any column layout), RTKLIB time tags, RTKLIB
``.pos`` solutions.

Time.  Every stamp is an integer nanosecond count of GPS time on the Unix calendar
(``time_t`` as RTKLIB's ``gtime_t`` holds GPST, no leap seconds): the ``.pos`` file's GPST
dates, the tag's ``time_t`` and an IMU clock mapped onto them share that scale, so a bag's
stamps of both sensors are directly comparable.  A ``.pos`` file in UTC is shifted to GPST by
the leap seconds of its date (the table of :mod:`dpos_core.imports.timescales`).

Bad lines are never fatal: a cut or malformed line is skipped and counted with its line number
(:attr:`ImuLog.skipped`, :attr:`PosLog.skipped`), so that the caller says what was dropped.
"""

from __future__ import annotations

import bisect
import calendar
import math
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from decimal import ROUND_HALF_EVEN, Decimal
from fractions import Fraction
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.errors import LogFormatError

from ..series import GnssSeries, ImuSeries
from ..units import DEG, G0_MPS2, FloatArray
from .timescales import utc_to_gpst_ns

#: GPS - UTC [s] since 2017-01-01 (the last entry of :data:`dpos_core.imports.timescales.LEAP_SECONDS`)
GPS_UTC_LEAP_S = 18
#: the GPS epoch 1980-01-06 00:00:00 on the Unix calendar [s]
GPS_EPOCH_UNIX_S = 315_964_800
_WEEK_S = 604_800
#: skip reasons quoted in a LogFormatError
_QUOTED_REASONS = 3
_TAG_HEADER = b"TIMETAG"
_TAG_TIME_OFFSET = 64  # uint32 time_t, then float64 fraction [s]
_TAG_RECORDS = 76  # (uint32 tick_ms, uint32 file_pos) records

ACCEL_UNITS = {"g": G0_MPS2, "mps2": 1.0}
GYRO_UNITS = {"deg_s": DEG, "rad_s": 1.0}


def data_fields(path: Path, skip_header: int, width: int, split: Callable[[str], list[str]],
                skipped: list[tuple[int, str]]) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of each data line of a text log: the first ``skip_header`` lines, blank
    lines and ``#`` / ``%`` comments left out; a line of fewer than ``width`` fields (``split`` of
    the stripped line) is appended to ``skipped`` as a cut line."""
    with path.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            if lineno <= skip_header:
                continue
            s = line.strip()
            if not s or s.startswith("#") or s.startswith("%"):
                continue
            parts = split(s)
            if len(parts) < width:
                skipped.append((lineno, f"{len(parts)} field(s), {width} needed (cut line)"))
                continue
            yield lineno, parts


def first_reasons(skipped: list[tuple[int, str]]) -> str:
    """``line 3: <reason>; line 7: <reason>`` of the first skipped lines (for error messages)."""
    return "; ".join(f"line {n}: {why}" for n, why in sorted(skipped)[:_QUOTED_REASONS])


@dataclass(frozen=True)
class ImuColumns:
    """Where the IMU fields are in a CSV line (0-based column indices) and their units.

    Attributes:
        accel: (x, y, z) columns of the specific force.
        gyro: (x, y, z) columns of the angular rate.
        accel_unit: ``g`` (x 9.80665 m/s^2) or ``mps2``.
        gyro_unit: ``deg_s`` or ``rad_s``.
        counter: column of the IMU's own clock (a counter), or None.
        counter_unit_s: seconds per counter unit (1e-3: milliseconds).
        time: column of a time stamp in GPST seconds on the Unix calendar, or None (then the
            counter and a time tag give the time).
        skip_header: leading lines to ignore.
        delimiter: field separator; a blank one (``" "``, ``"\\t"``) = any run of whitespace.
    """

    accel: tuple[int, int, int] = (0, 1, 2)
    gyro: tuple[int, int, int] = (3, 4, 5)
    accel_unit: str = "g"
    gyro_unit: str = "deg_s"
    counter: int | None = 6
    counter_unit_s: float = 1e-3
    time: int | None = None
    skip_header: int = 0
    delimiter: str = ","

    def __post_init__(self) -> None:
        if self.accel_unit not in ACCEL_UNITS:
            raise ValueError(f"accel_unit must be one of {sorted(ACCEL_UNITS)}, got {self.accel_unit!r}")
        if self.gyro_unit not in GYRO_UNITS:
            raise ValueError(f"gyro_unit must be one of {sorted(GYRO_UNITS)}, got {self.gyro_unit!r}")
        if self.counter is None and self.time is None:
            raise ValueError("an IMU log needs a time column or a counter column (with a time tag)")
        if not self.counter_unit_s > 0:
            raise ValueError(f"counter_unit_s must be > 0, got {self.counter_unit_s}")
        cols = [*self.accel, *self.gyro] + [c for c in (self.counter, self.time) if c is not None]
        if len(set(cols)) != len(cols) or min(cols) < 0:
            raise ValueError(f"IMU columns must be distinct and >= 0, got {cols}")

    @property
    def width(self) -> int:
        """Fields a line must have at least."""
        return 1 + max(c for c in (*self.accel, *self.gyro, self.counter, self.time) if c is not None)


@dataclass(frozen=True)
class TimeTag:
    """An RTKLIB time tag (``.tag``): GPST of the first byte and (tick_ms, file_pos) records.

    Attributes:
        start_ns: GPST of tick 0 [ns, Unix calendar].
        tick_ms: (K,) logger ticks [ms since start].
        file_pos: (K,) byte position in the logged file reached at each tick.
    """

    start_ns: int
    tick_ms: NDArray[np.int64]
    file_pos: NDArray[np.int64]

    @property
    def span_s(self) -> float:
        return float(self.tick_ms[-1]) * 1e-3 if self.tick_ms.size else 0.0


@dataclass
class ImuLog:
    """IMU samples read from a log.

    Attributes:
        t_ns: (N,) stamps [ns GPST], strictly increasing.
        omega_radps: (N, 3) angular rate in the IMU's axes.
        f_mps2: (N, 3) specific force in the IMU's axes.
        skipped: (line number (1-based), reason) of every line not used.
        repeated: samples whose six values equal the previous sample's (a logger faster than the
            sensor; kept: the ZOH of the sensor's output).
        clock_scale: GPST seconds per IMU-clock second of the counter mapping (1.0 without tag).
    """

    t_ns: NDArray[np.int64]
    omega_radps: FloatArray
    f_mps2: FloatArray
    skipped: list[tuple[int, str]] = field(default_factory=list)
    repeated: int = 0
    clock_scale: float = 1.0

    def __len__(self) -> int:
        return int(self.t_ns.size)

    def series(self, origin_ns: int) -> ImuSeries:
        """The samples as the core's :class:`~dpos_core.series.ImuSeries`, seconds after ``origin_ns``."""
        return ImuSeries(np.asarray((self.t_ns - origin_ns) * 1e-9, dtype=np.float64), self.omega_radps, self.f_mps2)

    def intervals_s(self) -> FloatArray:
        return np.diff(self.t_ns) * 1e-9


def read_tag(path: str | Path) -> TimeTag:
    """Read an RTKLIB time-tag file (module docstring of the format: 60-byte text header starting
    ``TIMETAG``, at byte 64 uint32 ``time_t`` and float64 fraction, then (uint32, uint32) records)."""
    p = Path(path)
    data = p.read_bytes()
    if not data.startswith(_TAG_HEADER) or len(data) < _TAG_RECORDS:
        raise LogFormatError(f"{p}: not an RTKLIB time tag (no 'TIMETAG' header or shorter than {_TAG_RECORDS} bytes)")
    time_t, frac = struct.unpack_from("<Id", data, _TAG_TIME_OFFSET)
    if not (0.0 <= frac < 1.0):
        raise LogFormatError(f"{p}: time fraction {frac} at byte {_TAG_TIME_OFFSET + 4} is not in [0, 1)")
    body = data[_TAG_RECORDS:]
    usable = len(body) // 8 * 8
    rec = np.frombuffer(body[:usable], dtype="<u4").reshape(-1, 2).astype(np.int64)
    return TimeTag(int(time_t) * 1_000_000_000 + int(round(frac * 1e9)), rec[:, 0].copy(), rec[:, 1].copy())


def increasing_lines(stamps: list[float | int] | NDArray[np.int64]) -> NDArray[np.bool_]:
    """(N,) which of the N ``stamps`` (in file order) form the longest strictly increasing
    subsequence (the earliest such one): every other line is a glitch, a repeat or out of order.
    One stamp far ahead (a line +1 h) drops that line only, where "drop what is not after the last
    kept" would drop every line after it.  O(N) when the stamps already increase, else O(N log N)."""
    n = len(stamps)
    keep = np.zeros(n, dtype=bool)
    if n == 0:
        return keep
    if all(stamps[i] < stamps[i + 1] for i in range(n - 1)):
        keep[:] = True
        return keep
    tails: list[float | int] = []  # the smallest last stamp of an increasing run of each length
    tail_idx: list[int] = []
    parent = [-1] * n
    for i, t in enumerate(stamps):
        k = bisect.bisect_left(tails, t)
        parent[i] = tail_idx[k - 1] if k else -1
        if k == len(tails):
            tails.append(t)
            tail_idx.append(i)
        elif t < tails[k]:  # (a repeat of a run's last stamp keeps the earlier line)
            tails[k] = t
            tail_idx[k] = i
    i = tail_idx[-1]
    while i >= 0:
        keep[i] = True
        i = parent[i]
    return keep


def read_imu_csv(path: str | Path, columns: ImuColumns = ImuColumns(), tag: TimeTag | None = None) -> ImuLog:
    """Read an IMU CSV log.

    Time: the ``time`` column when there is one; else the ``counter`` column mapped linearly
    onto the tag's ``[start, start + last tick]`` (the IMU clock is scaled to the logger's,
    ``ImuLog.clock_scale``), or, without a tag, counter seconds from 0.  The time column is read as
    an exact decimal (float64 seconds of today's dates would be off by up to 120 ns).  Lines with too few fields,
    non-numeric or non-finite values, or a stamp not after the previous one are skipped and listed
    in ``ImuLog.skipped``.  Raises :class:`LogFormatError` when no line is usable.
    """
    p = Path(path)
    c = columns
    rows: list[list[float]] = []  # the six values and the line number
    clock: list[float | int] = []  # counter values (float), or time-column stamps [ns] (int)
    skipped: list[tuple[int, str]] = []
    tcol = c.time if c.time is not None else c.counter
    assert tcol is not None
    split = (lambda s: s.split(c.delimiter)) if c.delimiter.strip() else str.split
    for lineno, parts in data_fields(p, c.skip_header, c.width, split, skipped):
        try:
            vals = [float(parts[k]) for k in (*c.accel, *c.gyro)]
            tick = float(parts[tcol]) if c.time is None else _decimal_ns(parts[tcol])
        except (ValueError, ArithmeticError):
            skipped.append((lineno, "a field is not a number"))
            continue
        if tick is None or not all(math.isfinite(v) for v in (*vals, tick)):
            skipped.append((lineno, "a field is not finite"))
            continue
        rows.append([*vals, float(lineno)])
        clock.append(tick)
    if not rows:
        first = f": {first_reasons(skipped)}" if skipped else ""
        raise LogFormatError(f"{p}: no usable IMU line ({len(skipped)} skipped{first}; expected columns {c})")
    a = np.array(rows)
    # stamps must increase: keep the longest strictly increasing sequence of the lines and drop
    # (and name) the others, so that one glitched stamp (a line +1 h) costs that line only
    keep = increasing_lines(clock)
    unit = "counter" if c.time is None else "time [ns]"
    kept = np.flatnonzero(keep)
    for i in np.flatnonzero(~keep):
        k = int(np.searchsorted(kept, i))  # the kept lines around line i
        prev = clock[kept[k - 1]] if k else None
        nxt = clock[kept[k]] if k < kept.size else None
        why = (f"{unit} {clock[i]!r} not after the previous {prev!r}" if prev is not None and clock[i] <= prev
               else f"{unit} {clock[i]!r} not before the next {nxt!r} (a glitched stamp)")
        skipped.append((int(a[i, 6]), why))
    a = a[keep]
    scale = 1.0
    if c.time is not None:
        t_ns = np.array(clock, dtype=np.int64)[keep]
    else:
        counter = np.array(clock, dtype=np.float64)[keep]
        ticks = (counter - counter[0]) * c.counter_unit_s  # IMU clock seconds since the first sample
        if tag is not None:
            if ticks[-1] <= 0:
                raise LogFormatError(f"{p}: a single counter value cannot be mapped onto the tag")
            scale = tag.span_s / float(ticks[-1])
            if not 0.99 < scale < 1.01:
                raise LogFormatError(f"{p}: the IMU counter spans {ticks[-1]:.3f} s but the tag {tag.span_s:.3f} s "
                                     "(more than 1 % apart): wrong counter unit or wrong tag")
            t_ns = tag.start_ns + np.round(ticks * scale * 1e9).astype(np.int64)
        else:
            t_ns = np.round(ticks * 1e9).astype(np.int64)
    f = a[:, 0:3] * ACCEL_UNITS[c.accel_unit]
    om = a[:, 3:6] * GYRO_UNITS[c.gyro_unit]
    repeated = int(np.all(np.diff(a[:, :6], axis=0) == 0.0, axis=1).sum())
    skipped.sort()
    return ImuLog(t_ns, om, f, skipped, repeated, scale)


@dataclass
class PosLog:
    """An RTKLIB position solution.

    Attributes:
        t_ns: (M,) GPST [ns, Unix calendar].
        llh: (M, 3) [lat_rad, lon_rad, h_m] (ellipsoidal height).
        quality: (M,) RTKLIB Q (1 fix, 2 float, 3 SBAS, 4 DGPS, 5 single, 6 PPP).
        n_sat: (M,) satellites.
        pos_cov_enu_m2: (M, 3, 3) position covariance, East, North, Up [m^2].
        vel_n_mps: (M, 3) ENU velocity, NaN when the file has none.
        vel_cov_enu: (M, 3, 3) velocity covariance [m^2/s^2] (NaN when none).
        skipped: (line number, reason) of the lines not used.
        reordered: lines whose stamp was before the previous line's (the solution is sorted by stamp).
    """

    t_ns: NDArray[np.int64]
    llh: FloatArray
    quality: NDArray[np.int64]
    n_sat: NDArray[np.int64]
    pos_cov_enu_m2: FloatArray
    vel_n_mps: FloatArray
    vel_cov_enu: FloatArray
    skipped: list[tuple[int, str]] = field(default_factory=list)
    reordered: int = 0

    def __len__(self) -> int:
        return int(self.t_ns.size)

    def series(self, origin_ns: int, keep: NDArray[np.bool_] | None = None) -> GnssSeries:
        """The (``keep``-selected) epochs as the core's :class:`~dpos_core.series.GnssSeries`, seconds
        after ``origin_ns``, 1-sigma from the diagonals of the ENU covariances."""
        k = np.ones(self.t_ns.shape, dtype=bool) if keep is None else keep
        return GnssSeries(np.asarray((self.t_ns[k] - origin_ns) * 1e-9, dtype=np.float64), self.llh[k],
                          np.sqrt(np.diagonal(self.pos_cov_enu_m2[k], axis1=1, axis2=2)), self.vel_n_mps[k],
                          np.sqrt(np.diagonal(self.vel_cov_enu[k], axis1=1, axis2=2)))

    @property
    def has_velocity(self) -> bool:
        return bool(np.all(np.isfinite(self.vel_n_mps)))

    def select(self, keep: NDArray[np.bool_]) -> PosLog:
        return PosLog(self.t_ns[keep], self.llh[keep], self.quality[keep], self.n_sat[keep], self.pos_cov_enu_m2[keep],
                      self.vel_n_mps[keep], self.vel_cov_enu[keep], list(self.skipped), self.reordered)


def _decimal_ns(text: str) -> int | None:
    """Seconds written in decimal -> integer ns, exactly; None for NaN / infinity (``Decimal``:
    raises ``decimal.InvalidOperation``, an ArithmeticError, for what is not a number)."""
    d = Decimal(text.strip())
    if not d.is_finite():
        return None
    t_ns = int((d * 1_000_000_000).to_integral_value(rounding=ROUND_HALF_EVEN))
    if not 0 <= t_ns < 2**63:
        raise ValueError(f"time {text!r} s is out of range")
    return t_ns


def _cov_enu(sn: float, se: float, su: float, sne: float, seu: float, sun: float) -> FloatArray:
    """RTKLIB's signed square roots of the covariances (``sdne = sign(c) sqrt(|c|)``) -> ENU (3, 3)."""
    def c(s: float) -> float:
        return math.copysign(s * s, s)

    return np.array([[se * se, c(sne), c(seu)], [c(sne), sn * sn, c(sun)], [c(seu), c(sun), su * su]])


def _parse_time(date: str, clock: str) -> int:
    """``yyyy/mm/dd hh:mm:ss.sss`` or ``week tow`` (RTKLIB out-timeform=tow) -> ns on the Unix calendar."""
    if "/" not in date and ":" not in clock:
        week, tow_s = int(date), float(clock)
        if week < 0 or not 0.0 <= tow_s < _WEEK_S:
            raise ValueError(f"GPS week {week} / time of week {tow_s} out of range")
        return (GPS_EPOCH_UNIX_S + week * _WEEK_S) * 1_000_000_000 + int(round(tow_s * 1e9))
    y, mo, d = (int(x) for x in date.split("/"))
    hh, mm, ss = clock.split(":")
    sec = float(ss)
    whole = int(math.floor(sec))
    base = calendar.timegm((y, mo, d, int(hh), int(mm), whole, 0, 0, 0))
    return base * 1_000_000_000 + int(round((sec - whole) * 1e9))


def read_pos(path: str | Path) -> PosLog:
    """Read an RTKLIB ``.pos`` solution in the ``yyyy/mm/dd hh:mm:ss.sss`` (or ``week tow``) time
    format with latitude / longitude in degrees (RTKLIB ``out-solformat=llh``, ``out-degform=deg``);
    with or without the velocity columns (RTKLIB demo5 writes them).  GPST or UTC time (from the
    header), UTC shifted by the leap seconds of its date.  Lines with a latitude outside [-90, 90] or a
    longitude outside [-180, 180] deg are skipped (an ECEF solution written without its header).

    Raises :class:`LogFormatError` for another solution format (ECEF, ENU baseline, NMEA, dms) or
    no usable line.
    """
    p = Path(path)
    utc = False
    header_seen = False
    rows: list[tuple[int, int, list[float]]] = []  # (line number, t_ns, values)
    skipped: list[tuple[int, str]] = []
    with p.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s:
                continue
            if s.startswith("%"):
                low = s.lower()
                if "latitude" in low or "x-ecef" in low or "e-baseline" in low:
                    header_seen = True
                    if "x-ecef" in low or "e-baseline" in low:
                        raise LogFormatError(f"{p}: ECEF / baseline solutions are not supported; write the solution as "
                                             "latitude / longitude / height in degrees (RTKLIB out-solformat=llh, out-degform=deg)")
                    if "(deg)" not in low:
                        raise LogFormatError(f"{p}: latitude / longitude must be in degrees (RTKLIB out-degform=deg)")
                    utc = "utc" in low.split()[1].lower() if len(low.split()) > 1 else False
                continue
            parts = s.split()
            if len(parts) < 15:
                skipped.append((lineno, f"{len(parts)} field(s), 15 needed (cut line)"))
                continue
            try:
                t_ns = _parse_time(parts[0], parts[1])
                vals = [float(x) for x in parts[2:]]
            except ValueError:
                skipped.append((lineno, "a field is not a number or the time is not yyyy/mm/dd hh:mm:ss.sss"))
                continue
            if not all(math.isfinite(v) for v in vals[:13]):
                skipped.append((lineno, "a field is not finite"))
                continue
            if not (-90.0 <= vals[0] <= 90.0 and -180.0 <= vals[1] <= 180.0):
                skipped.append((lineno, f"latitude {vals[0]:g} / longitude {vals[1]:g} deg out of range (not an llh solution in degrees?)"))
                continue
            if not (vals[3] == int(vals[3]) and 1 <= vals[3] <= 6):
                skipped.append((lineno, f"Q {vals[3]:g} is not an RTKLIB quality 1-6 (a dms solution without its header?)"))
                continue
            if not all(v > 0.0 for v in vals[5:8]):
                skipped.append((lineno, f"sigma sdn/sde/sdu {vals[5]:g}/{vals[6]:g}/{vals[7]:g} m not > 0 (an exact fix claimed)"))
                continue
            rows.append((lineno, t_ns, vals))
    if not header_seen and len(rows) >= 3 and all(v[0] == int(v[0]) and v[1] == int(v[1]) for _, _, v in rows):
        raise LogFormatError(f"{p}: every latitude and longitude is a whole number of degrees: looks like a dms solution "
                             "(deg min sec) without its header read as degrees (write RTKLIB out-degform=deg, keep the header)")
    if not header_seen and not rows:
        first = f"; {len(skipped)} skipped: {first_reasons(skipped)}" if skipped else ""
        raise LogFormatError(f"{p}: not an RTKLIB .pos solution (no header, no usable solution line{first})")
    if not rows:
        first = f": {first_reasons(skipped)}" if skipped else ""
        raise LogFormatError(f"{p}: no usable solution line ({len(skipped)} skipped{first})")
    # lines out of stamp order are sorted (counted in PosLog.reordered); a repeated stamp is named, not used
    reordered = sum(1 for k in range(1, len(rows)) if rows[k][1] < rows[k - 1][1])
    out_t: list[int] = []
    out_v: list[list[float]] = []
    for lineno, t_ns, vals in sorted(rows, key=lambda r: (r[1], r[0])):
        if out_t and t_ns <= out_t[-1]:
            skipped.append((lineno, f"stamp {t_ns} ns not after the previous {out_t[-1]} ns (a repeated stamp)"))
            continue
        out_t.append(t_ns)
        out_v.append(vals)
    t = np.array(out_t, dtype=np.int64)
    if utc:
        t = utc_to_gpst_ns(t)  # the leap seconds of the date (dpos_core.imports.timescales' table)
    m = len(out_v)
    llh = np.array([[v[0] * DEG, v[1] * DEG, v[2]] for v in out_v])
    q = np.array([int(v[3]) for v in out_v], dtype=np.int64)
    ns = np.array([int(v[4]) for v in out_v], dtype=np.int64)
    pc = np.array([_cov_enu(*v[5:11]) for v in out_v])
    vel = np.full((m, 3), np.nan)
    vc = np.full((m, 3, 3), np.nan)
    for i, v in enumerate(out_v):
        if len(v) >= 22 and all(math.isfinite(x) for x in v[13:22]):
            vn, ve, vu = v[13:16]
            vel[i] = (ve, vn, vu)
            vc[i] = _cov_enu(*v[16:22])
    skipped.sort()
    return PosLog(t, llh, q, ns, pc, vel, vc, skipped, reordered)


def outage_mask(t_ns: NDArray[np.int64], outages_s: list[tuple[float, float]], origin_ns: int) -> NDArray[np.bool_]:
    """True for the epochs to keep: outside every ``[start, end)`` (seconds after ``origin_ns``)."""
    rel = (t_ns - origin_ns) * 1e-9
    keep = np.ones(t_ns.shape, dtype=bool)
    for a, b in outages_s:
        if not b > a:
            raise ValueError(f"outage [{a}, {b}) must end after it starts")
        keep &= ~((rel >= a) & (rel < b))
    return keep


def grid_offset_ns(t_ns: NDArray[np.int64], rate_hz: float) -> NDArray[np.int64]:
    """Signed distance [ns] of each stamp from the nearest epoch of the ``rate_hz`` grid of GPS time
    (grid origin: the GPS epoch; e.g. -1_000_000 for 12:00:00.999 at 1 Hz).

    ``rate_hz`` must be a ratio of integers up to 1000 (1, 4, 0.2, 2/3 ...).  Integer arithmetic
    (float64 stamps of today's dates are only good to 256 ns): with ``rate = p / q`` the grid repeats
    every ``q`` seconds, and the phase is counted in units of 1/p ns."""
    if not rate_hz > 0:
        raise ValueError(f"rate must be > 0, got {rate_hz}")
    frac = Fraction(rate_hz).limit_denominator(1000)
    if frac.numerator > 1000 or abs(float(frac) - rate_hz) > 1e-9 * rate_hz:
        raise ValueError(f"rate {rate_hz} Hz is not a ratio of integers up to 1000")
    p_, q_ = frac.numerator, frac.denominator
    rel = np.asarray(t_ns, dtype=np.int64) - GPS_EPOCH_UNIX_S * 1_000_000_000
    sec = np.floor_divide(rel, 1_000_000_000)
    sub_ns = rel - sec * 1_000_000_000
    period = 1_000_000_000 * q_  # the grid period in units of 1/p ns
    phase = np.mod((np.mod(sec, q_) * 1_000_000_000 + sub_ns) * p_, period)
    signed = np.where(phase > period // 2, phase - period, phase)
    return np.round(signed / p_).astype(np.int64)


def decimate_mask(t_ns: NDArray[np.int64], rate_hz: float, tol_s: float = 1e-3) -> NDArray[np.bool_]:
    """True for the epochs on the ``rate_hz`` grid of GPS time (e.g. the whole seconds for 1 Hz)
    within ``tol_s`` (inclusive; see :func:`grid_offset_ns`)."""
    return np.abs(grid_offset_ns(t_ns, rate_hz)) <= int(round(tol_s * 1e9))


__all__ = ["ImuColumns", "ImuLog", "TimeTag", "PosLog", "LogFormatError", "read_tag", "read_imu_csv", "read_pos",
           "outage_mask", "decimate_mask", "grid_offset_ns", "GPS_UTC_LEAP_S", "GPS_EPOCH_UNIX_S"]
