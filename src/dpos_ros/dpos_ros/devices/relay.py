"""``device: ros``: relay an existing driver's standard topics onto the dpos contract topics.

A device node (pos_sub_node, pos_master_node) with ``device: ros`` does not simulate anything: a
:class:`DeviceRelay` subscribes to a real driver's topics (relative, remappable names such as
``imu_in``, so ``--ros-args -r imu_in:=/vn100/imu`` points it at a driver) and republishes every
good message on the contract topic (docs/design.md "Topics"), e.g. ``/sub_imu/<name>/imu``.

Per message (one :class:`Route` = one driver input -> one contract output)
    - ``header.stamp`` is kept (the sampling time, design.md "Frames, units, time"); the output's
      ``header.frame_id`` is the route's frame (``master_imu``, ``sub_imu_<name>``, ``gnss``).
    - Rejected, counted, and warned about (the first time per route and reason at once, then at
      most every ``WARN_PERIOD_S`` with the count; never an exception), with the reasons
      (:data:`REASONS`):
      ``nan`` (a NaN/inf value or covariance), ``zero_stamp`` (stamp 0: the driver does not stamp),
      ``duplicate`` (the stamp of the previous accepted message of this input),
      ``out_of_order`` (older than it), ``unavailable`` (Imu: angular velocity or linear
      acceleration covariance[0] = -1, "field not provided" per sensor_msgs/Imu; Twist: linear
      covariance[0] = -1), ``no_fix`` (NavSatFix status NO_FIX), ``zero_cov`` (NavSatFix / Twist:
      all-zero position / linear-velocity covariance, i.e. unknown), ``negative_cov`` (a negative
      variance on the diagonal), ``out_of_range`` (latitude outside [-90, 90] or longitude
      outside [-180, 180] deg).
      An all-zero Imu covariance ("unknown" per sensor_msgs/Imu) is accepted: the transfer
      alignment uses the aircraft configuration's sensor error model, not the message's.
    - Stamp jumps: a stamp more than ``JUMP_S`` ahead of the last accepted one is held, not
      relayed at once. When the next message goes on from the old stamps, the held one(s) were a
      glitch (one message stamped +1 h): rejected (``jump``), and the stream goes on - one bad
      stamp costs that message only, where accepting it made every later message ``out_of_order``.
      When ``JUMP_CONFIRM`` messages in a row go on from the new stamps, the jump was real (a long
      gap, a clock step): the held ones are relayed in order.
    - Gaps: an accepted stamp step larger than ``GAP_FACTOR`` (1.75, dpos_core.series) times the median of the last
      ``PERIOD_WINDOW`` steps (once ``MIN_PERIODS`` steps are known) is counted as a gap, with the
      estimated number of missing samples, and warned about. The message itself is relayed.
    - ``imu`` routes: with ``R_out_in`` (3, 3) the angular velocity and linear acceleration are
      rotated from the driver's axes into our FLU body axes, ``x_out = R_out_in @ x_in``, and their
      covariances ``C_out = R_out_in @ C_in @ R_out_in.T``. Drivers often publish FRD axes or a
      mounting frame; the nodes take ``input_rotation_rpy_deg`` ([roll, pitch, yaw] of the driver
      axes in our body axes, URDF/tf2 ``setRPY`` convention, see :func:`rotation_from_rpy_deg`);
      FRD -> FLU is ``[180, 0, 0]``. The orientation field is not relayed: the output carries an
      identity quaternion with ``orientation_covariance[0] = -1`` as the contract says.
    - ``fix`` routes (sensor_msgs/NavSatFix): passed through; ``position_covariance`` is ENU
      (REP 145), as the contract's ``/gnss/fix``.
    - ``vel`` routes (geometry_msgs/TwistWithCovarianceStamped): passed through. GNSS drivers
      (nmea_navsat_driver's ``vel``, ublox_gps's ``fix_velocity``) publish the velocity in ENU
      axes at the antenna, as the contract's ``/gnss/vel``; the angular part may be unknown
      (-1 on its diagonal), it is not checked.

QoS
    Inputs: ``best_effort`` by default (a best-effort reader matches reliable and best-effort
    driver publishers; most drivers publish with the sensor-data profile), ``reliable`` on request
    (then only reliable publishers match, and the driver's writer retransmits what was lost);
    KEEP_LAST with the contract's deep queue, VOLATILE. Outputs: the contract's
    :data:`dpos_ros.contract.qos.SENSOR_QOS`.

Status
    The relay itself publishes a ``diagnostic_msgs/DiagnosticArray`` on ``~/status`` (i.e.
    ``/<node name>/status``, :data:`dpos_ros.contract.qos.STATUS_QOS`, latched) every ``status_period_s``
    (1 s), one DiagnosticStatus per route with its counts; pass ``status_period_s=None`` to publish
    :meth:`DeviceRelay.diagnostics` yourself. :attr:`DeviceRelay.stats` gives the same counts.

Threading: the callbacks may run in any executor (a lock guards the counts); ``on_message`` is
called in the subscription callback, after the message is published.
"""

