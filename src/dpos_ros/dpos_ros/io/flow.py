"""Flow control of the publishers that feed the graph as fast as it keeps up (the simulated
devices of :mod:`dpos_ros.devices.sim_device` and dpos-play, :mod:`dpos_ros.io.play`): writer
history depths that share a window of unacknowledged messages, and the Fast DDS writer profile
whose short heartbeat period makes acknowledgements prompt.  The module docstring of
:mod:`dpos_ros.devices.sim_device` ("Flow control") explains the Fast DDS behaviour.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections import deque
from collections.abc import MutableMapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from rclpy.qos import QoSProfile

from dpos_ros.contract.qos import qos_profile


class FlowStream(Protocol):
    """What flow control needs of a stream: its QoS kind and its message count (``len()``)."""

    @property
    def qos(self) -> str: ...

    def __len__(self) -> int: ...

#: Messages a subscription callback takes at once from its reader (:func:`take_waiting`).
TAKE_BATCH = 256

#: Longest sleep of the publishing thread between two checks of the stop flag [s].
POLL_S = 0.05
#: Unacknowledged messages per device over all topics (see "Flow control").
FLOW_WINDOW = 100
#: Writer heartbeat period of the device processes' Fast DDS profile [ms].
HEARTBEAT_PERIOD_MS = 20
#: A flow-control wait is logged after this many seconds, and again every as many.
ACK_WARN_S = 10.0
#: Poll period of a flow-control wait [s] (see _wait_acked: the GIL).
ACK_POLL_S = 0.001

_PROFILE_XML = """<?xml version="1.0" encoding="UTF-8" ?>
<!-- written by dpos_ros.devices.sim_device.use_device_fastdds_profile: writer heartbeat period of the
     simulated device nodes (flow control waits for acknowledgements, which follow heartbeats) -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <data_writer profile_name="dpos_sim_device_writer" is_default_profile="true">
    <times>
      <heartbeatPeriod>
        <sec>0</sec>
        <nanosec>{nanosec}</nanosec>
      </heartbeatPeriod>
    </times>
  </data_writer>
  <data_reader profile_name="dpos_reader" is_default_profile="true">
    <topic>
      <resourceLimitsQos>
        <max_samples>0</max_samples>
        <max_instances>0</max_instances>
        <max_samples_per_instance>0</max_samples_per_instance>
        <allocated_samples>100</allocated_samples>
      </resourceLimitsQos>
    </topic>
  </data_reader>
