"""Plausibility of units and installation: the gross mistakes a reader cannot see in a file's format.

An IMU log in m/s^2 read as g has the right columns and finite numbers; only its values give it
away.  Each check here takes arrays (or numbers) and returns a :class:`Finding` (the input, the
statistic that was measured and the likely mistake) or ``None``.  The checks are one-sided and
loose: they flag what no vehicle can do (a factor 9.81 or 57.3 off, a lever arm longer than the
aircraft), never a merely unusual flight.  The entry points (dpos-import, read_session, the
aircraft-file loader) refuse an input with a finding in one line.  Pure numpy; no ROS.

Checks:
- :func:`check_specific_force`: median |f| over the quietest seconds against g (0.3 g .. 3 g
  accepted): 9.81 g is m/s^2 read as g, 0.102 g is g read as m/s^2.
- :func:`check_angular_rate`: |omega| that no vehicle has (the 99th percentile above
  1000 deg/s, or 20 deg/s median in the quietest seconds): deg/s read as rad/s.  Rates too
  small (rad/s read as deg/s) by the tilt of the specific force between quiet seconds, which the
  gyros must account for (a vector turned by theta in the body needs int |omega| dt >= theta).
- :func:`check_lever_arm`: a lever arm within a size bound (:func:`size_bound_m`).
- :func:`check_datum`: a datum within 200 km of the first fix.
- :func:`check_sigma`: a standard deviation > 0 and finite.
- :func:`check_time_offset`: an offset within a bound (60 s by default).
- :func:`check_imu_with_track`: an IMU record's units, and its rates against the GNSS course.
- :func:`check_fix_sigmas`: GNSS fixes with a position sigma > 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .units import DEG, G0_MPS2

#: the quietest seconds' median |f| / g accepted (a steady turn at 60 deg bank is 2 g)
F_RATIO_RANGE = (0.3, 3.0)
#: 99th percentile of |omega| no vehicle reaches [rad/s] (MEMS gyros saturate at 2000 deg/s)
OMEGA_P99_MAX_RADPS = 1000.0 * DEG
#: median |omega| over the quietest seconds no steady vehicle has [rad/s]
OMEGA_QUIET_MAX_RADPS = 20.0 * DEG
#: a tilt of the specific force between quiet seconds that the gyros must account for [rad]
TILT_MIN_RAD = 10.0 * DEG
#: the tilt / int|omega|dt ratio above which the gyros are too small (rad/s read as deg/s: 57.3)
TILT_RATIO_MAX = 5.0
#: a datum farther than this from the first fix is the wrong datum [m]
DATUM_MAX_DISTANCE_M = 200_000.0
#: a time offset beyond this is a unit or a typing mistake [s]
TIME_OFFSET_MAX_S = 60.0
#: a lever arm may exceed the aircraft's span by this much (the fuselage, the tail) [m]
FUSELAGE_MARGIN_M = 30.0
#: the size bound of a vehicle without a wing in its file [m] (the largest aircraft: 84 m long)
DEFAULT_SIZE_M = 60.0
#: the largest semi-span an aircraft has [m] (Stratolaunch: 58.5 m)
MAX_SEMI_SPAN_M = 100.0
#: the quietest seconds used (a fraction of the 1 s windows, at least one)
QUIET_FRACTION = 0.1
_MAX_QUIET = 400
_EARTH_R_M = 6_371_000.0


@dataclass(frozen=True)
class Finding:
    """A gross mistake in one input.

    Attributes:
        input: the input, as the user named it (``--imu imu.csv``, ``sub-IMU sub_l``).
        statistic: what was measured (``median |f| over the 10 quietest seconds 96.2 m/s^2``).
        mistake: the likely mistake (``looks like m/s^2 read as g``).
    """

    input: str
    statistic: str
    mistake: str

    def __str__(self) -> str:
        return f"{self.input}: {self.statistic}: {self.mistake}"


def _windows(t_s: NDArray[np.float64], window_s: float) -> NDArray[np.int64]:
    """(W+1,) sample indices that split ``t_s`` (N,) into windows of ``window_s`` seconds."""
    k = np.floor((t_s - t_s[0]) / window_s).astype(np.int64)
    return np.concatenate(([0], np.flatnonzero(np.diff(k)) + 1, [t_s.size]))


def quiet_windows(t_s: NDArray[np.float64], f_mps2: NDArray[np.float64], window_s: float = 1.0) -> list[tuple[int, int]]:
    """The quietest 1 s windows of an IMU record, quietest first: (start, stop) sample index
    pairs of the windows of at least 5 samples with the smallest std of |f| (a fraction
    :data:`QUIET_FRACTION`, at least one, at most 400).  ``t_s`` (N,) [s], ``f_mps2`` (N, 3)."""
    if t_s.size < 5:
        return [(0, int(t_s.size))]
    edges = _windows(t_s, window_s)
    nf = np.linalg.norm(f_mps2, axis=1)
    spans = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b - a >= 5]
    if not spans:
        return [(0, int(t_s.size))]
    score = np.array([float(np.std(nf[a:b])) for a, b in spans])
    n = min(_MAX_QUIET, max(1, int(round(QUIET_FRACTION * len(spans)))))
    order = np.argsort(score, kind="stable")[:n]
    return [spans[i] for i in order]


def check_specific_force(what: str, t_s: NDArray[np.float64], f_mps2: NDArray[np.float64]) -> Finding | None:
    """Median |f| over the quietest seconds against g: near g at rest or in steady flight.

    ``t_s`` (N,) [s], ``f_mps2`` (N, 3) [m/s^2] as read (after the unit the user gave)."""
    if f_mps2.shape[0] == 0:
        return None
    quiet = quiet_windows(t_s, f_mps2)
    nf = np.linalg.norm(f_mps2, axis=1)
    med = float(np.median(np.concatenate([nf[a:b] for a, b in quiet])))
    r = med / G0_MPS2
    if F_RATIO_RANGE[0] <= r <= F_RATIO_RANGE[1]:
        return None
    stat = f"median |f| over the {len(quiet)} quietest second(s) is {med:.4g} m/s^2 ({r:.3g} g), not near g"
    if abs(math.log(max(r, 1e-300) / G0_MPS2)) < math.log(1.5):
        why = "looks like m/s^2 read as g (x 9.81)"
    elif abs(math.log(max(r, 1e-300) * G0_MPS2)) < math.log(1.5):
        why = "looks like g read as m/s^2 (/ 9.81)"
    elif med == 0.0:
        why = "the accelerometer columns are all zero: wrong columns?"
    else:
        why = "wrong accelerometer unit, scale or columns"
    return Finding(what, stat, why)


def check_angular_rate(what: str, t_s: NDArray[np.float64], omega_radps: NDArray[np.float64],
                       f_mps2: NDArray[np.float64]) -> Finding | None:
    """Angular rates a vehicle can have, and enough of them to account for the vehicle's tilts.

    ``t_s`` (N,) [s], ``omega_radps`` (N, 3) [rad/s] and ``f_mps2`` (N, 3) [m/s^2] as read."""
    n = omega_radps.shape[0]
    if n < 2:
        return None
    w = np.linalg.norm(omega_radps, axis=1)
    p99 = float(np.percentile(w, 99.0))
    deg_as_rad = "looks like deg/s read as rad/s (x 57.3)"
    if p99 > OMEGA_P99_MAX_RADPS:
        return Finding(what, f"99th percentile of |omega| is {p99 / DEG:.4g} deg/s, faster than a vehicle turns", deg_as_rad)
    quiet = quiet_windows(t_s, f_mps2)
    wq = float(np.median(np.concatenate([w[a:b] for a, b in quiet])))
    if wq > OMEGA_QUIET_MAX_RADPS:
        return Finding(what, f"median |omega| over the {len(quiet)} quietest second(s) is {wq / DEG:.4g} deg/s, "
                       "not a vehicle at rest or in steady motion", deg_as_rad)
    # the specific force at rest is gravity: a tilt between two quiet seconds is a rotation the
    # gyros measured; int |omega| dt >= the angle the vector turned (|d v/dt| = |omega x v| <= |omega|)
    if len(quiet) < 2:
        return None
    dt = np.diff(t_s, prepend=t_s[0])
    gap = dt > max(0.1, 5.0 * float(np.median(dt[1:])))  # what happened in a gap is not measured
    cum = np.cumsum(np.where(gap, 0.0, w * dt))  # int |omega| dt [rad]
    segment = np.cumsum(gap)
    mids = np.array([(a + b - 1) // 2 for a, b in quiet])
    u = np.array([np.mean(f_mps2[a:b], axis=0) for a, b in quiet])
    nu = np.linalg.norm(u, axis=1, keepdims=True)
    if np.any(nu == 0.0):
        return None
    u = u / nu
    tilt = np.arccos(np.clip(u @ u.T, -1.0, 1.0))  # (K, K) [rad]
    turned = np.abs(cum[mids][:, None] - cum[mids][None, :])
    same = segment[mids][:, None] == segment[mids][None, :]
    bad = same & (tilt > TILT_MIN_RAD) & (tilt > TILT_RATIO_MAX * turned)
    if not np.any(bad):
        return None
    i, j = np.unravel_index(int(np.argmax(np.where(bad, tilt, -1.0))), tilt.shape)
    return Finding(what, f"the specific force at rest turned by {tilt[i, j] / DEG:.3g} deg between t = {t_s[mids[i]] - t_s[0]:.1f} s "
                   f"and {t_s[mids[j]] - t_s[0]:.1f} s but the gyros integrate to {turned[i, j] / DEG:.3g} deg",
                   "looks like rad/s read as deg/s (/ 57.3)")


def check_imu(what: str, t_s: NDArray[np.float64], omega_radps: NDArray[np.float64], f_mps2: NDArray[np.float64]) -> list[Finding]:
    """Both IMU checks (:func:`check_specific_force`, :func:`check_angular_rate`); NaN rows left out.
    ``t_s`` (N,) [s], ``omega_radps`` (N, 3) [rad/s], ``f_mps2`` (N, 3) [m/s^2]."""
    ok = np.isfinite(t_s) & np.all(np.isfinite(omega_radps), axis=1) & np.all(np.isfinite(f_mps2), axis=1)
    t, om, f = t_s[ok], omega_radps[ok], f_mps2[ok]
    out = [check_specific_force(what, t, f), check_angular_rate(what, t, om, f)]
    return [x for x in out if x is not None]


def size_bound_m(spans_m: list[float], semi_span_m: float | None = None) -> float:
    """The longest lever arm an aircraft can have [m]: its largest span position (or its wing's
    semi-span) plus :data:`FUSELAGE_MARGIN_M`, at least :data:`DEFAULT_SIZE_M`."""
    largest = max([abs(s) for s in spans_m] + [semi_span_m or 0.0, 0.0])
    return max(DEFAULT_SIZE_M, largest + FUSELAGE_MARGIN_M)


def check_lever_arm(what: str, arm_m: tuple[float, float, float] | NDArray[np.float64], bound_m: float) -> Finding | None:
    """A lever arm (3,) [m] no longer than ``bound_m`` (:func:`size_bound_m`)."""
    n = float(np.linalg.norm(np.asarray(arm_m, dtype=np.float64)))
    if not math.isfinite(n) or n <= bound_m:
        return None
    why = ("longer than the aircraft: looks like millimetres given as metres (/ 1000)" if n / 1000.0 <= bound_m
           else "longer than the aircraft: a typing or unit mistake")
    return Finding(what, f"length {n:.6g} m exceeds the aircraft's size bound {bound_m:.3g} m", why)


def check_datum(what: str, datum_lat_rad: float, datum_lon_rad: float, fix_lat_rad: float, fix_lon_rad: float,
                max_m: float = DATUM_MAX_DISTANCE_M) -> Finding | None:
    """A datum (the local frame's origin) within ``max_m`` of the first fix (great-circle distance)."""
    c = (math.sin(datum_lat_rad) * math.sin(fix_lat_rad)
         + math.cos(datum_lat_rad) * math.cos(fix_lat_rad) * math.cos(datum_lon_rad - fix_lon_rad))
    d = _EARTH_R_M * math.acos(max(-1.0, min(1.0, c)))
    if d <= max_m:
        return None
    return Finding(what, f"{d / 1000.0:.4g} km from the first fix (lat {fix_lat_rad / DEG:.6f}, lon {fix_lon_rad / DEG:.6f} deg)",
                   "the datum of another place, or latitude / longitude swapped or in radians")


def check_sigma(what: str, sigma: float) -> Finding | None:
    """A standard deviation finite and > 0 (zero claims a perfect value; the filter then never corrects it)."""
    if isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma > 0.0:
        return None
    return Finding(what, f"sigma is {sigma!r}", "a sigma must be > 0 and finite (0 claims an exact value)")


def check_time_offset(what: str, offset_s: float, max_s: float = TIME_OFFSET_MAX_S) -> Finding | None:
    """A time offset finite and within ``max_s`` seconds."""
    if isinstance(offset_s, (int, float)) and math.isfinite(offset_s) and abs(offset_s) <= max_s:
        return None
    return Finding(what, f"{offset_s!r} s is beyond +-{max_s:g} s",
                   "a unit mistake (ms as s?) or a clock of another day: give the offset in seconds")


def check_overlap(what: str, a_s: tuple[float, float], b_s: tuple[float, float], max_gap_s: float = 3600.0) -> Finding | None:
    """Two records of one flight (``a_s``, ``b_s``: first and last stamp [s] on one time scale)
    overlap, or are at most ``max_gap_s`` apart."""
    gap = max(a_s[0], b_s[0]) - min(a_s[1], b_s[1])
    if math.isfinite(gap) and gap <= max_gap_s:
        return None
    day = " (whole days: a time tag or a date of another day)" if abs(abs(b_s[0] - a_s[0]) / 86400.0 - round(abs(b_s[0] - a_s[0]) / 86400.0)) < 0.05 \
        and abs(b_s[0] - a_s[0]) > 43200.0 else ""
    return Finding(what, f"the records do not overlap: {gap / 3600.0:.4g} h apart{day}",
                   "a time tag, a date or a time scale of another recording")


#: the reference's 90th percentile turn rate that shows the vehicle turned [rad/s]
TURNING_MIN_RADPS = 3.0 * DEG
#: gyro / reference turn-rate ratios (90th percentiles) outside which the gyro unit is wrong
RATE_RATIO_RANGE = (1.0 / 8.0, 20.0)


def course_rate_radps(t_s: NDArray[np.float64], llh: NDArray[np.float64], step_s: float = 1.0,
                      min_speed_mps: float = 1.0) -> NDArray[np.float64]:
    """|d course / dt| [rad/s] of a track: positions ``llh`` (N, 3) [rad, rad, m] at ``t_s`` (N,)
    [s] on a ``step_s`` grid, velocity by differences, the course change between two steps where
    the speed is at least ``min_speed_mps`` at both; (M,) rates, empty for a short track."""
    if t_s.size < 3 or t_s[-1] - t_s[0] < 3.0 * step_s:
        return np.zeros(0)
    g = np.arange(t_s[0], t_s[-1], step_s)
    north = (np.interp(g, t_s, llh[:, 0]) - llh[0, 0]) * _EARTH_R_M
    east = (np.interp(g, t_s, llh[:, 1]) - llh[0, 1]) * _EARTH_R_M * math.cos(float(llh[0, 0]))
    ve, vn = np.diff(east) / step_s, np.diff(north) / step_s
    course = np.arctan2(ve, vn)
    fast = np.hypot(ve, vn) >= min_speed_mps
    d = np.angle(np.exp(1j * np.diff(course)))
    return np.asarray(np.abs(d[fast[1:] & fast[:-1]]) / step_s, dtype=np.float64)


def check_rate_scale(what: str, omega_radps: NDArray[np.float64], ref_rate_radps: NDArray[np.float64], ref: str,
                     min_turn_radps: float = TURNING_MIN_RADPS) -> Finding | None:
    """The gyro's |omega| (N, 3) [rad/s] against the turn rates of another record of the same
    vehicle over the same span (``ref_rate_radps`` (M,) [rad/s]: the GNSS course rate, the main
    system's body rates): the 90th percentiles 57.3 apart flag deg/s and rad/s swapped.  Needs the
    vehicle to have turned (the reference's 90th percentile >= ``min_turn_radps``, 3 deg/s for the
    noisy GNSS course); else no finding."""
    w = np.linalg.norm(omega_radps[np.all(np.isfinite(omega_radps), axis=1)], axis=1)
    r = ref_rate_radps[np.isfinite(ref_rate_radps)]
    if w.size < 10 or r.size < 10:
        return None
    pr, pw = float(np.percentile(r, 90.0)), float(np.percentile(w, 90.0))
    if pr < min_turn_radps:
        return None
    ratio = pw / pr
    if RATE_RATIO_RANGE[0] <= ratio <= RATE_RATIO_RANGE[1]:
        return None
    stat = f"90th percentile of |omega| is {pw / DEG:.4g} deg/s against {pr / DEG:.4g} deg/s of {ref} (ratio {ratio:.3g})"
    why = "looks like rad/s read as deg/s (/ 57.3)" if ratio < 1.0 else "looks like deg/s read as rad/s (x 57.3)"
    return Finding(what, stat, why)


def check_imu_with_track(what: str, t_s: NDArray[np.float64], omega_radps: NDArray[np.float64], f_mps2: NDArray[np.float64],
                         track_t_s: NDArray[np.float64], track_llh: NDArray[np.float64], track: str) -> list[Finding]:
    """An IMU record against its own values (:func:`check_imu`) and, when those pass, its rates against
    the course of the vehicle's GNSS track over the IMU's span (:func:`check_rate_scale`): what an IMU
    with fixes (dpos-ifa's ``/imu/data`` and ``/fix``) can show.  ``t_s`` (N,) and ``track_t_s`` (M,)
    on one time scale [s]; ``omega_radps``, ``f_mps2`` (N, 3); ``track_llh`` (M, 3) [rad, rad, m];
    ``track``: the fixes as the user names them."""
    found = check_imu(what, t_s, omega_radps, f_mps2)
    if found or t_s.size < 2:
        return found
    inside = (track_t_s >= t_s[0]) & (track_t_s <= t_s[-1])
    course = course_rate_radps(np.asarray(track_t_s[inside], dtype=np.float64), np.asarray(track_llh[inside], dtype=np.float64))
    scale = check_rate_scale(what, omega_radps, course, f"the course of {track}")
    return [scale] if scale is not None else []


def check_fix_sigmas(what: str, pos_sigma_m: NDArray[np.float64]) -> Finding | None:
    """GNSS fixes' position 1-sigma (M, 3) [m]: a finding when no fix has all three finite and > 0
    (a driver that leaves its covariance at zero claims exact fixes; the filter rejects each)."""
    s = np.asarray(pos_sigma_m, dtype=np.float64).reshape(-1, 3)
    if s.shape[0] == 0 or np.any(np.all(np.isfinite(s) & (s > 0.0), axis=1)):
        return None
    return Finding(what, f"every one of the {s.shape[0]} fixes has a zero (or invalid) position sigma",
                   "a sigma must be > 0 (0 claims an exact fix): the driver's position_covariance is not filled")