from __future__ import annotations

import copy
import math
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from dpos_core.series import GAP_FACTOR
from dpos_core.units import FloatArray
from dpos_ros.contract.qos import SENSOR_QOS, STATUS_QOS, STREAM_DEPTH
from dpos_ros.io.flow import subscribe_draining, take_waiting
from dpos_ros.runtime.params import param

__all__ = [
    "Route", "RouteStats", "DeviceRelay", "KINDS", "REASONS", "INPUT_RELIABILITIES", "input_qos",
    "rotation_from_rpy_deg", "input_reliability_param", "input_rotation_param",
    "GAP_FACTOR", "PERIOD_WINDOW", "MIN_PERIODS", "WARN_PERIOD_S",
]


#: Route kinds and their message types.
KINDS: dict[str, type] = {"imu": Imu, "fix": NavSatFix, "vel": TwistWithCovarianceStamped}
#: Reasons a message is rejected (see the module docstring).
REASONS = ("nan", "zero_stamp", "duplicate", "out_of_order", "unavailable", "no_fix", "zero_cov", "negative_cov",
           "out_of_range", "jump")
#: A stamp this far [s] ahead of the last accepted one is held until the stream confirms it.
JUMP_S = 60.0
#: Messages in a row (the held one included) on the new stamps that confirm a jump as real.
JUMP_CONFIRM = 3
#: Values of the nodes' ``input_reliability`` parameter.
INPUT_RELIABILITIES = ("best_effort", "reliable")
#: A stamp step larger than this times the median step is a gap.
#: Number of recent stamp steps whose median is the nominal period.
PERIOD_WINDOW = 200
#: Steps needed before gaps are detected.
MIN_PERIODS = 5
#: Repeated warnings of one route and reason are logged at most this often [s].
WARN_PERIOD_S = 5.0


@dataclass(frozen=True)
class Route:
    """One driver input -> one contract output.

    Attributes:
        kind: ``imu`` (sensor_msgs/Imu), ``fix`` (sensor_msgs/NavSatFix) or ``vel``
            (geometry_msgs/TwistWithCovarianceStamped).
        input_topic: the driver topic; a relative name (``imu_in``) can be remapped.
        output_topic: the contract topic, e.g. ``/sub_imu/<name>/imu``.
        frame_id: the ``header.frame_id`` of the output, e.g. ``sub_imu_<name>``.
    """

    kind: str
    input_topic: str
    output_topic: str
    frame_id: str

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"route kind {self.kind!r}: expected one of {', '.join(KINDS)}")
        for name in ("input_topic", "output_topic", "frame_id"):
            if not getattr(self, name):
                raise ValueError(f"route {self.kind}: {name} must not be empty")


@dataclass
class RouteStats:
    """Counts of one route (a snapshot when read through :attr:`DeviceRelay.stats`).

    ``received == relayed + sum(rejected.values()) + held`` (``held``: messages after a stamp jump
    that wait for the stream to confirm it, module docstring); ``gaps`` stamp steps larger than
    ``GAP_FACTOR`` x ``period_s``, missing about ``missing`` samples; ``last_stamp_ns`` of the
    last accepted message.
    """

    received: int = 0
    relayed: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    gaps: int = 0
    missing: int = 0
    largest_gap_s: float = 0.0
    period_s: float | None = None
    last_stamp_ns: int | None = None
    held: int = 0

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())


