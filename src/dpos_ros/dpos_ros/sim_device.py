"""Live simulated device: publish a device's :class:`~dpos_ros.sim_streams.TopicStream` s on DDS.

A ``device: sim`` node (pos_master_node, pos_sub_node) hands its streams to :class:`SimDevice`,
which creates one publisher per topic and publishes every message **byte for byte** as
``stream.message(i)`` (serialized CDR, ``publisher.publish(bytes)``), so that a live session
carries exactly the samples that ``dpos-sim`` writes to a bag.

Order and pacing
    Streams with ``qos == 'datum'`` (the latched ``/dpos/datum``, TRANSIENT_LOCAL) are published
    first, at once, before any waiting: late joiners get them anyway. All other messages follow in
    :func:`~dpos_ros.sim_streams.merged_order` (by stamp; ``/session/end`` last). With
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
    Per publisher, after at most ``batch`` messages (``depth // 4`` of its QoS, 1250 with the
    default depth 5000) the thread waits until every matched reliable subscription has
    acknowledged them before it publishes more on that topic; with ``rate_factor`` 1 the wait
    returns at once, with 0 it is what "as fast as subscribers keep up" means. Before
    ``/session/end`` every topic is waited for, so that a subscriber receives the end of the
    session after the last sample of every topic. An acknowledgement means the sample is in the
    subscriber's DDS history (depth 5000, i.e. four batches of headroom), not that its callback
    has run: a subscriber that stops taking samples for longer than that still loses the oldest.
    A wait is not bounded (a subscriber that disappears no longer counts), but is logged every
    ``ACK_WARN_S`` seconds and ends at :meth:`SimDevice.stop`.

Waiting for subscribers
    With ``min_subscribers > 0`` publishing starts only when every topic but the latched datum has
    at least that many matched subscriptions, or after ``wait_subscribers_s`` seconds (then with a
    WARNING naming the topics still short of subscribers). VOLATILE samples published before a
    subscription matched are never delivered to it; this makes a scripted graph deterministic
    (start the recorder/consumers, then the devices). ``min_subscribers == 0`` starts at once.
    Note that all topics count, ``/truth/*`` included: with ``publish_truth`` and nobody
    subscribing to truth, the wait runs out.

Progress is logged every ~10 % and at the end: ``published N messages on M topics in T s``.
"""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from rclpy.duration import Duration
from rclpy.qos import QoSProfile

from . import qos as dpos_qos
from .sim_streams import TopicStream, merged_order

__all__ = ["SimDevice", "message_class", "qos_profile", "load_sim_session", "END_TOPIC"]

#: The topic that ends a session; everything else is acknowledged before it is published.
END_TOPIC = "/session/end"
#: Longest sleep of the publishing thread between two checks of the stop flag [s].
POLL_S = 0.05
#: A flow-control wait is logged after this many seconds, and again every as many.
ACK_WARN_S = 10.0

_QOS = {
    "sensor": dpos_qos.SENSOR_QOS,
    "nav": dpos_qos.NAV_QOS,
    "datum": dpos_qos.DATUM_QOS,
    "status": dpos_qos.STATUS_QOS,
}


def qos_profile(kind: str) -> QoSProfile:
    """The QoS profile of a stream's ``qos`` kind (``sensor``, ``nav``, ``datum``, ``status``)."""
    try:
        return _QOS[kind]
    except KeyError:
        raise ValueError(f"unknown stream QoS kind {kind!r}; known: {sorted(_QOS)}") from None


def message_class(msgtype: str) -> type:
    """The Python message class of ``pkg/msg/Name`` (rosidl_runtime_py when installed)."""
    try:
        from rosidl_runtime_py.utilities import get_message
    except ImportError:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    return get_message(msgtype)


def load_sim_session(scenario: str, aircraft_config: str, seed: int, duration_s: float) -> Any:
    """The :class:`~dpos_core.sim.session.SimulatedSession` of a device node's parameters.

    ``aircraft_config`` '' = the scenario's own aircraft; ``duration_s`` 0 = the whole scenario.
    Cheap: samples are generated lazily. Raises :class:`~dpos_ros.params.ParameterError` naming
    the parameter (``scenario``, ``aircraft_config``, ``duration`` or ``seed``).
    """
    from dpos_core.sim.scenario import ConfigError, load_aircraft, load_scenario
    from dpos_core.sim.session import SimulatedSession

    from .params import ParameterError

    if aircraft_config:
        try:
            load_aircraft(aircraft_config)
        except ConfigError as exc:
            raise ParameterError("aircraft_config", aircraft_config, str(exc)) from None
    try:
        sc = load_scenario(scenario, aircraft=aircraft_config or None)
    except ConfigError as exc:
        raise ParameterError("scenario", scenario, str(exc)) from None
    if duration_s > sc.duration_s:
        raise ParameterError(
            "duration", duration_s, f"longer than scenario {sc.name!r} ({sc.duration_s:g} s); 0 = the whole scenario"
        )
    try:
        return SimulatedSession(sc, seed, duration_s if duration_s > 0 else None)
    except (ConfigError, ValueError) as exc:
        name = "seed" if "seed" in str(exc) else "duration"
        raise ParameterError(name, seed if name == "seed" else duration_s, str(exc)) from None


