"""Replay a rosbag2 on DDS byte for byte: the library of ``dpos-play``.

:class:`BagPlayer` reads a bag with rosbags (``AnyReader``, MCAP or SQLite, messages streamed in
log-time order, so memory stays bounded) and publishes every message's serialized bytes unchanged
(``publisher.publish(bytes)``) on a publisher of the recorded type.

Timing
    ``rate`` > 0: the message with log time ``t`` is published when
    ``(monotonic - wall_start) * rate >= t - t_first`` (1.0 = as recorded). ``rate`` 0: as fast as
    the subscribers keep up (flow control below). For a ``dpos-sim`` bag the log time is the header
    stamp; for a ``dpos-record`` bag the receive time.

/clock (``clock=True``)
    ``rosgraph_msgs/Clock`` with the bag's log time, so that nodes with ``use_sim_time`` follow
    the bag: before the first message, then at most ``clock_hz`` times per wall second, always
    before the message whose time it carries (while waiting for the next message at ``rate`` > 0
    it advances with the scaled wall time), and the last log time at the end. QoS as rclcpp's
    ``ClockQoS`` (BEST_EFFORT, KEEP_LAST 1), what the time sources of rclpy/rclcpp subscribe with.
    A ``/clock`` topic in the bag is not replayed while the player publishes its own.

QoS
    ``/dpos/datum`` and ``*/status`` - and any topic whose recorded publishers offered
    TRANSIENT_LOCAL (bag metadata) - are latched: RELIABLE, TRANSIENT_LOCAL, the design's depth
    (1 for the datum, 10 for status). Everything else RELIABLE, VOLATILE, KEEP_LAST with the
    shallow depths of :func:`dpos_ros.devices.sim_device.writer_depths`: ``flow_window`` messages
    (``PLAY_FLOW_WINDOW`` = 1000, ten times a device's window: one player feeds the whole graph)
    shared in proportion to the topics' message counts.

Flow control (as :mod:`dpos_ros.devices.sim_device`, whose docstring explains the Fast DDS behaviour)
    Before a message would make a topic's unacknowledged count exceed its writer depth, the player
    waits (``wait_for_all_acked``) until every matched reliable subscription acknowledged that
    topic; before ``/session/end`` every topic is waited for, and at the end everything is
    acknowledged before :meth:`BagPlayer.run` returns. With ``rate`` 0 this is what "as fast as
    subscribers keep up, no loss" means. The CLI applies the device nodes' Fast DDS profile
    (:func:`~dpos_ros.devices.sim_device.use_device_fastdds_profile`, 20 ms writer heartbeat) so that
    acknowledgements are prompt. Measured on 2 cores, 300 s paired paper_su bag (270k messages)
    into ``dpos-record`` in another process, lossless in every case: window 100: 3.2k msg/s,
    1000: 18k msg/s, 3000: 31k msg/s (the window exceeds the shared-memory port queue of 512;
    the dropped samples are repaired after a 20 ms heartbeat).

Waiting for subscribers
    With ``min_subscribers`` > 0 publishing starts when every played non-latched topic has that
    many matched subscriptions, or after ``wait_subscribers_s`` (then with a warning naming the
    topics short of subscribers). Latched topics are not waited for at the start; at the end the
    player waits (for at most ``wait_subscribers_s`` more) until they too have ``min_subscribers``
    and have been acknowledged, so that a subscriber that matched them late still gets them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.duration import Duration
from rclpy.exceptions import InvalidTopicNameException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader

from dpos_core.errors import BagError
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import qos_profile
from dpos_ros.contract.topics import message_class
from dpos_ros.io.bag import readable_bag, typestore
from dpos_ros.io.flow import ACK_WARN_S, POLL_S, writer_depths

__all__ = ["BagPlayer", "BagError", "PlayTopic", "CLOCK_TOPIC", "CLOCK_QOS", "open_bag"]

CLOCK_TOPIC = "/clock"
#: Default unacknowledged messages over all non-latched topics (see "Flow control").
PLAY_FLOW_WINDOW = 1000
#: rclcpp::ClockQoS(): what the ROS time sources subscribe /clock with.
CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE
)


@dataclass
class PlayTopic:
    """One topic to replay. ``qos``: ``sensor`` or a latched kind (``datum``, ``status``);
    ``len()`` is the message count (as :func:`~dpos_ros.devices.sim_device.writer_depths` expects)."""

    topic: str
    msgtype: str
    count: int
    qos: str

    def __len__(self) -> int:
        return self.count

    @property
    def latched(self) -> bool:
        return self.qos in ("datum", "status")


def _describe(path: Path, exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if str(path) in text else f"{path}: {text}"


def _data_files(path: Path) -> str:
    files = sorted(p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3")) if path.is_dir() else []
    return ", ".join(str(path / f) for f in files) or str(path)


def open_bag(path: Path, log: Callable[[str], None] | None = None) -> Any:
    """An opened rosbags ``AnyReader`` of the bag directory ``path`` (a bag's .mcap/.db3 file or
    metadata.yaml stand for its directory); :class:`BagError` naming the path when unreadable. A bag
    without metadata (a recorder that was killed) is recovered first and ``log`` told so
    (:func:`dpos_ros.io.bag.readable_bag`)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag (a rosbag2 directory)")
    if path.is_file() and (path.parent / "metadata.yaml").is_file():
        path = path.parent
    problem = _not_a_bag(path)
    if problem is not None:
        raise BagError(problem)
    try:
        path, note = readable_bag(path, verify=True)  # (rosbags checks no CRC: a bad chunk is skipped in a recovery)
    except (ValueError, OSError) as exc:
        raise BagError(f"cannot read bag {_data_files(path)}: {exc}") from exc
    if note is not None and log is not None:
        log(note)
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds; all mean "unreadable"
        raise BagError(f"cannot read bag {_data_files(path)}: {_describe(path, exc)}") from exc
    return reader