def rotation_from_rpy_deg(rpy_deg: Sequence[float]) -> FloatArray:
    """R_out_in (3, 3) of [roll, pitch, yaw] in degrees: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    The URDF / tf2 ``setRPY`` convention: the orientation of the input (driver) axes in the output
    (body) axes, so that ``v_out = R_out_in @ v_in``. ``[180, 0, 0]`` maps FRD to FLU.
    """
    r, p, y = (math.radians(float(a)) for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    R = Rz @ Ry @ Rx
    R[np.abs(R) < 1e-15] = 0.0  # exact zeros for multiples of 90 deg
    return R


def input_qos(reliability: str) -> QoSProfile:
    """The QoS of a driver subscription: ``best_effort`` or ``reliable``, KEEP_ALL, VOLATILE: what
    was delivered is never overwritten before the relay takes it (:func:`~dpos_ros.contract.qos.keep_all`)."""
    if reliability not in INPUT_RELIABILITIES:
        raise ValueError(f"input reliability {reliability!r}: expected one of {', '.join(INPUT_RELIABILITIES)}")
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        depth=STREAM_DEPTH,
        reliability=ReliabilityPolicy.BEST_EFFORT if reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def input_reliability_param() -> Any:
    """The ``input_reliability`` parameter of a ``device: ros`` node (a :func:`~dpos_ros.runtime.params.param` field)."""
    return param(
        "best_effort",
        "device: ros: QoS reliability of the driver subscriptions; best_effort matches every driver, "
        "reliable only reliable publishers",
        choices=INPUT_RELIABILITIES,
    )


def input_rotation_param() -> Any:
    """The ``input_rotation_rpy_deg`` parameter of a ``device: ros`` node (see :func:`rotation_from_rpy_deg`)."""
    return param(
        (0.0, 0.0, 0.0),
        "device: ros: [roll, pitch, yaw] [deg] of the driver's IMU axes in our FLU body axes "
        "(URDF rpy; FRD -> FLU = [180, 0, 0]); the IMU vectors and covariances are rotated by it",
        length=3,
    )


# ----------------------------------------------------------------------------- checks


def _finite(*values: Any) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)


def _vec(v: Any) -> FloatArray:
    return np.array([v.x, v.y, v.z], dtype=float)


def _set_vec(v: Any, x: FloatArray) -> None:
    v.x, v.y, v.z = (float(a) for a in x)


def _cov_reason(cov3: FloatArray) -> str | None:
    """``zero_cov`` / ``negative_cov`` / None for a (3, 3) covariance."""
    d = np.diag(cov3)
    if np.any(d < 0.0):
        return "negative_cov"
    if not np.any(cov3):
        return "zero_cov"
    return None


def _check_imu(msg: Imu) -> str | None:
    w_cov = np.asarray(msg.angular_velocity_covariance, dtype=float)
    a_cov = np.asarray(msg.linear_acceleration_covariance, dtype=float)
    if not _finite(_vec(msg.angular_velocity), _vec(msg.linear_acceleration), w_cov, a_cov):
        return "nan"
    if w_cov[0] == -1.0 or a_cov[0] == -1.0:
        return "unavailable"
    if np.any(w_cov[[0, 4, 8]] < 0.0) or np.any(a_cov[[0, 4, 8]] < 0.0):
        return "negative_cov"
    return None


def _check_fix(msg: NavSatFix) -> str | None:
    cov = np.asarray(msg.position_covariance, dtype=float)
    if not _finite([msg.latitude, msg.longitude, msg.altitude], cov):
        return "nan"
    if msg.status.status <= NavSatStatus.STATUS_NO_FIX:
        return "no_fix"
    if not (-90.0 <= msg.latitude <= 90.0 and -180.0 <= msg.longitude <= 180.0):
        return "out_of_range"
    return _cov_reason(cov.reshape(3, 3))


