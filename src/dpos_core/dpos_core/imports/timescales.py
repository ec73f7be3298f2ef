"""Time scales of imported logs: UTC <-> GPST through a leap-second table, date-time strings.

Every stamp of the import is an integer nanosecond count of GPS time on the Unix calendar (the
convention of :mod:`dpos_core.imports.logs`).  UTC is converted with the GPS - UTC offset valid at
that instant (:data:`LEAP_SECONDS`, IERS Bulletin C: 17 s from 2015-07-01, 18 s from 2017-01-01),
never a constant, so a UTC log from 2016 comes out one second different from one of 2017.
"""

from __future__ import annotations

import calendar
import re
from decimal import Decimal, InvalidOperation

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: the GPS epoch 1980-01-06 00:00:00 on the Unix calendar [s]
GPS_EPOCH_UNIX_S = 315_964_800
WEEK_S = 604_800
_NS = 1_000_000_000

#: (UTC date from which it holds, GPS - UTC [s]) - IERS Bulletin C (leap seconds since the GPS epoch)
LEAP_SECONDS: tuple[tuple[tuple[int, int, int], int], ...] = (
    ((1980, 1, 6), 0), ((1981, 7, 1), 1), ((1982, 7, 1), 2), ((1983, 7, 1), 3), ((1985, 7, 1), 4),
    ((1988, 1, 1), 5), ((1990, 1, 1), 6), ((1991, 1, 1), 7), ((1992, 7, 1), 8), ((1993, 7, 1), 9),
    ((1994, 7, 1), 10), ((1996, 1, 1), 11), ((1997, 7, 1), 12), ((1999, 1, 1), 13), ((2006, 1, 1), 14),
    ((2009, 1, 1), 15), ((2012, 7, 1), 16), ((2015, 7, 1), 17), ((2017, 1, 1), 18),
)
_LEAP_UTC_NS = np.array([calendar.timegm((*d, 0, 0, 0, 0, 0, 0)) * _NS for d, _ in LEAP_SECONDS], dtype=np.int64)
_LEAP_S = np.array([n for _, n in LEAP_SECONDS], dtype=np.int64)

TIME_SCALES = ("gpst", "utc")


def gps_minus_utc_s(utc_ns: ArrayLike) -> NDArray[np.int64]:
    """GPS - UTC [s] (N,) at UTC instants ``utc_ns`` [ns, Unix calendar]; before 1980-01-06: 0."""
    i = np.searchsorted(_LEAP_UTC_NS, np.asarray(utc_ns, dtype=np.int64), side="right") - 1
    return np.where(i >= 0, _LEAP_S[np.clip(i, 0, None)], 0)


def utc_to_gpst_ns(utc_ns: ArrayLike) -> NDArray[np.int64]:
    """UTC [ns, Unix calendar] -> GPST [ns, Unix calendar] (adds the leap seconds of the table)."""
    u = np.asarray(utc_ns, dtype=np.int64)
    return u + gps_minus_utc_s(u) * _NS


def gpst_to_utc_ns(gpst_ns: ArrayLike) -> NDArray[np.int64]:
    """GPST [ns, Unix calendar] -> UTC (inverse of :func:`utc_to_gpst_ns` away from the leap instant)."""
    g = np.asarray(gpst_ns, dtype=np.int64)
    first = g - gps_minus_utc_s(g) * _NS
    return g - gps_minus_utc_s(first) * _NS


def to_gpst_ns(t_ns: ArrayLike, scale: str) -> NDArray[np.int64]:
    """Stamps in ``scale`` (``gpst`` or ``utc``) [ns, Unix calendar] -> GPST."""
    if scale not in TIME_SCALES:
        raise ValueError(f"time scale must be one of {TIME_SCALES}, got {scale!r}")
    t = np.asarray(t_ns, dtype=np.int64)
    return t if scale == "gpst" else utc_to_gpst_ns(t)


def week_sow_ns(week: int, sow_s: str | float) -> int:
    """GPS week and seconds of week -> GPST [ns, Unix calendar]."""
    sow_ns = decimal_ns(str(sow_s))
    if week < 0 or not 0 <= sow_ns < WEEK_S * _NS:
        raise ValueError(f"GPS week {week} / seconds of week {sow_s} out of range")
    return (GPS_EPOCH_UNIX_S + int(week) * WEEK_S) * _NS + sow_ns


def decimal_ns(text: str) -> int:
    """``'1656144000.123456789'`` [s] -> exact ns (no float64 rounding). ValueError when not a finite number."""
    try:
        d = Decimal(text.strip())
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    if not d.is_finite():
        raise ValueError(f"not finite: {text!r}")
    return int((d * _NS).to_integral_value())


_DATETIME = re.compile(r"^\s*(\d{4})[-/](\d{1,2})[-/](\d{1,2})[ T](\d{1,2}):(\d{2}):(\d{2}(?:\.\d*)?)\s*(?:Z|UTC|GPST)?\s*$")


def datetime_ns(text: str) -> int:
    """``YYYY-MM-DD HH:MM:SS[.fff]`` (``/`` or ``-``, ``T`` or a blank, an optional ``Z``) -> ns on
    the Unix calendar, in the scale the string is in.  ValueError for anything else."""
    m = _DATETIME.match(text)
    if not m:
        raise ValueError(f"not a date-time 'YYYY-MM-DD HH:MM:SS[.fff]': {text!r}")
    y, mo, d, hh, mi = (int(m.group(k)) for k in range(1, 6))
    sec_ns = decimal_ns(m.group(6))
    if not (1 <= mo <= 12 and 1 <= d <= 31 and hh < 24 and mi < 60 and sec_ns < 61 * _NS):
        raise ValueError(f"date-time out of range: {text!r}")
    return calendar.timegm((y, mo, d, hh, mi, 0, 0, 0, 0)) * _NS + sec_ns


__all__ = ["GPS_EPOCH_UNIX_S", "LEAP_SECONDS", "TIME_SCALES", "WEEK_S", "datetime_ns", "decimal_ns", "gps_minus_utc_s",
           "gpst_to_utc_ns", "to_gpst_ns", "utc_to_gpst_ns", "week_sow_ns"]
