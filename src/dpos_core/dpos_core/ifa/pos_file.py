"""The main POS's navigation as an RTKLIB-style ``.pos`` solution file.

The file is what RTKLIB writes with ``out-solformat=llh``, ``out-degform=deg``, ``out-timesys=gpst``,
``out-timeform`` ``yyyy/mm/dd hh:mm:ss.sss`` and the demo5 velocity columns, so that
:func:`dpos_core.imports.logs.read_pos` (and RTKLIB's own tools: rtkplot, pos2kml) read it back.
One line per navigation row, 23 whitespace-separated columns after the two of the time:

====  ==============  =========================================================================
 col  name            content
====  ==============  =========================================================================
 1-2  GPST            ``yyyy/mm/dd hh:mm:ss.ssssss`` (GPS time, Unix calendar, no leap seconds;
                      microseconds, RTKLIB's ``out-timendec=6``: IMU-rate rows may be < 1 ms apart)
 3    latitude(deg)   geodetic latitude [deg], 9 decimals
 4    longitude(deg)  longitude [deg], 9 decimals
 5    height(m)       ellipsoidal height [m]
 6    Q               1: GNSS-aided (a GNSS update within ``gap_s`` of the row on both sides,
                      forward: on the side before), 5: bridged by the IMU alone across a longer
                      gap (an outage) - RTKLIB's "fix" and "single" codes, reused as flags
 7    ns              GNSS updates used within ``gap_s`` of the row (0 or 1 or 2; RTKLIB: satellites)
 8-10 sdn sde sdu     1-sigma position North, East, Up [m]
 11   sdne            signed square root of the NE position covariance [m] (RTKLIB's convention)
 12   sdeu            ... EU
 13   sdun            ... UN
 14   age(s)          time from the nearest GNSS update used [s] (forward: the last one before)
 15   ratio           0 (no ambiguity ratio: not a GNSS solution)
 16-18 vn ve vu       velocity North, East, Up [m/s]
 19-21 sdvn sdve sdvu 1-sigma velocity [m/s]
 22-24 sdvne sdveu sdvun  signed square roots of the velocity covariances [m/s]
====  ==============  =========================================================================

Attitude is not in the ``.pos`` format: ``dpos-ifa`` writes it (with its sigmas) in the CSV beside.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from dpos_core.units import DEG, FloatArray

#: the header line of the columns (RTKLIB's, GPST, with velocities)
HEADER = ("%  GPST                     latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  "
          "sdeu(m)  sdun(m) age(s)  ratio    vn(m/s)    ve(m/s)    vu(m/s)     sdvn     sdve     sdvu    sdvne    sdveu    sdvun")

#: Q of a row with a GNSS update within ``gap_s`` (before and after) / bridged by the IMU alone
Q_AIDED, Q_BRIDGED = 1, 5


def _signed_root(c: FloatArray) -> FloatArray:
    return np.sign(c) * np.sqrt(np.abs(c))


class GnssSupport(NamedTuple):
    """The columns that say how each row of a solution is supported by GNSS (module docstring), (N,) each:
    ``quality`` (Q: :data:`Q_AIDED` or :data:`Q_BRIDGED`), ``n_used`` (ns), ``age_s`` (age(s) [s], NaN: no update)."""

    quality: NDArray[np.int64]
    n_used: NDArray[np.int64]
    age_s: FloatArray


def gnss_support(t_s: FloatArray, updates_s: FloatArray, gap_s: float, smoothed: bool) -> GnssSupport:
    """Q, ns and age(s) of each row (module docstring).

    Args:
        t_s: (N,) the rows' times [s]; updates_s: (K,) times of the GNSS updates used [s], increasing.
        gap_s: the longest interval to a GNSS update that still counts as aided [s].
        smoothed: the solution uses the updates after the row too (forward: only those at or before it).
    """
    t = np.asarray(t_s, dtype=float)
    u = np.asarray(updates_s, dtype=float)
    if u.size == 0:
        return GnssSupport(np.full(t.size, Q_BRIDGED, dtype=np.int64), np.zeros(t.size, dtype=np.int64), np.full(t.size, np.nan))
    j = np.searchsorted(u, t + 1e-9, side="right") - 1  # the last update at or before
    before = np.where(j >= 0, t - u[np.maximum(j, 0)], np.inf)
    after = np.where(j + 1 < u.size, u[np.minimum(j + 1, u.size - 1)] - t, np.inf)
    ok_b, ok_a = before <= gap_s, after <= gap_s
    if smoothed:
        aided = ok_b & ok_a
        ns = ok_b.astype(np.int64) + ok_a.astype(np.int64)
        age = np.minimum(before, after)
    else:
        aided = ok_b
        ns = ok_b.astype(np.int64)
        age = before
    return GnssSupport(np.where(aided, Q_AIDED, Q_BRIDGED).astype(np.int64), ns, np.where(np.isfinite(age), age, np.nan))


def write_pos(path: str | Path, t_ns: NDArray[np.int64], llh: FloatArray, pos_cov_enu_m2: FloatArray, vel_enu_mps: FloatArray,
              vel_cov_enu: FloatArray, support: GnssSupport, comments: list[str] | None = None) -> None:
    """Write a navigation solution as an RTKLIB ``.pos`` file (module docstring: the columns).

    Args:
        t_ns: (N,) stamps [ns GPST, Unix calendar], strictly increasing (as ``read_pos`` needs), at
            least 1 us apart (written to the microsecond).
        llh: (N, 3) [lat_rad, lon_rad, h_m]; vel_enu_mps: (N, 3) East, North, Up [m/s].
        pos_cov_enu_m2, vel_cov_enu: (N, 3, 3) covariances in ENU [m^2], [m^2/s^2].
        support: the Q, ns and age(s) columns (:func:`gnss_support`).
        comments: lines written after ``%`` at the top (what the solution is).
    """
    t = np.asarray(t_ns, dtype=np.int64)
    n = t.size
    if np.any(np.diff(t) < 1000):
        raise ValueError("write_pos: stamps must be strictly increasing, at least 1 us apart")
    P, V = np.asarray(pos_cov_enu_m2, dtype=float), np.asarray(vel_cov_enu, dtype=float)
    v = np.asarray(vel_enu_mps, dtype=float)
    sec = t // 1_000_000_000
    us = (t - sec * 1_000_000_000 + 500) // 1000  # half up: stamps 1 us apart stay apart
    sec, us = np.where(us == 1_000_000, sec + 1, sec), np.where(us == 1_000_000, 0, us)  # rounded up to the next second
    # RTKLIB's order: N, E, U; the cross terms NE, EU, UN
    sd = np.sqrt(np.stack([P[:, 1, 1], P[:, 0, 0], P[:, 2, 2]], axis=1))
    cr = _signed_root(np.stack([P[:, 1, 0], P[:, 0, 2], P[:, 2, 1]], axis=1))
    sdv = np.sqrt(np.stack([V[:, 1, 1], V[:, 0, 0], V[:, 2, 2]], axis=1))
    crv = _signed_root(np.stack([V[:, 1, 0], V[:, 0, 2], V[:, 2, 1]], axis=1))
    quality, n_used = support.quality, support.n_used
    age = np.nan_to_num(np.asarray(support.age_s, dtype=float), nan=0.0)
    lines = [f"% {c}" for c in (comments or [])] + ["%", HEADER]
    for i in range(n):
        date = time.strftime("%Y/%m/%d %H:%M:%S", time.gmtime(int(sec[i])))
        lines.append(
            f"{date}.{int(us[i]):06d} {llh[i, 0] / DEG:14.9f} {llh[i, 1] / DEG:14.9f} {llh[i, 2]:10.4f} {int(quality[i]):3d} "
            f"{int(n_used[i]):3d} {sd[i, 0]:8.4f} {sd[i, 1]:8.4f} {sd[i, 2]:8.4f} {cr[i, 0]:8.4f} {cr[i, 1]:8.4f} {cr[i, 2]:8.4f} "
            f"{age[i]:6.2f} {0.0:6.1f} {v[i, 1]:10.5f} {v[i, 0]:10.5f} {v[i, 2]:10.5f} {sdv[i, 0]:8.5f} {sdv[i, 1]:8.5f} "
            f"{sdv[i, 2]:8.5f} {crv[i, 0]:8.5f} {crv[i, 1]:8.5f} {crv[i, 2]:8.5f}")
    Path(path).write_text("\n".join(lines) + "\n")


__all__ = ["HEADER", "Q_AIDED", "Q_BRIDGED", "GnssSupport", "gnss_support", "write_pos"]
