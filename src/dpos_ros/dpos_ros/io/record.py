"""Record DDS topics into a rosbag2 (MCAP, zstd chunks) byte for byte: the library of ``dpos-record``.

:class:`BagRecorder` subscribes **raw** (serialized CDR bytes, ``raw=True``) to the requested
topics and writes every message unchanged, as it arrives, to a bag kept open for the whole
recording; memory stays bounded by the MCAP chunk (rosbags writes and compresses a chunk when it
is full).

Discovery
    A timer (``DISCOVERY_PERIOD_S``) looks up the graph (``get_topic_names_and_types``) for the
    requested topics that have no subscription yet, and subscribes as soon as a publisher
    appears, with the type the graph reports (the first one, with a warning when publishers
    disagree). It keeps looking for the whole recording; topics that never appear are listed by
    :meth:`BagRecorder.missing` (the CLI reports them at the end and exits with status 1).
    ``all_topics`` records every topic discovered except ``ALL_EXCLUDED`` (``/rosout``,
    ``/parameter_events``, ``/clock``), which must be named explicitly.

QoS (docs/design.md, ``dpos_ros.contract.qos``)
    ``/dpos/datum`` and ``*/status``: TRANSIENT_LOCAL (late joiners get the latched message),
    everything else RELIABLE KEEP_ALL (see "Threading"), VOLATILE. Adapted to the publishers like ``ros2 bag``:
    BEST_EFFORT when every publisher is best effort (a reliable reader would match none), VOLATILE
    when a publisher is volatile (a transient-local reader would not match it). The publishers'
    offered QoS profiles are stored in the bag metadata (``offered_qos_profiles``), from which
    ``dpos-play`` restores latching.

Threading
    The subscription callbacks run in the executor of the caller (the CLI spins a
    SingleThreadedExecutor in the main thread); they only put ``(connection, log time, bytes)`` on
    a queue. A writer thread drains the queue into the rosbags ``Writer`` (connections are created
    through the same queue, so no lock is needed and a connection always precedes its messages).
    The executor so never waits for compression or disk. A callback also takes (``take_message``,
    up to ``dpos_ros.io.flow.TAKE_BATCH``) the further samples already waiting on its subscription: the rclpy
    executor's per-dispatch overhead (~100 us) otherwise limits a Python recorder to ~10k msg/s.

    Sensor/navigation streams are subscribed KEEP_ALL (the design allows it; ``keep_all=False``
    gives KEEP_LAST 5000): an acknowledged sample is in the reader's DDS history but not yet
    taken, so a KEEP_LAST reader whose callbacks fall behind by more than its depth would lose
    samples, whereas a KEEP_ALL reader stops acknowledging when its resource limits are reached and
    throttles a flow-controlled publisher (dpos-play, the simulated devices) instead (measured:
    a 300 s, 270k-message bag at ``dpos-play --rate 0`` with a 3000-message window arrives
    complete).

Log time
    The receive time, as ``ros2 bag record`` does: the DDS reception timestamp of the sample
    (``MessageInfo['received_timestamp']``, system clock), or the wall clock when the middleware
    gives none; per topic made non-decreasing so that readers that sort by log time keep the
    arrival order. The header stamps (sampling times) stay inside the unchanged message bytes.

Recoverable problems
    are counted in :attr:`BagRecorder.problems` (kind -> count) and logged as a warning (the first
    of each kind and topic): ``offered_qos`` (a publisher's QoS profile that cannot be stored in
    the metadata; the messages are recorded all the same), ``take`` (taking the further waiting
    samples failed, e.g. the subscription is being destroyed at shutdown; the executor delivers
    the rest), ``destroy`` (a timer or subscription already gone at :meth:`BagRecorder.close`).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from dpos_ros.contract import qos as dpos_qos
from dpos_ros.contract import topics as T
from dpos_ros.contract.topics import message_class
from dpos_ros.io.bag import ROSBAG2_VERSION, typestore
from dpos_ros.io.flow import take_waiting

__all__ = ["BagRecorder", "subscription_qos", "ALL_EXCLUDED", "DISCOVERY_PERIOD_S"]

#: Period of the graph look-up for topics not yet subscribed [s].
DISCOVERY_PERIOD_S = 0.1
#: Topics that ``all_topics`` leaves out (record them by naming them).
ALL_EXCLUDED = ("/rosout", "/parameter_events", "/clock")
#: A queue backlog that is logged (the writer thread does not keep up).
BACKLOG_WARN = 20000

_INFINITE_NS = (2**63 - 1)


def subscription_qos(topic: str, offered: Sequence[QoSProfile] = (), keep_all: bool = True) -> QoSProfile:
    """The recorder's QoS for ``topic`` given the publishers' ``offered`` profiles (module docstring)."""
    base = {"datum": dpos_qos.DATUM_QOS, "status": dpos_qos.STATUS_QOS}.get(T.qos_kind(topic), dpos_qos.SENSOR_QOS)
    reliability = base.reliability
    durability = base.durability
    if offered and all(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in offered):
        reliability = ReliabilityPolicy.BEST_EFFORT
    if durability == DurabilityPolicy.TRANSIENT_LOCAL and any(p.durability == DurabilityPolicy.VOLATILE for p in offered):
        durability = DurabilityPolicy.VOLATILE
    if durability == DurabilityPolicy.TRANSIENT_LOCAL or base is not dpos_qos.SENSOR_QOS or not keep_all:
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(base.depth, 1), reliability=reliability, durability=durability)
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=base.depth, reliability=reliability, durability=durability)


def _rosbags_qos(p: QoSProfile) -> Any:
    """An rclpy QoS profile as rosbags' ``Qos`` (for the metadata's offered_qos_profiles)."""
    def t(d: Any) -> QosTime:
        ns = int(getattr(d, "nanoseconds", 0) or 0)
        if ns <= 0 or ns >= _INFINITE_NS:
            return QosTime(0, 0) if ns <= 0 else QosTime(2147483647, 4294967295)
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)

    def enum(cls: Any, value: Any, default: Any) -> Any:
        try:
            return cls(int(value))
        except (ValueError, TypeError):
            return default

    return Qos(
        history=enum(QosHistory, p.history, QosHistory.UNKNOWN),
        depth=int(p.depth),
        reliability=enum(QosReliability, p.reliability, QosReliability.UNKNOWN),
        durability=enum(QosDurability, p.durability, QosDurability.UNKNOWN),
        deadline=t(p.deadline),
        lifespan=t(p.lifespan),
        liveliness=enum(QosLiveliness, p.liveliness, QosLiveliness.UNKNOWN),
        liveliness_lease_duration=t(p.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(p.avoid_ros_namespace_conventions),
    )


class BagRecorder:
    """Records topics of ``node``'s graph into the new rosbag2 directory ``out`` (module docstring).

    Args:
        node: the rclpy node that owns the subscriptions and the discovery timer; spin it.
        out: new bag directory (must not exist).
        topics: topic names to record.
        all_topics: also record every other topic discovered (but ``ALL_EXCLUDED``).
        custom_data: rosbag2 metadata ``custom_data``.
        watch_session_end: subscribe to ``/session/end`` even when it is not recorded, and set
            :attr:`session_ended` when it arrives.

    Call :meth:`close` once (after the last spin) to flush and close the bag; then :attr:`counts`
    holds the messages written per topic.
    """

    def __init__(
        self,
        node: Any,
        out: Path,
        topics: Iterable[str] = (),
        *,
        all_topics: bool = False,
        custom_data: Mapping[str, str] | None = None,
        watch_session_end: bool = False,
    ) -> None:
        self.node = node
        self.out = Path(out)
        self.requested = list(dict.fromkeys(topics))
        self.all_topics = bool(all_topics)
        self.watch_session_end = bool(watch_session_end)
        self._log = node.get_logger()
        if self.out.exists():
            raise FileExistsError(f"{self.out} exists: choose a new output directory (rosbag2 writes a new one)")
        self._writer = Writer(self.out, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(str(key), str(value))
        self._writer.open()
        self._typestore = typestore()
        #: topic -> message type of the subscribed (recorded) topics, in subscription order
        self.types: dict[str, str] = {}
        #: messages written per recorded topic (final after :meth:`close`)
        self.counts: dict[str, int] = {}
        #: messages received per topic so far (callback side)
        self.received: dict[str, int] = {}
        #: topics that could not be recorded, with the reason
        self.failed: dict[str, str] = {}
        self.session_ended = threading.Event()
        #: time.monotonic() of the last message received, of the /session/end
        self.last_receive = 0.0
        self.session_end_at: float | None = None
        self.error: BaseException | None = None
        #: recoverable problems (module docstring): kind -> count
        self.problems: dict[str, int] = {}
        self._warned_problems: set[tuple[str, str]] = set()
        self._subs: dict[str, Any] = {}
        self._last_t: dict[str, int] = {}
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._closed = False
        self._thread = threading.Thread(target=self._write_loop, name="dpos_record_writer", daemon=True)
        self._thread.start()
        self._timer = node.create_timer(DISCOVERY_PERIOD_S, self.discover)
        self.discover()

    def _problem(self, kind: str, topic: str, text: str, exc: BaseException) -> None:
        """Count a recoverable problem; warn the first one of each kind and topic."""
        self.problems[kind] = self.problems.get(kind, 0) + 1
        if (kind, topic) not in self._warned_problems:
            self._warned_problems.add((kind, topic))
            self._log.warning(f"{topic}: {text} ({type(exc).__name__}: {exc}); counted as '{kind}', later ones on this topic are not logged")

    # ------------------------------------------------------------------ discovery

    def _wanted(self, topic: str) -> bool:
        if topic in self.requested:
            return True
        if self.watch_session_end and topic == T.SESSION_END:
            return True
        return self.all_topics and topic not in ALL_EXCLUDED

    def discover(self) -> None:
        """Subscribe to every wanted topic that has appeared in the graph (timer callback)."""
        if self._closed:
            return
        pending = [t for t in self.requested if t not in self._subs and t not in self.failed]
        if self.watch_session_end and T.SESSION_END not in self._subs:
            pending.append(T.SESSION_END)
        if not pending and not self.all_topics:
            return
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._subs or topic in self.failed or not self._wanted(topic):
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue  # only subscribers so far: wait for a publisher
            pub_types = list(dict.fromkeys(i.topic_type for i in infos)) or list(types)
            if len(pub_types) > 1:
                self._log.warning(f"{topic}: publishers of several types {pub_types}; recording {pub_types[0]}")
            self._subscribe(topic, pub_types[0], [i.qos_profile for i in infos])

    def _subscribe(self, topic: str, msgtype: str, offered: Sequence[QoSProfile]) -> None:
        record = topic in self.requested or (self.all_topics and topic not in ALL_EXCLUDED)
        try:
            cls = message_class(msgtype)
        except (ImportError, AttributeError, ValueError, ModuleNotFoundError) as exc:
            self.failed[topic] = f"message type {msgtype} not available ({exc})"
            self._log.error(f"{topic}: cannot record: {self.failed[topic]}")
            return
        if record:
            if msgtype not in self._typestore.fielddefs:
                self.failed[topic] = f"message type {msgtype} unknown to the rosbags typestore (ROS2_JAZZY)"
                self._log.error(f"{topic}: cannot record: {self.failed[topic]}")
                return
            qos_list = []
            for p in offered:
                try:
                    qos_list.append(_rosbags_qos(p))
                except (AttributeError, TypeError, ValueError) as exc:  # an rclpy profile rosbags cannot express
                    self._problem("offered_qos", topic, "a publisher's QoS profile is not stored in the bag metadata "
                                  "(dpos-play cannot restore it); recording anyway", exc)
            self.types[topic] = msgtype
            self.counts[topic] = 0
            self.received[topic] = 0
            self._queue.put(("connection", topic, msgtype, tuple(qos_list)))
        qos = subscription_qos(topic, offered)

        def on_message(raw: bytes, info: Any, topic: str = topic, record: bool = record) -> None:
            now = time.monotonic()
            self.last_receive = now
            if record:
                t = 0
                if isinstance(info, Mapping):
                    t = int(info.get("received_timestamp") or 0)
                if t <= 0:
                    t = time.time_ns()
                last = self._last_t.get(topic, 0)
                if t < last:
                    t = last
                self._last_t[topic] = t
                self.received[topic] += 1
                self._queue.put((topic, t, raw))
            if topic == T.SESSION_END and not self.session_ended.is_set():
                self.session_end_at = now
                self.session_ended.set()

        def callback(raw: bytes, info: Any) -> None:
            on_message(raw, info)
            # take what else is waiting on this subscription at once: one executor dispatch per
            # batch instead of per message (the executor's overhead dominates a raw recorder)
            if self._closed:
                return
            batch = []
            try:
                batch = take_waiting(sub, cls, True)
            except RuntimeError as exc:  # rclpy's InvalidHandle / RCLError: being destroyed (shutdown); the executor takes the rest
                self._problem("take", topic, "taking the waiting samples failed; the executor delivers them", exc)
            for raw_i, info_i in batch:  # outside the try: a failure here is a bug and propagates
                on_message(raw_i, info_i)

        sub = self.node.create_subscription(cls, topic, callback, qos, raw=True)
        self._subs[topic] = sub
        what = "recording" if record else "watching"
        latched = ", transient local" if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL else ""
        self._log.info(f"{what} {topic} ({msgtype}{latched})")

    def missing(self) -> list[str]:
        """Requested topics without a subscription (no publisher seen, or an unusable type)."""
        out = [t for t in self.requested if t not in self._subs]
        if self.watch_session_end and T.SESSION_END not in self._subs and T.SESSION_END not in out:
            out.append(T.SESSION_END)
        return out

    # ------------------------------------------------------------------ writing

    def _write_loop(self) -> None:
        w = self._writer
        conns: dict[str, Any] = {}
        q = self._queue
        warned = False
        while True:
            item = q.get()
            if item is None:
                return
            if self.error is not None:
                continue  # keep draining so that callbacks never block; the error is reported
            try:
                if item[0] == "connection":
                    _, topic, msgtype, qos_list = item
                    conns[topic] = w.add_connection(topic, msgtype, typestore=self._typestore, offered_qos_profiles=qos_list)
                    continue
                topic, t, raw = item
                w.write(conns[topic], t, raw)
                self.counts[topic] += 1
                if not warned and q.qsize() > BACKLOG_WARN:
                    warned = True
                    self._log.warning(f"writer backlog of {q.qsize()} messages (the disk or compression is slow)")
            except BaseException as exc:  # noqa: BLE001 - reported by close()
                self.error = exc
                self._log.error(f"writing {self.out} failed: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        """Stop subscribing, write what is queued and close the bag (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.node.destroy_timer(self._timer)
        except RuntimeError as exc:  # rclpy's InvalidHandle: the node may already be gone
            self._problem("destroy", "discovery timer", "could not be destroyed at close", exc)
        for topic, sub in self._subs.items():
            try:
                self.node.destroy_subscription(sub)
            except RuntimeError as exc:  # rclpy's InvalidHandle
                self._problem("destroy", topic, "subscription could not be destroyed at close", exc)
        self._queue.put(None)
        self._thread.join()
        self._writer.close()
        if self.error is not None:
            raise RuntimeError(f"writing {self.out} failed: {self.error}") from self.error