class SimDevice:
    """Publishes a device's streams from a background thread (see the module docstring).

    Args:
        node: the rclpy node that owns the publishers (and whose clock and logger are used).
        streams: the streams, or a callable that generates them (called in the thread).
        rate_factor: 1.0 = real time, 10 = ten times faster, 0 = as fast as subscribers keep up.
        min_subscribers: matched subscriptions every non-latched topic needs before starting.
        wait_subscribers_s: longest wait for ``min_subscribers`` [s].
        on_finished: called in the thread once everything is published, with this object.

    Attributes (read after :attr:`finished` is set): ``published`` (messages), ``topics``,
    ``elapsed_s``, ``error`` (an exception that ended the thread early, else None).
    """

    def __init__(
        self,
        node: Any,
        streams: Sequence[TopicStream] | Callable[[], Sequence[TopicStream]],
        rate_factor: float,
        *,
        min_subscribers: int = 0,
        wait_subscribers_s: float = 0.0,
        on_finished: Callable[["SimDevice"], None] | None = None,
    ) -> None:
        if not rate_factor >= 0.0:
            raise ValueError(f"rate_factor must be >= 0, got {rate_factor}")
        self._node = node
        self._streams_source = streams
        self.rate_factor = float(rate_factor)
        self.min_subscribers = int(min_subscribers)
        self.wait_subscribers_s = float(wait_subscribers_s)
        self._on_finished = on_finished
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

    def start(self) -> "SimDevice":
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the thread to stop and join it (call before destroying the node)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)

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
        streams = list(source() if callable(source) else source)
        topics = [s.topic for s in streams]
        if len(set(topics)) != len(topics):
            raise ValueError(f"duplicate topics in the device streams: {topics}")
        if self._stop.is_set():
            return
        self.streams = streams
        self.topics = len(streams)
        profiles = [qos_profile(s.qos) for s in streams]
        self.publishers = [
            self._node.create_publisher(message_class(s.msgtype), s.topic, p) for s, p in zip(streams, profiles)
        ]
        self.started.set()
        t0_wall = time.monotonic()

        latched = [i for i, s in enumerate(streams) if s.qos == "datum"]
        for i in latched:
            for k in range(len(streams[i])):
                self.publishers[i].publish(streams[i].message(k))
                self.published += 1
        if not self._wait_for_subscribers([i for i in range(len(streams)) if i not in latched]):
            return

        t_all, si_all, mi_all = merged_order(streams)
        keep = ~np.isin(si_all, latched)
        t_all, si_all, mi_all = t_all[keep], si_all[keep], mi_all[keep]
        n = len(t_all)
        batch = [max(1, p.depth // 4) for p in profiles]
        unacked = [0] * len(streams)
        end_index = {i for i, s in enumerate(streams) if s.topic == END_TOPIC}
        rate = self.rate_factor
        t_first = int(t_all[0]) if n else 0
        wall_start = self._now_ns()
        now_rel = 0.0  # (now - wall_start) * rate, in stamp ns; refreshed only when needed
        next_report = 1
        self._log.info(
            f"publishing {n} messages on {len(streams) - len(latched)} topics "
            f"({'as fast as subscribers keep up' if rate == 0 else f'rate_factor {rate:g}'})"
        )
        for k in range(n):
            if self._stop.is_set():
                return
            i = int(si_all[k])
            if rate > 0.0:
                due = int(t_all[k]) - t_first
                while now_rel < due:
                    now_rel = (self._now_ns() - wall_start) * rate
                    if now_rel < due:
                        wait_s = min((due - now_rel) / rate * 1e-9, POLL_S)
                        if self._stop.wait(wait_s):
                            return
            if i in end_index and not self._wait_acked(range(len(streams)), unacked):
                return
            self.publishers[i].publish(streams[i].message(int(mi_all[k])))
            self.published += 1
            unacked[i] += 1
            if unacked[i] >= batch[i] and not self._wait_acked([i], unacked):
                return
            tenth = (k + 1) * 10 // n
            if tenth >= next_report and k + 1 < n:
                self._log.info(
                    f"{tenth * 10}% published ({k + 1}/{n} messages, stamp "
                    f"+{(int(t_all[k]) - t_first) * 1e-9:.1f} s, after {time.monotonic() - t0_wall:.1f} s)"
                )
                next_report = tenth + 1
        if not self._wait_acked(range(len(streams)), unacked):
            return
        self.elapsed_s = time.monotonic() - t0_wall
        self._log.info(f"published {self.published} messages on {len(streams)} topics in {self.elapsed_s:.1f} s")
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
            waited = 0.0
            while not publisher.wait_for_all_acked(Duration(nanoseconds=int(0.5e9))):
                if self._stop.is_set():
                    return False
                waited += 0.5
                if waited % ACK_WARN_S == 0:
                    self._log.warning(
                        f"{self.streams[i].topic}: subscribers have not acknowledged "
                        f"{unacked[i]} messages for {waited:.0f} s; waiting (flow control)"
                    )
            unacked[i] = 0
        return not self._stop.is_set()