def _not_a_bag(path: Path) -> str | None:
    """Why ``path`` (which exists) cannot be a rosbag2 at all, or None when it may be one: a file
    that is not a bag's .mcap/.db3, a directory without metadata.yaml and without any data file."""
    if path.is_file():
        if path.suffix in (".mcap", ".db3"):
            return None
        return f"{path}: not a rosbag2 (a bag is a directory with metadata.yaml and .mcap or .db3 files)"
    if not path.is_dir():
        return f"{path}: not a rosbag2 (neither a directory nor a file)"
    try:
        names = [p.name for p in path.iterdir()]
    except OSError as exc:
        return f"{path}: cannot list the directory: {exc.strerror or exc}"
    if "metadata.yaml" in names or any(n.endswith((".mcap", ".db3")) for n in names):
        return None
    what = "it is empty" if not names else "no metadata.yaml and no .mcap or .db3 file in it"
    return f"{path}: not a rosbag2 directory ({what})"


@dataclass(frozen=True)
class PlayOptions:
    """How :class:`BagPlayer` plays a bag (dpos-play's options).

    Attributes:
        rate: 1.0 = as recorded, 10 = ten times faster, 0 = as fast as subscribers keep up.
        topics: play only these (None = all); a topic that is not in the bag is a :class:`BagError`.
        clock: publish /clock with the bag's log time.
        clock_hz: most /clock messages per wall second.
        min_subscribers, wait_subscribers_s: see "Waiting for subscribers".
        flow_window: unacknowledged messages over all non-latched topics (see "Flow control").
    """

    rate: float = 1.0
    topics: tuple[str, ...] | None = None
    clock: bool = True
    clock_hz: float = 100.0
    min_subscribers: int = 0
    wait_subscribers_s: float = 30.0
    flow_window: int = PLAY_FLOW_WINDOW

    def __post_init__(self) -> None:
        if not self.rate >= 0.0:
            raise ValueError(f"rate must be >= 0, got {self.rate}")
        if not self.clock_hz > 0.0:
            raise ValueError(f"clock_hz must be > 0, got {self.clock_hz}")


