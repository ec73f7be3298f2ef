"""A fake master-device driver feeding pos_master_node in-process (``device: ros``), for the node tests
(test_pos_master_node_relay.py, test_gates_pos_master.py).

:class:`MasterDriverGraph`: the driver publishes paper_ifa's simulated master IMU (sensor_msgs/Imu on
/drv/imu), GNSS fix (/drv/fix) and velocity (/drv/vel); a sink keeps /master/nav (serialized), /dpos/datum
and /pos_master/status; the node under test relays the driver's topics (:data:`REMAPS`). Every wait is
bounded (:func:`ros_wait.spin_until`); nothing sleeps.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_wait import spin_until
from sensor_msgs.msg import Imu, NavSatFix

from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS, STATUS_QOS
from dpos_ros.devices.sim_session import load_sim_session
from dpos_ros.devices.sim_streams import TopicStream, device_streams

TIMEOUT_S = 60.0
#: messages published before waiting for the relay to catch up
CHUNK = 100
DRIVER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
REMAPS = ["--ros-args", "-r", "imu_in:=/drv/imu", "-r", "fix_in:=/drv/fix", "-r", "vel_in:=/drv/vel"]
#: the driver's topics and the contract topics the node relays them to
RELAYED = {"/drv/imu": "/master/imu", "/drv/fix": "/gnss/fix", "/drv/vel": "/gnss/vel"}


class MasterDriverGraph:
    """The fake driver, a sink and the node under test (``overrides``: its parameters) on one executor,
    on ``duration_s`` of paper_ifa's session (seed 1). ``relayed``: the sink also keeps the relayed
    /master/imu, /gnss/fix and /gnss/vel (in :attr:`raw`), and the graph waits for the relay's
    publishers to match it."""

    def __init__(self, context: Any, executor: Any, overrides: list[Parameter], duration_s: float,
                 relayed: bool = False) -> None:
        from pos_master_node.node import PosMasterNode

        self.executor = executor
        self.session = load_sim_session("paper_ifa", "", 1, duration_s)
        self.streams: dict[str, TopicStream] = {s.topic: s for s in device_streams(self.session, "master", truth=False)}
        self.driver = Node("fake_master_driver", context=context)
        self.pubs = {"/drv/imu": self.driver.create_publisher(Imu, "/drv/imu", DRIVER_QOS),
                     "/drv/fix": self.driver.create_publisher(NavSatFix, "/drv/fix", DRIVER_QOS),
                     "/drv/vel": self.driver.create_publisher(TwistWithCovarianceStamped, "/drv/vel", DRIVER_QOS)}
        self.sink = Node("master_driver_sink", context=context)
        self.raw: dict[str, list[bytes]] = defaultdict(list)
        kept = [("/master/nav", Odometry, NAV_QOS)]
        if relayed:
            kept += [("/master/imu", Imu, SENSOR_QOS), ("/gnss/fix", NavSatFix, SENSOR_QOS),
                     ("/gnss/vel", TwistWithCovarianceStamped, SENSOR_QOS)]
        for topic, cls, qos in kept:
            self.sink.create_subscription(cls, topic, lambda m, t=topic: self.raw[t].append(bytes(m)), qos, raw=True)
        self.datum: list[NavSatFix] = []
        self.sink.create_subscription(NavSatFix, "/dpos/datum", self.datum.append, DATUM_QOS)
        self.status: list[dict[str, str]] = []
        self.sink.create_subscription(
            DiagnosticArray, "/pos_master/status",
            lambda m: self.status.append({kv.key: kv.value for kv in m.status[0].values} | {"message": m.status[0].message}),
            STATUS_QOS)
        self.node = PosMasterNode(context=context, cli_args=REMAPS, parameter_overrides=overrides)
        self.nodes = [self.driver, self.sink, self.node]
        for n in self.nodes:
            executor.add_node(n)
        spin_until(executor, lambda: all(p.get_subscription_count() >= 1 for p in self.pubs.values())
                   and self.node.nav_pub.get_subscription_count() >= 1
                   and (not relayed or all(s.publisher.get_subscription_count() >= 1 for s in self.node.relay._states)),
                   TIMEOUT_S, "the driver -> relay -> sink matches")

    def received(self) -> int:
        """The messages the node's relay received."""
        return sum(st.received for st in self.node.relay.stats.values())

    def stamp_ns(self, t_s: float) -> int:
        """The ROS stamp [ns] of session time ``t_s`` [s]."""
        return int(cv.stamps_ns(self.session.scenario.start_time_s, np.array([t_s]))[0])

    def driver_messages(self, after_ns: int = -1, upto_ns: int = 2**63 - 1) -> list[tuple[int, str, bytes]]:
        """(stamp, driver topic, serialized message) of the master device's IMU, fixes and velocities
        stamped in ``(after_ns, upto_ns]``, in stamp order (IMU first at a tie)."""
        out = []
        for rank, (drv, topic) in enumerate(RELAYED.items()):
            s = self.streams[topic]
            out += [(int(t), rank, drv, s.message(i)) for i, t in enumerate(s.t_ns) if after_ns < t <= upto_ns]
        out.sort(key=lambda m: (m[0], m[1]))
        return [(t, drv, msg) for t, _, drv, msg in out]

    def play(self, messages: list[tuple[int, str, Any]]) -> None:
        """Publish (stamp, driver topic, bytes or message) in order, in chunks the relay catches up with."""
        for lo in range(0, len(messages), CHUNK):
            n0 = self.received()
            chunk = messages[lo:lo + CHUNK]
            for _, topic, msg in chunk:
                self.pubs[topic].publish(msg)
            spin_until(self.executor, lambda n=n0 + len(chunk): self.received() >= n, TIMEOUT_S,
                       lambda: f"the relay to receive {len(chunk)} messages (got {self.received() - n0})")

    def nav(self, datum_llh: np.ndarray | None = None) -> cv.OdometryBlock:
        """The received /master/nav, poses in the ``enu`` frame of ``datum_llh`` (default: the session's)."""
        lay = cdr.layout("odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        rows = np.stack([np.frombuffer(r, dtype=np.uint8)[: lay.size] for r in self.raw["/master/nav"]])
        t_ns, vals = cdr.decode(lay, rows)
        return cv.odometry_from_values(t_ns, vals, self.session.datum_llh if datum_llh is None else datum_llh)

    def wait_status(self, condition: Any, what: str) -> dict[str, str]:
        """Spin until the last /pos_master/status meets ``condition``; returns it."""
        spin_until(self.executor, lambda: bool(self.status) and condition(self.status[-1]), TIMEOUT_S,
                   lambda: f"{what} (last status: {self.status[-1] if self.status else None})")
        return self.status[-1]

    def close(self) -> None:
        """Remove the graph's nodes from the executor and destroy them (the node under test first)."""
        for n in self.nodes[::-1]:
            self.executor.remove_node(n)
            n.destroy_node()