def _check_vel(msg: TwistWithCovarianceStamped) -> str | None:
    cov = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[:3, :3]
    if not _finite(_vec(msg.twist.twist.linear), cov):
        return "nan"
    if cov[0, 0] == -1.0:
        return "unavailable"
    return _cov_reason(cov)


_CHECKS: dict[str, Callable[[Any], str | None]] = {"imu": _check_imu, "fix": _check_fix, "vel": _check_vel}


def _rotate_imu(msg: Imu, R: FloatArray) -> None:
    """Rotate the IMU vectors and covariances in place: x' = R x, C' = R C R^T."""
    _set_vec(msg.angular_velocity, R @ _vec(msg.angular_velocity))
    _set_vec(msg.linear_acceleration, R @ _vec(msg.linear_acceleration))
    for name in ("angular_velocity_covariance", "linear_acceleration_covariance"):
        C = np.asarray(getattr(msg, name), dtype=float).reshape(3, 3)
        setattr(msg, name, (R @ C @ R.T).reshape(9))


_NO_ORIENTATION_COV = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])


# ----------------------------------------------------------------------------- relay


class _RouteState:
    """Mutable per-route state (under the relay's lock)."""

    def __init__(self, route: Route) -> None:
        self.route = route
        self.stats = RouteStats()
        self.steps_ns: deque[int] = deque(maxlen=PERIOD_WINDOW)
        self.warned_at: dict[str, float] = {}
        self.publisher: Any = None
        self.subscription: Any = None
        self.held: list[tuple[int, Any]] = []  # (stamp [ns], message) held after a stamp jump

    @property
    def input_name(self) -> str:
        """The resolved (remapped) input topic."""
        return self.subscription.topic_name if self.subscription is not None else self.route.input_topic