class BagPlayer:
    """Publishes a bag on ``node``'s publishers (module docstring); call :meth:`run` once.

    Args:
        node: the rclpy node that owns the publishers. It need not be spun.
        bag: the rosbag2 directory.
        options: :class:`PlayOptions`.
        log: progress reporting (default: the node's logger at INFO).

    Attributes after :meth:`run`: ``published`` (bag messages), ``clock_published``,
    ``per_topic`` (messages per topic), ``elapsed_s`` (from the first message), ``first_ns`` /
    ``last_ns`` (log times).
    """

    def __init__(self, node: Any, bag: Path, options: PlayOptions = PlayOptions(), *,
                 log: Callable[[str], None] | None = None) -> None:
        self.node = node
        self.bag = Path(bag)
        self.rate = float(options.rate)
        self.clock = bool(options.clock)
        self.clock_period_s = 1.0 / float(options.clock_hz)
        self.min_subscribers = int(options.min_subscribers)
        self.flow_window = max(1, int(options.flow_window))
        self.wait_subscribers_s = float(options.wait_subscribers_s)
        self._logger = node.get_logger()
        self._log = log or self._logger.info
        self._stop = threading.Event()
        self.reader = open_bag(self.bag, self._logger.warning)
        try:
            self._setup(None if options.topics is None else list(options.topics))
        except BaseException:
            self.reader.close()
            raise
        self.published = 0
        self.clock_published = 0
        self.per_topic = {t.topic: 0 for t in self.topics}
        self.elapsed_s = 0.0
        self.first_ns = 0
        self.last_ns = 0

    # ------------------------------------------------------------------ setup

    def _setup(self, wanted: list[str] | None) -> None:
        conns = list(self.reader.connections)
        in_bag = list(dict.fromkeys(c.topic for c in conns))
        if wanted is not None:
            unknown = [t for t in wanted if t not in in_bag]
            if unknown:
                raise BagError(f"{self.bag}: topics not in the bag: {', '.join(unknown)} (it has {', '.join(in_bag)})")
        by_topic: dict[str, PlayTopic] = {}
        for c in conns:
            if wanted is not None and c.topic not in wanted:
                continue
            if self.clock and c.topic == CLOCK_TOPIC:
                self._logger.warning(f"{self.bag}: not replaying the recorded {CLOCK_TOPIC} (the player publishes its own; --no-clock replays it)")
                continue
            t = by_topic.get(c.topic)
            if t is not None:
                if t.msgtype != c.msgtype:
                    raise BagError(f"{self.bag}: topic {c.topic} has several types ({t.msgtype}, {c.msgtype})")
                t.count += int(c.msgcount)
                continue
            kind = T.qos_kind(c.topic)
            offered = getattr(getattr(c, "ext", None), "offered_qos_profiles", None) or ()
            if kind == "sensor" and any(getattr(getattr(q, "durability", None), "name", "") == "TRANSIENT_LOCAL" for q in offered):
                kind = "status"
            by_topic[c.topic] = PlayTopic(c.topic, c.msgtype, int(c.msgcount), kind)
        self.topics: list[PlayTopic] = list(by_topic.values())
        self.connections = [c for c in conns if c.topic in by_topic]
        self.total = sum(t.count for t in self.topics)
        self.index = {t.topic: i for i, t in enumerate(self.topics)}
        self.depths = writer_depths(self.topics, self.flow_window)
        self.publishers: list[Any] = []
        for t, depth in zip(self.topics, self.depths):
            try:
                cls = message_class(t.msgtype)
            except (ImportError, AttributeError, ValueError) as exc:
                raise BagError(f"{self.bag}: topic {t.topic}: message type {t.msgtype} not available ({exc})") from exc
            p = qos_profile(t.qos)
            qos = QoSProfile(history=p.history, depth=p.depth if t.latched else depth,
                             reliability=p.reliability, durability=p.durability)
            try:
                self.publishers.append(self.node.create_publisher(cls, t.topic, qos))
            except (InvalidTopicNameException, ValueError) as exc:  # a name rcl refuses (a space, a leading digit, ...)
                raise BagError(f"{self.bag}: topic {t.topic!r} is not a valid ROS topic name "
                               f"({' '.join(str(exc).split())[:200]}); play the others with --topics") from None
        self.clock_publisher = None
        if self.clock:
            from rosgraph_msgs.msg import Clock

            self._clock_cls = Clock
            self.clock_publisher = self.node.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS)

    # ------------------------------------------------------------------ control

    def stop(self) -> None:
        """Ask :meth:`run` (in another thread) to return soon."""
        self._stop.set()

    def close(self) -> None:
        self.reader.close()

    def _publish_clock(self, t_ns: int) -> None:
        msg = self._clock_cls()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        assert self.clock_publisher is not None  # called only when /clock is published
        self.clock_publisher.publish(msg)
        self.clock_published += 1

    # ------------------------------------------------------------------ playing

    def run(self) -> bool:
        """Publish the bag; True when everything was published and acknowledged, False when
        stopped. Raises :class:`BagError` when the bag turns out unreadable midway."""
        topics = self.topics
        n_topics = len(topics)
        latched = [i for i, t in enumerate(topics) if t.latched]
        others = [i for i in range(n_topics) if i not in latched]
        if not self._wait_for_subscribers(others, self.wait_subscribers_s):
            return False
        unacked = [0] * n_topics
        end_index = self.index.get(T.SESSION_END)
        rate = self.rate
        clock = self.clock_publisher is not None
        total = self.total
        self._log(
            f"playing {total} messages on {n_topics} topics from {self.bag} "
            f"({'as fast as subscribers keep up' if rate == 0 else f'rate {rate:g}'}"
            f"{', publishing /clock' if clock else ''})"
        )
        t_first = None
        wall_start = time.monotonic()
        last_clock_wall = -1e9
        next_report = 1
        k = 0
        index = self.index
        pubs = self.publishers
        depths = self.depths
        per_topic = self.per_topic
        try:
            messages = self.reader.messages(connections=self.connections)
            for conn, t_ns, raw in messages:
                if self._stop.is_set():
                    return False
                i = index[conn.topic]
                if t_first is None:
                    t_first = t_ns
                    self.first_ns = t_ns
                    wall_start = time.monotonic()
                if rate > 0.0:
                    due_s = (t_ns - t_first) * 1e-9 / rate
                    while True:
                        now = time.monotonic()
                        ahead = due_s - (now - wall_start)
                        if ahead <= 0:
                            break
                        if clock and now - last_clock_wall >= self.clock_period_s:
                            self._publish_clock(t_first + int((now - wall_start) * rate * 1e9))
                            last_clock_wall = now
                        wait = min(ahead, POLL_S, self.clock_period_s if clock else POLL_S)
                        if self._stop.wait(wait):
                            return False
                if clock:
                    now = time.monotonic()
                    if now - last_clock_wall >= self.clock_period_s:
                        self._publish_clock(t_ns)
                        last_clock_wall = now
                if i == end_index:
                    if not self._wait_acked(range(n_topics), unacked):
                        return False
                elif unacked[i] >= depths[i] and not self._wait_acked((i,), unacked):
                    return False
                pubs[i].publish(raw)
                unacked[i] += 1
                per_topic[conn.topic] += 1
                k += 1
                self.last_ns = t_ns
                tenth = k * 10 // max(total, 1)
                if tenth >= next_report and k < total:
                    self._log(f"{tenth * 10}% played ({k}/{total} messages, log time +{(t_ns - t_first) * 1e-9:.1f} s, "
                              f"after {time.monotonic() - wall_start:.1f} s)")
                    next_report = tenth + 1
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - a corrupt chunk, a short file, ...
            if self._stop.is_set():
                return False
            raise BagError(f"reading bag {_data_files(self.bag)} failed after {k} messages: {_describe(self.bag, exc)}") from exc
        finally:
            self.published = k
        if clock and k:
            self._publish_clock(self.last_ns)
        if not self._wait_acked(range(n_topics), unacked):
            return False
        if latched and self.min_subscribers > 0:
            # a subscriber that matched a latched topic late gets it from the writer's history
            if not self._wait_for_subscribers(latched, self.wait_subscribers_s):
                return False
            if not self._wait_acked(latched, [1] * n_topics):
                return False
        self.elapsed_s = time.monotonic() - wall_start
        return True

    def _wait_for_subscribers(self, indices: Sequence[int], timeout_s: float) -> bool:
        """Wait (bounded) until ``min_subscribers`` per topic; False when stopped."""
        need = self.min_subscribers
        if need <= 0 or not indices:
            return True

        def short() -> list[str]:
            return [self.topics[i].topic for i in indices if self.publishers[i].get_subscription_count() < need]

        missing = short()
        if not missing:
            return True
        self._log(f"waiting up to {timeout_s:g} s for {need} subscriber(s) on each of {len(indices)} topics "
                  f"(missing on {', '.join(missing)})")
        deadline = time.monotonic() + timeout_s
        while missing:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._logger.warning(
                    f"going on after {timeout_s:g} s without {need} subscriber(s) on {', '.join(missing)}: "
                    "their subscribers miss what is published before they match")
                return True
            if self._stop.wait(min(POLL_S, remaining)):
                return False
            missing = short()
        self._log("subscribers matched")
        return True

    def _wait_acked(self, indices: Iterable[int], unacked: list[int]) -> bool:
        """Wait until the reliable subscribers acknowledged everything on ``indices``; False when stopped."""
        for i in indices:
            if unacked[i] == 0:
                continue
            publisher = self.publishers[i]
            waited = 0.0
            while not publisher.wait_for_all_acked(Duration(nanoseconds=int(0.5e9))):
                if self._stop.is_set():
                    return False
                waited += 0.5
                if waited % ACK_WARN_S == 0:
                    self._logger.warning(f"{self.topics[i].topic}: subscribers have not acknowledged {unacked[i]} "
                                         f"messages for {waited:.0f} s; waiting (flow control)")
            unacked[i] = 0
        return not self._stop.is_set()
