"""Live simulated device: publish a device's :class:`~dpos_ros.devices.sim_streams.TopicStream` s on DDS.

A ``device: sim`` node (pos_master_node, pos_sub_node) hands its streams to :class:`SimDevice`,
which creates one publisher per topic and publishes every message **byte for byte** as
``stream.message(i)`` (serialized CDR, ``publisher.publish(bytes)``), so that a live session
carries exactly the samples that ``dpos-sim`` writes to a bag.

Order and pacing
    Streams with ``qos == 'datum'`` (the latched ``/dpos/datum``, TRANSIENT_LOCAL) are published
    first, at once, before any waiting: late joiners get them anyway. All other messages follow in
    :func:`~dpos_ros.devices.sim_streams.merged_order` (by stamp; ``/session/end`` last). With
    ``rate_factor > 0`` the message with stamp ``t`` is published when
    ``(now - wall_start) * rate_factor >= t - t_first``, ``now`` read from the node's clock
    (``wall_start`` = when publishing starts; with ``use_sim_time`` the node's clock follows
    ``/clock``, and pacing stops while no clock is published). ``rate_factor == 0`` publishes as
    fast as the subscribers keep up (see flow control).

Why a dedicated publishing thread and not an executor timer
    Flow control has to *block* in ``Publisher.wait_for_all_acked`` until reliable subscribers
    acknowledge a batch. Doing that in a timer callback would stall the executor the node spins
    in - and with it any subscription in the same executor (the in-process tests, a composed
    graph), which could then never acknowledge: a deadlock. A timer would also quantise the
    real-time pacing to its period and compete with the node's own callbacks. The thread only
    publishes (rclpy publishers are thread-safe) and sleeps on an Event, so :meth:`SimDevice.stop`
    ends it within ``POLL_S``; the executor stays free for parameter services and other callbacks.
    The streams themselves are generated in the thread too (a few seconds for a whole scenario),
    so the node is up and answering at once.

Flow control (never overrun the KEEP_LAST history)
    A reliable KEEP_LAST writer overwrites its oldest sample when its history is full, whether or
    not the subscribers have acknowledged it. So before a message would make a topic's unacknowledged
    count exceed its writer depth, the thread waits (``Publisher.wait_for_all_acked``) until every
    matched reliable subscription has acknowledged that topic: nothing unacknowledged is ever
    overwritten, in any mode; with ``rate_factor`` 0 this is what "as fast as subscribers keep up"
    means. Before ``/session/end`` every topic is waited for, so that a subscriber receives the end
    of the session after the last sample of every topic.

    The writers use the stream's QoS (``dpos_ros.contract.qos``: RELIABLE, VOLATILE) with a shallower depth
    (:func:`writer_depths`): ``FLOW_WINDOW`` = 100 messages shared among the topics in proportion to
    their message counts (>= 1 each, preferably a divisor of the count). Two Fast DDS behaviours
    set this (both measured here):

    - readers acknowledge only on a writer heartbeat. Fast DDS piggybacks one on every sample sent
      while the writer's history is full, otherwise only every ~200 kB (send-buffer size) or every
      3 s (heartbeat period); a VOLATILE writer drops samples from its history once they are
      acknowledged. So the device waits exactly when a topic's history is full (``depth``
      unacknowledged samples), and the acknowledgement takes milliseconds. With the design depth
      of 5000 each wait took up to 3 s (a 150 s master session, 45k messages, at rate 0 to a
      Python recorder in another process: ~60 s; now ~6 s). A last batch
      shorter than the depth may wait up to 3 s once at the end, hence depths that divide the
      message count where possible;
    - the shared-memory transport drops samples beyond its port queue (512 by default), and a
      dropped last sample is repaired only after the next periodic heartbeat (3 s). At most ~100-150
      unacknowledged messages per device keep three devices and a recorder below it.

    The subscribers' QoS (depth 5000) is the design's deep queue: unchanged; DDS matching does not
    depend on depths.

    Safety net: the device processes (console scripts) call :func:`use_device_fastdds_profile`
    before ``rclpy.init``: a Fast DDS XML default profile with a writer heartbeat period of
    ``HEARTBEAT_PERIOD_MS`` (20 ms instead of 3 s), so that a repair or a last short batch costs
    milliseconds, not seconds. (Measured: with three devices blasting into one recorder, a device
    otherwise stalled 3 s at a third of its waits.) Heartbeats are only sent while samples are
    unacknowledged, so an idle writer costs nothing. It is not applied when the user configures
    Fast DDS (``FASTRTPS_DEFAULT_PROFILES_FILE`` / ``FASTDDS_DEFAULT_PROFILES_FILE``, or a
    ``DEFAULT_FASTRTPS_PROFILES.xml`` in the working directory) or uses another RMW.

    An acknowledgement means the sample is in the subscriber's DDS history, not that its callback
    has run: a KEEP_LAST subscriber that falls behind by more than its depth still loses the oldest
    samples (a KEEP_ALL subscriber throttles the device instead). A wait is not bounded (a
    subscriber that disappears no longer counts), but is logged every ``ACK_WARN_S`` seconds and
    ends at :meth:`SimDevice.stop`.

Waiting for subscribers
    With ``min_subscribers > 0`` publishing starts only when every topic but the latched datum has
    at least that many matched subscriptions, or after ``wait_subscribers_s`` seconds (then with a
    WARNING naming the topics still short of subscribers). VOLATILE samples published before a
    subscription matched are never delivered to it; this makes a scripted graph deterministic
    (start the recorder/consumers, then the devices). ``min_subscribers == 0`` starts at once.
    Note that all topics count, ``/truth/*`` included: with ``publish_truth`` and nobody
    subscribing to truth, the wait runs out.

Taps (derived streams)
    A :class:`Tap` publishes messages computed from one of the device's streams by the device
    thread itself, e.g. pos_master_node's /master/nav mechanized from /master/imu. Before a source
    message is published for the first time, ``produce(stream, indices)`` gets it together with
    the following source messages that are already due (``rate_factor`` 0: the next
    ``max_batch``; > 0: those whose time has come, at most ``max_batch``), so that the work is
    batched; it returns, per source message, the derived messages (serialized) to publish right
    after it. The tap's writer gets the source's depth and the same flow control; before
    ``/session/end`` it is acknowledged too. Its subscribers are not waited for
    (``min_subscribers`` counts the device's own streams only). ``tap_published`` counts its
    messages (``published`` counts the streams' only).

Batches
    :class:`StreamBatches` publishes streams too long to hold (transfer_align_node's antenna
    poses of a long session) a batch at a time: the writers and their depths come from
    the streams' descriptions (topic, type, QoS, total count), the batches are generated in the
    thread as they are published, each in its merged order, the flow control across them as for
    whole streams: the same messages in the same order as the whole streams would be (the
    batches split the session in time).  No tap, no latched stream.

Progress is logged every ~10 % and at the end: ``published N messages on M topics in T s``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rclpy.duration import Duration
from rclpy.qos import QoSProfile

from dpos_ros.contract.qos import qos_profile
from dpos_ros.contract.topics import SESSION_END, message_class
from dpos_ros.io.flow import (
    ACK_POLL_S,
    ACK_WARN_S,
    POLL_S,
    use_device_fastdds_profile,
    writer_depths,
    writer_qos,
)
from dpos_ros.io.streams import TopicStream, merged_order

__all__ = ["SimDevice", "StreamBatches", "StreamInfo", "Tap", "use_device_fastdds_profile"]


@dataclass(frozen=True)
class Tap:
    """A stream derived from one of the device's streams (see "Taps" in the module docstring).

    Attributes:
        source: topic of the device stream that feeds it.
        topic, msgtype: of the derived messages; qos: a stream QoS kind (:func:`qos_profile`).
        produce: ``(source stream, message indices (B,)) -> B sequences of serialized messages``,
            called in the device thread before those source messages are published.
        max_batch: most source messages per call.
    """

    source: str
    topic: str
    msgtype: str
    produce: Callable[[TopicStream, NDArray[np.int64]], Sequence[Sequence[bytes]]]
    qos: str = "nav"
    max_batch: int = 100


@dataclass(frozen=True)
class StreamInfo:
    """What the writers need of a stream published in batches: its ``topic``, ``msgtype``, QoS
    kind ``qos`` (:func:`qos_profile`) and its message ``count`` over all batches (``len()``:
    the writer depths, :func:`writer_depths`)."""

    topic: str
    msgtype: str
    qos: str
    count: int

    def __len__(self) -> int:
        return self.count


@dataclass(frozen=True)
class StreamBatches:
    """Streams published a batch at a time (module docstring, "Batches"): ``topics`` describes
    the streams, ``batches()`` gives, in time order, lists of TopicStreams of those topics in
    that order, every message of a batch stamped before those of the next one."""

    topics: Sequence[StreamInfo]
    batches: Callable[[], Iterable[Sequence[TopicStream]]]


class SimDevice:
    """Publishes a device's streams from a background thread (see the module docstring).

    Args:
        node: the rclpy node that owns the publishers (and whose clock and logger are used).
        streams: the streams, or a callable that generates them (called in the thread), or
            :class:`StreamBatches` (module docstring, "Batches").
        rate_factor: 1.0 = real time, 10 = ten times faster, 0 = as fast as subscribers keep up.
        min_subscribers: matched subscriptions every non-latched topic needs before starting.
        wait_subscribers_s: longest wait for ``min_subscribers`` [s].
        on_finished: called in the thread once everything is published, with this object.
        taps: derived streams published by the thread (module docstring, "Taps").

    Attributes (read after :attr:`finished` is set): ``published`` (messages), ``topics``,
    ``elapsed_s``, ``error`` (an exception that ended the thread early, else None).
    """

    def __init__(
        self,
        node: Any,
        streams: Sequence[TopicStream] | Callable[[], Sequence[TopicStream]] | StreamBatches,
        rate_factor: float,
        *,
        min_subscribers: int = 0,
        wait_subscribers_s: float = 0.0,
        on_finished: Callable[[SimDevice], None] | None = None,
        taps: Sequence[Tap] = (),
    ) -> None:
        if not rate_factor >= 0.0:
            raise ValueError(f"rate_factor must be >= 0, got {rate_factor}")
        self._node = node
        self._streams_source = streams
        self.rate_factor = float(rate_factor)
        self.min_subscribers = int(min_subscribers)
        self.wait_subscribers_s = float(wait_subscribers_s)
        self._on_finished = on_finished
        self.taps = list(taps)
        #: messages published by the taps
        self.tap_published = 0
        self._log = node.get_logger()
        self._stop = threading.Event()
        #: set when every message is published (or the thread ended on an error)
        self.finished = threading.Event()
        #: set once the publishers exist
        self.started = threading.Event()
        self.streams: list[TopicStream] = []
        self.publishers: list[Any] = []
        self.published = 0
        self.topics = 0
        self.elapsed_s = 0.0
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=f"sim_device:{node.get_name()}", daemon=True)

    # ------------------------------------------------------------------ control

    def start(self) -> SimDevice:
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the thread to stop and join it (call before destroying the node)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    @property
    def stopping(self) -> bool:
        """:meth:`stop` was called."""
        return self._stop.is_set()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    # ------------------------------------------------------------------ thread

    def _run(self) -> None:
        try:
            self._publish_all()
        except BaseException as exc:  # noqa: BLE001 - reported, never raised out of the thread
            if self._stop.is_set() or not self._node.context.ok():
                return  # shutting down: a publish on a destroyed node/context is expected
            self.error = exc
            self._log.error(f"simulated device failed: {type(exc).__name__}: {exc}")
        finally:
            self.finished.set()

    def _now_ns(self) -> int:
        return self._node.get_clock().now().nanoseconds

    def _publish_all(self) -> None:
        source = self._streams_source
        batches: Iterable[Sequence[TopicStream]]
        heads: list[Any]
        if isinstance(source, StreamBatches):
            heads = list(source.topics)
            if self.taps or any(h.qos == "datum" for h in heads):
                raise ValueError("streams in batches take no tap and no latched stream")
            batches = source.batches()  # (generated as they are published)
        else:
            streams = list(source() if callable(source) else source)
            heads = streams
            batches = [streams]
        topics = [s.topic for s in heads]
        if len(set(topics)) != len(topics):
            raise ValueError(f"duplicate topics in the device streams: {topics}")
        if self._stop.is_set():
            return
        self.streams = heads
        self.topics = len(heads)
        depth = writer_depths(heads)
        self.publishers = [
            self._node.create_publisher(message_class(s.msgtype), s.topic, writer_qos(s, d)) for s, d in zip(heads, depth)
        ]
        # taps: one writer each after the streams' (index len(streams) + j), the source's depth
        tap_source: dict[int, int] = {}  # stream index -> tap index
        for j, tap in enumerate(self.taps):
            if tap.source not in topics:
                raise ValueError(f"tap {tap.topic}: no device stream {tap.source!r}")
            src = topics.index(tap.source)
            if src in tap_source:
                raise ValueError(f"more than one tap on {tap.source}")
            tap_source[src] = j
            p = qos_profile(tap.qos)
            d = depth[src]
            depth.append(d)
            self.publishers.append(self._node.create_publisher(
                message_class(tap.msgtype), tap.topic,
                QoSProfile(history=p.history, depth=d, reliability=p.reliability, durability=p.durability)))
        self._pub_topics = topics + [t.topic for t in self.taps]
        self.started.set()
        t0_wall = time.monotonic()

        latched = [i for i, s in enumerate(heads) if s.qos == "datum"]
        for i in latched:  # (whole streams only)
            for k in range(len(heads[i])):
                self.publishers[i].publish(heads[i].message(k))
                self.published += 1
        if not self._wait_for_subscribers([i for i in range(len(heads)) if i not in latched]):
            return

        n = sum(len(h) for i, h in enumerate(heads) if i not in latched)
        unacked = [0] * len(self.publishers)
        tap_out: dict[int, dict[int, Sequence[bytes]]] = {i: {} for i in tap_source}  # derived messages per source message
        tap_next = {i: 0 for i in tap_source}  # first source message not handed to produce yet
        end_index = {i for i, s in enumerate(heads) if s.topic == SESSION_END}
        rate = self.rate_factor
        t_first: int | None = None
        wall_start = self._now_ns()
        now_rel = 0.0  # (now - wall_start) * rate, in stamp ns; refreshed only when needed
        next_report = 1
        self._log.info(
            f"publishing {n} messages on {len(heads) - len(latched)} topics "
            f"({'as fast as subscribers keep up' if rate == 0 else f'rate_factor {rate:g}'})"
        )
        k_all = 0  # messages published of the batches so far
        for batch in batches:
            if [s.topic for s in batch] != topics:
                raise ValueError(f"a batch has the topics {[s.topic for s in batch]}, not {topics}")
            t_all, si_all, mi_all = merged_order(list(batch))
            keep = ~np.isin(si_all, latched)
            t_all, si_all, mi_all = t_all[keep], si_all[keep], mi_all[keep]
            if t_first is None and len(t_all):
                t_first = int(t_all[0])
            t_ref = t_first or 0
            for k in range(len(t_all)):
                if self._stop.is_set():
                    return
                i = int(si_all[k])
                if rate > 0.0:
                    due = int(t_all[k]) - t_ref
                    while now_rel < due:
                        now_rel = (self._now_ns() - wall_start) * rate
                        if now_rel < due:
                            wait_s = min((due - now_rel) / rate * 1e-9, POLL_S)
                            if self._stop.wait(wait_s):
                                return
                m = int(mi_all[k])
                if i in tap_source and m >= tap_next[i]:
                    tap = self.taps[tap_source[i]]
                    fed = batch[i]
                    hi = min(len(fed), m + max(1, tap.max_batch))
                    if rate > 0.0:  # only what is due now (at least this message)
                        due_until = t_ref + now_rel
                        hi = max(m + 1, min(hi, int(np.searchsorted(fed.t_ns, due_until, side="right"))))
                    idx = np.arange(m, hi)
                    out = tap.produce(fed, idx)
                    if len(out) != idx.size:
                        raise ValueError(f"tap {tap.topic}: produce returned {len(out)} entries for {idx.size} messages")
                    tap_out[i].update(zip(idx.tolist(), out))
                    tap_next[i] = hi
                if i in end_index:
                    if not self._wait_acked(range(len(self.publishers)), unacked):
                        return
                elif unacked[i] >= depth[i] and not self._wait_acked([i], unacked):
                    return
                self.publishers[i].publish(batch[i].message(m))
                self.published += 1
                unacked[i] += 1
                if i in tap_source:
                    jt = len(heads) + tap_source[i]
                    for raw in tap_out[i].pop(m, ()):
                        if unacked[jt] >= depth[jt] and not self._wait_acked([jt], unacked):
                            return
                        self.publishers[jt].publish(raw)
                        self.tap_published += 1
                        unacked[jt] += 1
                k_all += 1
                tenth = k_all * 10 // n
                if tenth >= next_report and k_all < n:
                    self._log.info(
                        f"{tenth * 10}% published ({k_all}/{n} messages, stamp "
                        f"+{(int(t_all[k]) - t_ref) * 1e-9:.1f} s, after {time.monotonic() - t0_wall:.1f} s)"
                    )
                    next_report = tenth + 1
        if not self._wait_acked(range(len(self.publishers)), unacked):
            return
        self.elapsed_s = time.monotonic() - t0_wall
        self._log.info(f"published {self.published} messages on {len(heads)} topics in {self.elapsed_s:.1f} s")
        if self._on_finished is not None:
            self._on_finished(self)

    def _wait_for_subscribers(self, indices: list[int]) -> bool:
        """Wait (bounded) until ``min_subscribers`` per topic; False when stopped."""
        need = self.min_subscribers
        if need <= 0 or not indices:
            return True

        def short() -> list[str]:
            return [self.streams[i].topic for i in indices if self.publishers[i].get_subscription_count() < need]

        missing = short()
        if not missing:
            return True
        self._log.info(
            f"waiting up to {self.wait_subscribers_s:g} s for {need} subscriber(s) on each of "
            f"{len(indices)} topics (missing on {', '.join(missing)})"
        )
        deadline = time.monotonic() + self.wait_subscribers_s
        while missing:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._log.warning(
                    f"starting after {self.wait_subscribers_s:g} s without {need} subscriber(s) on "
                    f"{', '.join(missing)}: their subscribers miss what is published before they match"
                )
                return True
            if self._stop.wait(min(POLL_S, remaining)):
                return False
            missing = short()
        self._log.info("subscribers matched, starting")
        return True

    def _wait_acked(self, indices: Sequence[int] | range, unacked: list[int]) -> bool:
        """Wait until the reliable subscribers acknowledged everything on ``indices``; False when stopped."""
        for i in indices:
            if unacked[i] == 0:
                continue
            publisher = self.publishers[i]
            t_start = time.monotonic()
            next_warn = ACK_WARN_S
            # poll: rclpy holds the GIL inside wait_for_all_acked, so a blocking wait would starve
            # every other Python thread of the process (the executor whose subscriptions must take
            # the samples of a KEEP_ALL reader before it acknowledges more); Event.wait releases it
            while not publisher.wait_for_all_acked(Duration(nanoseconds=0)):
                if self._stop.wait(ACK_POLL_S):
                    return False
                waited = time.monotonic() - t_start
                if waited >= next_warn:
                    next_warn += ACK_WARN_S
                    self._log.warning(
                        f"{self._pub_topics[i]}: subscribers have not acknowledged "
                        f"{unacked[i]} messages for {waited:.0f} s; waiting (flow control)"
                    )
            unacked[i] = 0
        return not self._stop.is_set()