</profiles>
"""
_PROFILE_ENV = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def use_device_fastdds_profile(environ: MutableMapping[str, str] | None = None) -> str | None:
    """Point Fast DDS at the device writer profile (see "Flow control"); call before ``rclpy.init``.

    Returns the profile path, or None when not applied (another RMW, or the user configures Fast
    DDS). The file is written to the temporary directory (no package data needed).
    """
    env = os.environ if environ is None else environ
    if not env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps"):
        return None
    if any(env.get(k) for k in _PROFILE_ENV) or Path("DEFAULT_FASTRTPS_PROFILES.xml").exists():
        return None
    text = _PROFILE_XML.format(nanosec=HEARTBEAT_PERIOD_MS * 1_000_000)
    path = Path(tempfile.gettempdir()) / f"dpos_sim_device_fastdds_{os.getuid()}_{HEARTBEAT_PERIOD_MS}ms.xml"
    if not path.is_file() or path.read_text() != text:
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    for k in _PROFILE_ENV:
        env[k] = str(path)
    return str(path)


def _depth_for(n: int, target: float) -> int:
    """A depth near ``target`` that divides ``n`` when one lies in [target/4, 3 target/2], else round(target)."""
    if n <= max(1.0, target):
        return max(1, n)
    lo, hi = max(1, math.ceil(target / 4)), max(1, math.floor(1.5 * target))
    best = None
    for d in range(1, math.isqrt(n) + 1):
        if n % d == 0:
            for c in (d, n // d):
                if lo <= c <= hi and (best is None or abs(c - target) < abs(best - target)):
                    best = c
    return best if best is not None else max(1, round(target))


def writer_depths(streams: Sequence[FlowStream], window: int = FLOW_WINDOW) -> list[int]:
    """History depth of the device's writer of each stream (see "Flow control").

    Latched streams keep their profile's depth. The others share ``window`` in proportion to their
    message counts, each at least 1 and at most its own length, preferably a divisor of it (so that
    the last batch fills the history too and its acknowledgement is prompt).
    """
    total = sum(len(s) for s in streams if s.qos not in ("datum", "status")) or 1
    out = []
    for s in streams:
        if s.qos in ("datum", "status"):
            out.append(qos_profile(s.qos).depth)
        else:
            out.append(_depth_for(len(s), window * len(s) / total))
    return out


def writer_qos(stream: FlowStream, depth: int) -> QoSProfile:
    """The stream's QoS profile with the device writer's ``depth``."""
    p = qos_profile(stream.qos)
    return QoSProfile(history=p.history, depth=depth, reliability=p.reliability, durability=p.durability)


def take_waiting(subscription: Any, msg_class: Any, raw: bool, limit: int = TAKE_BATCH) -> list[tuple[Any, Any]]:
    """Take up to ``limit`` messages already waiting on ``subscription`` (``(message, info)`` pairs):
    called from the subscription's callback, it serves a backlog in one executor dispatch instead
    of one per message (rclpy's ~100 us dispatch otherwise limits a Python node to ~10k msg/s), so
    that a KEEP_ALL reader rarely reaches its DDS resource limits; there, measured with Fast DDS,
    a reader stopped acknowledging for 10-20 s at a time although its node took every message.
    Raises RuntimeError (rclpy's InvalidHandle / RCLError) while the subscription is
    being destroyed: the executor delivers the rest."""
    handle = getattr(subscription, "handle", None)
    out: list[tuple[Any, Any]] = []
    if handle is None:
        return out
    with handle:
        for _ in range(limit):
            taken = handle.take_message(msg_class, raw)
            if taken is None:
                break
            out.append((taken[0], taken[1] if len(taken) > 1 else None))
    return out


def subscribe_draining(node: Any, msg_class: Any, topic: str, callback: Any, qos: QoSProfile, raw: bool = False,
                       limit: int = TAKE_BATCH) -> Any:
    """``node.create_subscription`` whose callback also handles what else waits on the subscription
    (:func:`take_waiting`, up to ``limit`` per dispatch). Every subscription of a node that serves
    a backlog this way must do so: a single-threaded executor dispatches each ready subscription
    once per round, so a topic served one message per round falls behind one served in batches
    (measured: pos_master_node's /ifa/correction lagged 27 s of data behind the relayed IMU)."""
    box: list[Any] = []

    def on_message(msg: Any) -> None:
        callback(msg)
        if not box:
            return
        try:
            more = take_waiting(box[0], msg_class, raw, limit)
        except RuntimeError:  # being destroyed (shutdown): the executor delivers the rest
            return
        for m, _ in more:
            callback(m)

    sub = node.create_subscription(msg_class, topic, on_message, qos, raw=raw)
    box.append(sub)
    return sub


class ArrivalAge:
    """The stamps of one stream by the wall time they arrived: :meth:`aged_ns` is the newest stamp
    that arrived at least ``age_s`` ago. A node that must not act on a stamp before the messages of
    its other streams with earlier stamps are here waits both in stamps and in wall time: in a
    replay as fast as possible one stream is served in batches seconds of data ahead of another,
    but never long ahead in wall time."""

    def __init__(self) -> None:
        self._marks: deque[tuple[float, int]] = deque()
        self._aged_ns: int | None = None

    def add(self, t_ns: int, now_s: float | None = None) -> None:
        """A message stamped ``t_ns`` [ns] arrived (at monotonic ``now_s``, default now)."""
        self._marks.append((time.monotonic() if now_s is None else now_s, int(t_ns)))

    def aged_ns(self, age_s: float, now_s: float | None = None) -> int | None:
        """The newest stamp [ns] that arrived at least ``age_s`` [s] ago (None: none yet)."""
        now = time.monotonic() if now_s is None else now_s
        marks = self._marks
        while marks and now - marks[0][0] >= age_s:
            self._aged_ns = marks.popleft()[1]
        return self._aged_ns
