"""Gates on the contract topics: what a node is told, checked against what it knows.

Every check here is pure (no ROS, no clock of its own): a node hands it the message's values and
its own state and gets ``None`` (pass) or a :class:`Refusal` (a short ``reason`` code for the
status counters and a sentence for people). :class:`GateCounts` keeps the counts a node publishes
in its status (``gate_refused``, ``gate/<reason>``, ``last_gate``) and decides when a refusal is
logged: the first of each reason at once, later ones at most every ``interval_s`` (with the
number refused meanwhile).

The checks (docs/design.md, "Gates"):

:func:`check_stamp`
    a feedback stamp must not be in the future of what the node has (its newest IMU stamp + a
    tolerance) nor before the last one it accepted.
:func:`check_correction`
    an ``/ifa/correction`` against the node's own state at its stamp: the difference ``d`` (9,)
    [position ENU m, velocity ENU m/s, attitude error rad] must pass the chi-square test
    ``d^T (P_own + P_corr + diag(floor^2))^-1 d <= chi2_9(1 - p_false)`` (the innovation of a
    consistent filter has a covariance below ``P_prior``, which the sum bounds with the floor
    covering the process noise between two epochs); the correction's covariance must be
    finite, symmetric and positive semi-definite.
:func:`check_bias`
    an ``/ifa/imu_bias`` estimate must be finite and within ``MAX_GYRO_BIAS_DEG_S`` /
    ``MAX_ACCEL_BIAS_MPS2`` (far above any IMU a POS carries: only gross values are refused).
:func:`check_aligned`
    a status that claims ALIGNED must carry a heading sigma at most ``max_heading_sigma_deg``.
:func:`check_datum`
    a datum may not change within a session: a new one more than ``tol_m`` from the first is refused.
:class:`PublisherWatch`
    topics that should have one publisher: a second endpoint (a different GID) is reported once,
    with the nodes (a second graph on the domain, a stray process).
:class:`InterleaveWatch`
    a stream whose stamps keep going back (two sources interleaving on one topic: a second graph
    on the domain) is reported, once per episode.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from dpos_core import earth
from dpos_core.attitude import attitude_error, quat_to_dcm
from dpos_core.chi2 import chi2_quantile
from dpos_core.units import DEG, FloatArray

__all__ = ["Refusal", "GateCounts", "PublisherWatch", "InterleaveWatch", "check_stamp", "check_correction", "correction_difference",
           "check_aligned", "check_datum", "CORRECTION_FLOOR_SIGMA", "CORRECTION_P_FALSE", "FUTURE_TOL_S",
           "MAX_ALIGNED_HEADING_SIGMA_DEG", "check_bias", "MAX_GYRO_BIAS_DEG_S", "MAX_ACCEL_BIAS_MPS2", "DATUM_TOL_M", "WARN_INTERVAL_S", "EXTRAPOLATION_ACCEL_MPS2"]

#: 1 sigma floors [position m, velocity m/s, attitude deg] added to the sum of covariances: the
#: process noise between two epochs and the linearization (a legitimate correction never needs more)
CORRECTION_FLOOR_SIGMA = (3.0, 1.0, 2.0)
#: false-alarm probability of the correction gate (9 dof: threshold 60.7, about 7.8 sigma)
CORRECTION_P_FALSE = 1e-9
#: a feedback stamp may lead the node's newest IMU stamp by this much [s]
FUTURE_TOL_S = 2.0
#: an ALIGNED status with a heading sigma above this [deg] is refused (the ifa_node declares it at 0.1 deg)
MAX_ALIGNED_HEADING_SIGMA_DEG = 1.0
#: an IMU bias estimate above these is refused [deg/s], [m/s^2]
MAX_GYRO_BIAS_DEG_S = 10.0
MAX_ACCEL_BIAS_MPS2 = 2.0
#: a datum within this distance [m] of the first is the same datum
DATUM_TOL_M = 0.01
#: a refusal of one reason is logged at most this often [s] after the first
WARN_INTERVAL_S = 10.0
#: acceleration bound [m/s^2] for comparing a correction ahead of the node's newest state
EXTRAPOLATION_ACCEL_MPS2 = 20.0


class Refusal(NamedTuple):
    """Why an input is refused: ``reason`` (a short code for the counters) and ``text`` (for people)."""

    reason: str
    text: str


def check_stamp(t_ns: int, last_ns: int | None, newest_ns: int | None, future_tol_s: float = FUTURE_TOL_S) -> Refusal | None:
    """A feedback stamp ``t_ns`` [ns] against the last accepted one ``last_ns`` and the node's newest
    own stamp ``newest_ns`` (its IMU; None: not known yet, no future check).

    Returns ``Refusal("future", ...)`` when ``t_ns > newest_ns + future_tol_s``,
    ``Refusal("before_last", ...)`` when ``t_ns < last_ns`` (equal is a replacement, accepted), else None.
    """
    t = int(t_ns)
    if newest_ns is not None and t > int(newest_ns) + int(round(future_tol_s * 1e9)):
        return Refusal("future", f"stamp {t} ns is {(t - int(newest_ns)) * 1e-9:.6g} s after the newest IMU stamp "
                                 f"{int(newest_ns)} ns (tolerance {future_tol_s:g} s)")
    if last_ns is not None and t < int(last_ns):
        return Refusal("before_last", f"stamp {t} ns is {(int(last_ns) - t) * 1e-9:.6g} s before the last accepted one "
                                      f"{int(last_ns)} ns")
    return None


def correction_difference(llh: ArrayLike, vel_n_mps: ArrayLike, q_nb: ArrayLike,
                          own_llh: ArrayLike, own_vel_n_mps: ArrayLike, own_q_nb: ArrayLike) -> FloatArray:
    """The difference (9,) of a corrected state from the node's own: position [m] (ENU at the own
    position), velocity [m/s] (ENU), attitude error [rad] (ENU rotation vector, exact:
    :func:`dpos_core.attitude.attitude_error` of the own attitude against the corrected one)."""
    d_pos = earth.enu_between(own_llh, llh) * -1.0  # from own to corrected
    d_vel = np.asarray(vel_n_mps, dtype=float).reshape(3) - np.asarray(own_vel_n_mps, dtype=float).reshape(3)
    d_att = attitude_error(quat_to_dcm(np.asarray(own_q_nb, dtype=float)), quat_to_dcm(np.asarray(q_nb, dtype=float)))
    return np.concatenate([d_pos, d_vel, np.asarray(d_att, dtype=float).reshape(3)])


def _block_diag(pos: ArrayLike, vel: ArrayLike, att: ArrayLike) -> FloatArray:
    out = np.zeros((9, 9))
    for i, c in enumerate((pos, vel, att)):
        out[3 * i:3 * i + 3, 3 * i:3 * i + 3] = np.asarray(c, dtype=float).reshape(3, 3)
    return out


def check_correction(diff: ArrayLike, own_cov: tuple[ArrayLike, ArrayLike, ArrayLike],
                     corr_cov: tuple[ArrayLike, ArrayLike, ArrayLike],
                     floor_sigma: Sequence[float] = CORRECTION_FLOOR_SIGMA, p_false: float = CORRECTION_P_FALSE,
                     extra_var: ArrayLike | None = None) -> Refusal | None:
    """The chi-square gate of a correction (module docstring).

    Args:
        diff: (9,) corrected minus own state (:func:`correction_difference`).
        own_cov, corr_cov: (position [m^2], velocity [m^2/s^2], attitude [rad^2]) covariances (3, 3)
            each, ENU: the node's own and the correction's.
        floor_sigma: [position m, velocity m/s, attitude deg] 1 sigma floors added (each axis).
        p_false: the gate's false-alarm probability (9 dof).
        extra_var: (9,) variances added too (e.g. for an own state extrapolated to the stamp), or None.

    Returns:
        ``Refusal("covariance", ...)`` (the correction's covariance is not finite, symmetric, PSD),
        ``Refusal("nonfinite", ...)`` (the difference is not finite), ``Refusal("size", ...)`` (the
        test fails: the text gives the position / velocity / attitude differences and the
        statistic), else None.
    """
    d = np.asarray(diff, dtype=float).reshape(9)
    P_corr = _block_diag(*corr_cov)
    if not np.all(np.isfinite(P_corr)):
        return Refusal("covariance", "its covariance is not finite")
    scale = max(float(np.max(np.abs(P_corr))), 1e-300)
    if float(np.max(np.abs(P_corr - P_corr.T))) > 1e-6 * scale:
        return Refusal("covariance", "its covariance is not symmetric")
    if float(np.min(np.linalg.eigvalsh(0.5 * (P_corr + P_corr.T)))) < -1e-9 * scale:
        return Refusal("covariance", "its covariance is not positive semi-definite")
    if not np.all(np.isfinite(d)):
        return Refusal("nonfinite", "its state is not finite")
    fp, fv, fa = (float(x) for x in floor_sigma)
    floor = np.array([fp] * 3 + [fv] * 3 + [fa * DEG] * 3) ** 2
    S = _block_diag(*own_cov) + P_corr + np.diag(floor)
    if extra_var is not None:
        S = S + np.diag(np.asarray(extra_var, dtype=float).reshape(9))
    S = 0.5 * (S + S.T)
    if not np.all(np.isfinite(S)):
        return Refusal("covariance", "the sum of covariances is not finite")
    d2 = float(d @ np.linalg.solve(S, d))
    limit = chi2_quantile(1.0 - p_false, 9)
    if d2 <= limit:
        return None
    return Refusal("size", f"it moves the state by {np.linalg.norm(d[:3]):.4g} m, {np.linalg.norm(d[3:6]):.4g} m/s, "
                           f"{np.linalg.norm(d[6:]) / DEG:.4g} deg: chi-square {d2:.4g} > {limit:.4g} (9 dof, p {p_false:g}) "
                           f"against the node's and the correction's covariances (position sigma "
                           f"{math.sqrt(max(np.trace(np.asarray(own_cov[0], dtype=float)) / 3, 0.0)):.3g} m own, "
                           f"{math.sqrt(max(np.trace(np.asarray(corr_cov[0], dtype=float)) / 3, 0.0)):.3g} m its)")


def extrapolation_var(dt_s: float, accel_mps2: float = EXTRAPOLATION_ACCEL_MPS2) -> FloatArray:
    """(9,) variances of an own state carried ``dt_s`` ahead at constant velocity: position
    ``(a dt^2 / 2)^2``, velocity ``(a dt)^2``, attitude (0.1 rad/s dt)^2, ``a`` = ``accel_mps2``."""
    dt = abs(float(dt_s))
    return np.array([(0.5 * accel_mps2 * dt * dt) ** 2] * 3 + [(accel_mps2 * dt) ** 2] * 3 + [(0.1 * dt) ** 2] * 3)


def check_bias(gyro_radps: ArrayLike, accel_mps2: ArrayLike, max_gyro_deg_s: float = MAX_GYRO_BIAS_DEG_S,
               max_accel_mps2: float = MAX_ACCEL_BIAS_MPS2) -> Refusal | None:
    """An IMU bias estimate (gyro [rad/s] (3,), accel [m/s^2] (3,)): ``nonfinite`` or ``size`` (a
    component above the bounds), else None."""
    gb = np.asarray(gyro_radps, dtype=float).reshape(3)
    ab = np.asarray(accel_mps2, dtype=float).reshape(3)
    if not (np.all(np.isfinite(gb)) and np.all(np.isfinite(ab))):
        return Refusal("nonfinite", "its bias is not finite")
    g_max, a_max = float(np.max(np.abs(gb))) / DEG, float(np.max(np.abs(ab)))
    if g_max > max_gyro_deg_s or a_max > max_accel_mps2:
        return Refusal("size", f"a gyro bias of {g_max:.4g} deg/s / an accelerometer bias of {a_max:.4g} m/s^2 is not an "
                               f"IMU's (at most {max_gyro_deg_s:g} deg/s, {max_accel_mps2:g} m/s^2)")
    return None


def check_aligned(claims_aligned: bool, heading_sigma_deg: str | float | None,
                  max_heading_sigma_deg: float = MAX_ALIGNED_HEADING_SIGMA_DEG) -> Refusal | None:
    """An aligned claim (ALIGNED / DEGRADED) against the heading sigma [deg] the status carries (a
    number or its text; missing / not a number / not finite / above ``max_heading_sigma_deg``:
    refused, ``unsupported``). A claim of not aligned always passes."""
    if not claims_aligned:
        return None
    try:
        s = float(heading_sigma_deg) if heading_sigma_deg is not None else math.nan
    except (TypeError, ValueError):
        s = math.nan
    if not math.isfinite(s) or s < 0.0:
        return Refusal("unsupported", f"it claims ALIGNED without a valid heading sigma ({heading_sigma_deg!r})")
    if s > max_heading_sigma_deg:
        return Refusal("unsupported", f"it claims ALIGNED with a heading sigma of {s:.6g} deg "
                                      f"(at most {max_heading_sigma_deg:g} deg supports it)")
    return None


def check_datum(first_llh: ArrayLike | None, new_llh: ArrayLike, tol_m: float = DATUM_TOL_M) -> Refusal | None:
    """A datum ``new_llh`` [lat_rad, lon_rad, h_m] against the session's first (None: no first yet,
    passes when finite). ``nonfinite``: not finite; ``changed``: more than ``tol_m`` from the first."""
    new = np.asarray(new_llh, dtype=float).reshape(3)
    if not np.all(np.isfinite(new)) or abs(new[0]) > math.pi / 2:
        return Refusal("nonfinite", f"datum {new.tolist()} is not a position")
    if first_llh is None:
        return None
    first = np.asarray(first_llh, dtype=float).reshape(3)
    dist = float(np.linalg.norm(earth.enu_between(first, new)))
    if dist <= tol_m:
        return None
    return Refusal("changed", f"datum lat {new[0] / DEG:.9f} lon {new[1] / DEG:.9f} deg h {new[2]:.3f} m is {dist:.6g} m "
                              f"from the session's datum lat {first[0] / DEG:.9f} lon {first[1] / DEG:.9f} deg "
                              f"h {first[2]:.3f} m: a datum may not change within a session (the first is kept)")


@dataclass
class GateCounts:
    """The refusals of one node, by reason (``<topic>/<reason>`` by convention), and when to log them.

    Attributes:
        by_reason: refusals per reason.
        last: the latest refusal, for people.
        interval_s: after the first refusal of a reason, at most one log line per this many seconds.
    """

    interval_s: float = WARN_INTERVAL_S
    by_reason: dict[str, int] = field(default_factory=dict)
    last: str = ""
    _logged_at: dict[str, float] = field(default_factory=dict)
    _since: dict[str, int] = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.by_reason.values())

    def refuse(self, reason: str, text: str, now_s: float) -> str | None:
        """Count a refusal; the line to log now (the first of ``reason``, then at most one per
        ``interval_s`` of ``now_s``, a monotonic clock [s]) or None (counted, not logged)."""
        self.by_reason[reason] = self.by_reason.get(reason, 0) + 1
        self.last = f"{reason}: {text}"
        self._since[reason] = self._since.get(reason, 0) + 1
        at = self._logged_at.get(reason)
        if at is not None and now_s - at < self.interval_s:
            return None
        n = self._since.pop(reason)
        self._logged_at[reason] = now_s
        more = f" ({n} refused since the last report)" if at is not None and n > 1 else ""
        return f"refused {reason}: {text}{more} [{self.by_reason[reason]} so far]"

    def values(self) -> dict[str, int | str]:
        """The status key/values: ``gate_refused`` (total), ``gate/<reason>`` each, ``last_gate``."""
        out: dict[str, int | str] = {"gate_refused": self.total}
        out.update({f"gate/{k}": n for k, n in sorted(self.by_reason.items())})
        out["last_gate"] = self.last
        return out


@dataclass
class PublisherWatch:
    """Topics that should have one publisher each (besides the node's own, when it publishes them).

    :meth:`update` takes the current endpoints of a topic (``(gid, node name)``) and returns a
    sentence when a new endpoint makes more than ``expected`` at once (a second graph on the
    domain, a stray process). ``extra`` is, per topic, the most publishers seen at once beyond
    ``expected``; ``replaced`` counts single publishers whose GID changed (a restarted publisher:
    not a second one).
    """

    expected: dict[str, int]
    seen: dict[str, set[bytes]] = field(default_factory=dict)
    current: dict[str, set[bytes]] = field(default_factory=dict)
    extra: dict[str, int] = field(default_factory=dict)
    replaced: dict[str, int] = field(default_factory=dict)

    def update(self, topic: str, endpoints: Iterable[tuple[bytes, str]]) -> list[str]:
        eps = list(endpoints)
        gids = {g for g, _ in eps}
        seen = self.seen.setdefault(topic, set())
        before = self.current.get(topic, set())
        out: list[str] = []
        limit = self.expected.get(topic, 1)
        new = gids - seen
        if len(gids) > limit:
            self.extra[topic] = max(self.extra.get(topic, 0), len(gids) - limit)
        if len(gids) > limit and new:
            names = sorted({n for _, n in eps})
            out.append(f"{len(gids)} publishers on {topic} (expected {limit}): {', '.join(names)}; "
                       "a second graph on this ROS domain or a stray process? (use another ROS_DOMAIN_ID, or DDS Security)")
        elif new and before and not (before & gids) and len(gids) <= limit:
            self.replaced[topic] = self.replaced.get(topic, 0) + len(new)
        seen |= gids
        self.current[topic] = gids
        return out

    def values(self) -> dict[str, int]:
        """Status key/values: ``publishers_extra/<topic>`` and ``publishers_replaced/<topic>`` (non-zero ones)."""
        out = {f"publishers_extra{t}": n for t, n in sorted(self.extra.items())}
        out.update({f"publishers_replaced{t}": n for t, n in sorted(self.replaced.items())})
        return out


@dataclass
class InterleaveWatch:
    """Two sources interleaving on one stream: of the last ``window`` samples, at least
    ``min_back`` had a stamp at or before the newest one (an isolated glitch is one or two).

    :meth:`add` returns True when an episode starts (report it); ``episodes`` counts them; an
    episode ends after ``window`` samples in order.
    """

    window: int = 200
    min_back: int = 10
    episodes: int = 0
    _flags: deque[bool] = field(default_factory=deque)
    _n: int = 0
    _active: bool = False

    def add(self, back: bool) -> bool:
        """One sample: ``back`` = its stamp was at or before the newest one seen (O(1))."""
        self._flags.append(bool(back))
        self._n += bool(back)
        if len(self._flags) > self.window:
            self._n -= self._flags.popleft()
        n = self._n
        if not self._active and n >= self.min_back:
            self._active = True
            self.episodes += 1
            return True
        if self._active and n == 0:
            self._active = False
        return False

    @property
    def back_in_window(self) -> int:
        return self._n