class DeviceRelay:
    """Relays driver topics onto contract topics (see the module docstring).

    Args:
        node: the node that owns the subscriptions, publishers, status timer and logger.
        routes: the routes; input and output topics must be unique.
        input_reliability: ``best_effort`` (default) or ``reliable``.
        R_out_in: (3, 3) rotation of every ``imu`` route's vectors from the driver's axes into the
            body axes (a proper rotation); None = identity.
        on_message: called as ``on_message(output_topic, msg)`` after each relayed message.
        status_period_s: period of the DiagnosticArray on ``~/status``; None = no status publisher.

    Raises:
        ValueError: duplicate topics, a bad ``input_reliability`` or ``R_out_in``.
    """

    def __init__(
        self,
        node: Node,
        routes: Sequence[Route],
        *,
        input_reliability: str = "best_effort",
        R_out_in: FloatArray | None = None,
        on_message: Callable[[str, Any], None] | None = None,
        status_period_s: float | None = 1.0,
    ) -> None:
        if not routes:
            raise ValueError("a relay needs at least one route")
        for attr in ("input_topic", "output_topic"):
            names = [getattr(r, attr) for r in routes]
            if len(set(names)) != len(names):
                raise ValueError(f"routes: duplicate {attr} in {names}")
        qos_in = input_qos(input_reliability)
        self.R_out_in = None if R_out_in is None else self._check_rotation(R_out_in)
        self.node = node
        self.input_reliability = input_reliability
        self._on_message = on_message
        self._log = node.get_logger()
        self._lock = threading.Lock()
        self._states: list[_RouteState] = []
        for route in routes:
            st = _RouteState(route)
            st.publisher = node.create_publisher(KINDS[route.kind], route.output_topic, SENSOR_QOS)
            st.subscription = subscribe_draining(node, KINDS[route.kind], route.input_topic,
                                                 lambda msg, s=st: self._on_input(s, msg), qos_in)
            self._states.append(st)
        self._status_pub = None
        if status_period_s is not None:
            self._status_pub = node.create_publisher(DiagnosticArray, "~/status", STATUS_QOS)
            self._status_timer = node.create_timer(status_period_s, self.publish_status)

    @staticmethod
    def _check_rotation(R: Any) -> FloatArray:
        R = np.asarray(R, dtype=float)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError(f"R_out_in must be a finite (3, 3) rotation, got shape {R.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) <= 0.0:
            raise ValueError(f"R_out_in is not a proper rotation (orthonormal, det +1): {R.tolist()}")
        return R

    # ------------------------------------------------------------------ public

    @property
    def routes(self) -> list[Route]:
        return [s.route for s in self._states]

    def describe(self) -> str:
        """``imu_in (/drv/imu) -> /sub_imu/x/imu [sub_imu_x], ...`` with the resolved inputs."""
        return ", ".join(f"{s.route.input_topic} ({s.input_name}) -> {s.route.output_topic} [{s.route.frame_id}]"
                         for s in self._states)

    @property
    def stats(self) -> dict[str, RouteStats]:
        """A snapshot of the counts, keyed by output topic."""
        with self._lock:
            snap = {s.route.output_topic: copy.deepcopy(s.stats) for s in self._states}
            for s in self._states:
                snap[s.route.output_topic].held = len(s.held)
            return snap

    def diagnostics(self) -> list[DiagnosticStatus]:
        """One DiagnosticStatus per route: OK, or WARN with no input yet / rejections / gaps."""
        out = []
        name = self.node.get_name()
        with self._lock:
            for s in self._states:
                st = s.stats
                d = DiagnosticStatus(name=f"{name}: {s.input_name} -> {s.route.output_topic}", hardware_id=name)
                problems = []
                if st.received == 0:
                    problems.append(f"no message on {s.input_name} yet")
                if st.rejected:
                    problems.append("rejected " + ", ".join(f"{k} {v}" for k, v in sorted(st.rejected.items())))
                if st.gaps:
                    problems.append(f"{st.gaps} gap(s), ~{st.missing} sample(s) missing")
                d.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
                d.message = "; ".join(problems) or f"relaying ({st.relayed} messages)"
                values = {"input_topic": s.input_name, "output_topic": s.route.output_topic, "kind": s.route.kind,
                          "received": st.received, "relayed": st.relayed, "rejected": st.rejected_total,
                          "gaps": st.gaps, "missing": st.missing, "largest_gap_s": f"{st.largest_gap_s:.6g}",
                          "period_s": "" if st.period_s is None else f"{st.period_s:.6g}",
                          "last_stamp_ns": "" if st.last_stamp_ns is None else st.last_stamp_ns}
                values.update({f"rejected/{k}": v for k, v in sorted(st.rejected.items())})
                d.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
                out.append(d)
        return out

    def publish_status(self) -> None:
        """Publish :meth:`diagnostics` on ``~/status`` (called by the status timer)."""
        if self._status_pub is None:
            return
        arr = DiagnosticArray()
        arr.header.stamp = self.node.get_clock().now().to_msg()
        arr.status = self.diagnostics()
        self._status_pub.publish(arr)

    # ------------------------------------------------------------------ per message

    def take_pending(self, kinds: Sequence[str]) -> int:
        """Relay now what waits in the middleware on the routes of ``kinds`` (e.g. ``("fix", "vel")``
        before a decision that needs every fix up to a stamp: the node may have been busy); returns
        how many messages were taken."""
        n = 0
        for st in self._states:
            if st.route.kind not in kinds:
                continue
            try:
                more = take_waiting(st.subscription, KINDS[st.route.kind], False)
            except RuntimeError:  # being destroyed
                continue
            for m, _ in more:
                self._on_input(st, m)
            n += len(more)
        return n

    def _on_input(self, s: _RouteState, msg: Any) -> None:
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            s.stats.received += 1
            reason = _CHECKS[s.route.kind](msg)
            glitches: list[int] = []
            if reason is None:
                reason, release, glitches = self._order(s, t_ns, msg)
            if glitches:
                s.stats.rejected["jump"] = s.stats.rejected.get("jump", 0) + len(glitches)
                jumps = s.stats.rejected["jump"]
            if reason is not None:
                s.stats.rejected[reason] = s.stats.rejected.get(reason, 0) + 1
                count = s.stats.rejected[reason]
            last = s.stats.last_stamp_ns
        if glitches:
            self._warn(s, "jump", f"{s.route.kind} on {s.input_name}: {len(glitches)} message(s) stamped "
                       f"{(glitches[0] - (last or glitches[0])) * 1e-9:.6g} s ahead of the stream rejected (jump: a glitched "
                       f"stamp; the stream goes on from {last} ns); {jumps} rejected for jump so far")
        if reason is not None:
            self._warn(s, reason, f"{s.route.kind} on {s.input_name} rejected ({reason}): stamp {t_ns} ns"
                       f"{'' if last is None else f', previous accepted {last} ns'}; {count} rejected for {reason} so far")
            return
        for m in release:
            self._relay(s, m)

    def _order(self, s: _RouteState, t_ns: int, msg: Any) -> tuple[str | None, list[Any], list[int]]:
        """The stamp checks of a good message (under the lock; module docstring, "Stamp jumps"):
        ``(reason it is rejected or None, the messages to relay now in order, the stamps of held
        messages found to be glitches)``."""
        if t_ns <= 0:
            return "zero_stamp", [], []
        glitches: list[int] = []
        last = s.stats.last_stamp_ns
        if s.held:
            if t_ns > s.held[-1][0]:  # on the new stamps
                s.held.append((t_ns, msg))
                if len(s.held) < JUMP_CONFIRM:
                    return None, [], []
                held, s.held = s.held, []
                for t, _ in held:  # a real jump: the bookkeeping of each, in order
                    self._check_stamp(s, t)
                return None, [m for _, m in held], []
            if last is None or not last < t_ns < s.held[0][0]:
                return ("duplicate" if t_ns == last or any(t_ns == t for t, _ in s.held) else "out_of_order"), [], []
            glitches = [t for t, _ in s.held]  # the old stamps go on: the held ones were glitches
            s.held = []
        if last is not None and t_ns - last > JUMP_S * 1e9:
            s.held = [(t_ns, msg)]
            return None, [], glitches
        reason = self._check_stamp(s, t_ns)
        return reason, ([msg] if reason is None else []), glitches

    def _relay(self, s: _RouteState, msg: Any) -> None:
        """Publish one accepted message on the route's contract topic."""
        msg.header.frame_id = s.route.frame_id
        if s.route.kind == "imu":
            if self.R_out_in is not None:
                _rotate_imu(msg, self.R_out_in)
            msg.orientation.x = msg.orientation.y = msg.orientation.z = 0.0
            msg.orientation.w = 1.0
            msg.orientation_covariance = _NO_ORIENTATION_COV.copy()
        s.publisher.publish(msg)
        with self._lock:
            s.stats.relayed += 1
        if self._on_message is not None:
            self._on_message(s.route.output_topic, msg)

    def _check_stamp(self, s: _RouteState, t_ns: int) -> str | None:
        """Order and gap bookkeeping of an otherwise good message (under the lock)."""
        st = s.stats
        if t_ns <= 0:
            return "zero_stamp"
        if st.last_stamp_ns is not None:
            dt = t_ns - st.last_stamp_ns
            if dt == 0:
                return "duplicate"
            if dt < 0:
                return "out_of_order"
            if len(s.steps_ns) >= MIN_PERIODS:
                period = statistics.median(s.steps_ns)
                st.period_s = period * 1e-9
                if dt > GAP_FACTOR * period:
                    missing = max(1, round(dt / period) - 1)
                    st.gaps += 1
                    st.missing += missing
                    st.largest_gap_s = max(st.largest_gap_s, dt * 1e-9)
                    self._warn(s, "gap", f"gap on {s.input_name}: {dt * 1e-9:.6g} s between stamps "
                               f"{st.last_stamp_ns} and {t_ns} ns (period {period * 1e-9:.6g} s, ~{missing} sample(s) "
                               f"missing); {st.gaps} gap(s) so far")
                else:
                    s.steps_ns.append(dt)
            else:
                s.steps_ns.append(dt)
        st.last_stamp_ns = t_ns
        return None

    def _warn(self, s: _RouteState, key: str, text: str) -> None:
        """Log at once the first time per route and ``key``, then at most every WARN_PERIOD_S."""
        now = time.monotonic()
        last = s.warned_at.get(key)
        if last is not None and now - last < WARN_PERIOD_S:
            return
        s.warned_at[key] = now
        self._log.warning(text)
