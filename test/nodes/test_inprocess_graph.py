"""The graph in one process (an in-process graph test).

pos_master_node (device sim, alignment reference), two pos_sub_node (sub_r, sub_l) and
transfer_align_node (urtss) run as nodes of ONE process, in the test's own Context, spun by a
MultiThreadedExecutor (the devices publish from their own threads, the smoother runs in
transfer_align_node's worker processes): the session ends by /session/end, transfer_align_node writes the products
and publishes the antenna poses; every topic carries exactly the simulator's messages (received by
a counter node and in the node's spill, byte for byte), and the antenna poses match /truth.
test_transfer_align_node.py runs the same graph as processes. Every wait is bounded; nothing sleeps.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.serialization import deserialize_message
from ros_wait import spin_until, stop_and_destroy  # test/support/ros_wait.py

from dpos_ros.contract.qos import NAV_QOS, STATUS_QOS, qos_profile
from dpos_ros.contract.topics import message_class
from dpos_ros.devices.sim_session import load_sim_session
from dpos_ros.devices.sim_streams import TopicStream, device_streams, session_id
from dpos_ros.io import spill

pytestmark = [pytest.mark.ros, pytest.mark.slow]

SCENARIO, AIRCRAFT, SEED, DURATION_S = "paper_su", "paper_su_pair", 1, 10.0
SUBS = ("sub_r", "sub_l")
ANTENNAS = {"ant_r": "sub_r", "ant_l": "sub_l"}
TIMEOUT_S = 150.0
#: /truth/master too: at rate 0 a few hundred of its samples are still queued when /master/nav and
#: the sub-IMUs are complete; transfer_align_node's finalize must wait for them (none may be lost).
MASTER_TRUTH = True


def _keep_all(qos: QoSProfile) -> QoSProfile:
    """KEEP_ALL for the volatile streams (a slow callback throttles the device, never drops)."""
    if qos.durability.name == "TRANSIENT_LOCAL":
        return qos
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=qos.reliability, durability=qos.durability)


class Counter:
    """Raw subscriptions to every simulated topic and to the antenna poses; transfer_align_node's status."""

    def __init__(self, node: Node, streams: list[TopicStream]) -> None:
        self.received: dict[str, list[bytes]] = defaultdict(list)
        self.subscriptions = []
        topics = {s.topic: (message_class(s.msgtype), qos_profile(s.qos)) for s in streams}
        topics.update({f"/antenna/{a}/odom": (Odometry, NAV_QOS) for a in ANTENNAS})
        for topic, (cls, qos) in topics.items():
            self.subscriptions.append(node.create_subscription(
                cls, topic, lambda raw, t=topic: self.received[t].append(raw), _keep_all(qos), raw=True))
        self.ta_status: list[DiagnosticArray] = []
        self.subscriptions.append(node.create_subscription(
            DiagnosticArray, "/transfer_align/status", self.ta_status.append, STATUS_QOS))

    def ta_counts(self) -> dict[str, int]:
        """Messages per topic that transfer_align_node reports buffered (its latest status)."""
        if not self.ta_status:
            return {}
        values = {kv.key: kv.value for kv in self.ta_status[-1].status[0].values}
        return {k[: -len("/count")]: int(v) for k, v in values.items() if k.endswith("/count")}


def _positions(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns (N,), position in enu (N, 3) [m]) of serialized Odometry messages."""
    msgs = [deserialize_message(r, Odometry) for r in raws]
    t = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in msgs])
    p = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for m in msgs])
    return t, p


def test_graph_in_one_process(ros_context, tmp_path: Path) -> None:
    from pos_master_node.node import PosMasterNode
    from pos_sub_node.node import PosSubNode
    from transfer_align_node.node import TransferAlignNode

    session = load_sim_session(SCENARIO, AIRCRAFT, SEED, DURATION_S)
    sid = session_id(session)
    streams = device_streams(session, "master", truth=MASTER_TRUTH)
    for name in SUBS:
        streams += device_streams(session, f"sub_imu/{name}", truth=True)
    expected = {s.topic: s for s in streams}
    n_sub = len(expected["/sub_imu/sub_r/imu"])
    out = tmp_path / "out"
    products = out / sid

    sim = [Parameter("scenario", value=SCENARIO), Parameter("aircraft_config", value=AIRCRAFT),
           Parameter("seed", value=SEED), Parameter("duration", value=DURATION_S), Parameter("rate_factor", value=0.0),
           Parameter("min_subscribers", value=1), Parameter("wait_subscribers_s", value=30.0)]
    executor = MultiThreadedExecutor(num_threads=4, context=ros_context)
    nodes: list[Node] = []
    try:
        # consumers first, so that the devices (min_subscribers 1) find them matched
        counter_node = Node("graph_counter", context=ros_context)
        counter = Counter(counter_node, streams)
        ta = TransferAlignNode(context=ros_context, parameter_overrides=[
            Parameter("method", value="urtss"), Parameter("aircraft_config", value=AIRCRAFT),
            Parameter("output_dir", value=str(out)), Parameter("initial_attitude_error_deg", value=1.0),
            # one process carries the whole graph (GIL): on a loaded machine the master's streams may
            # reach the node seconds after /session/end; finalize must wait for them, not cut them off
            Parameter("finalize_timeout_s", value=60.0)])
        nodes += [counter_node, ta]
        for name in SUBS:
            nodes.append(PosSubNode(context=ros_context, cli_args=["--ros-args", "-r", f"__node:={name}"],
                                    parameter_overrides=[*sim, Parameter("name", value=name)]))
        for n in nodes:
            executor.add_node(n)
        # The sub-IMUs first, buffered by transfer_align_node (its /transfer_align/status counts)
        # before the master starts: at rate_factor 0 the devices are not paced, and the master's
        # /session/end must not overtake sub-IMU samples still queued for transfer_align_node.
        # (It waits for the sub-IMU data up to the end stamp, but /truth/* arriving after the end
        # would open a new session.)
        sub_topics = [t for t in expected if t.startswith(("/sub_imu/", "/truth/sub_imu/", "/truth/antenna/"))]

        def ta_buffered_subs() -> bool:
            counts = counter.ta_counts()
            return all(counts.get(t) == len(expected[t]) for t in sub_topics)

        spin_until(executor, ta_buffered_subs, TIMEOUT_S,
                    lambda: f"transfer_align_node to buffer the sub-IMU devices' topics; it reports {counter.ta_counts()}")
        master = PosMasterNode(context=ros_context, parameter_overrides=[
            *sim, Parameter("alignment", value="reference"), Parameter("publish_truth", value=MASTER_TRUTH)])
        nodes.append(master)
        executor.add_node(master)
        assert [n.get_name() for n in nodes] == ["graph_counter", "transfer_align_node", *SUBS, "pos_master_node"]

        def done() -> bool:
            return (products / "status.json").is_file() and all(
                len(counter.received[f"/antenna/{a}/odom"]) >= n_sub for a in ANTENNAS)

        spin_until(executor, done, TIMEOUT_S, lambda: f"the products and antenna poses; received "
                    f"{ {t: len(v) for t, v in counter.received.items()} }, transfer_align_node: {ta._progress}")
        for n in nodes[2:]:
            assert n.device.finished.is_set() and n.device.error is None
    finally:
        stop_and_destroy(executor, reversed(nodes))

    # nothing lost: the counter got every message of the simulator, byte for byte ...
    counts = {t: (len(counter.received[t]), len(s)) for t, s in expected.items()}
    assert all(got == want for got, want in counts.values()), counts
    for t, s in expected.items():
        assert counter.received[t] == [s.message(i) for i in range(len(s))], t
    # ... and so did transfer_align_node's spill, for every topic it buffers
    spills = [d for d in (out / "spill").iterdir() if spill.is_spill(d)]
    assert len(spills) == 1
    raw, _, _, warns = spill.read_spill(spills[0])
    assert not warns
    buffered = ["/dpos/datum", "/master/nav", "/truth/master", *(f"/sub_imu/{n}/imu" for n in SUBS),
                *(f"/truth/sub_imu/{n}" for n in SUBS), *(f"/truth/antenna/{a}" for a in ANTENNAS)]
    assert sorted(raw) == sorted(buffered)
    for t in buffered:
        assert raw[t][2] == counter.received[t], f"{t}: spill {len(raw[t][2])} of {len(counter.received[t])}"
    # every antenna pose at the sub-IMU rate, exactly once
    for a in ANTENNAS:
        assert len(counter.received[f"/antenna/{a}/odom"]) == n_sub, a

    # the products
    status = json.loads((products / "status.json").read_text())
    assert status["antennas"] == {a: "estimated" for a in ANTENNAS} and status["method"] == "urtss"
    # the simulator's reference main POS (no /pos_master/status): white noise, as [Gong2018] models it
    assert status["master_error_model"]["tau_s"] == 0.0 and "white noise" in status["master_error_model"]["why"], status
    for a in ANTENNAS:
        assert (products / f"{a}.csv").is_file()
    rmse = json.loads((products / "metrics.json").read_text())["methods"]["urtss"]["mean"]["rmse"]
    # as the 60 s multi-process test (test_transfer_align_node.py) for level attitude and velocity;
    # after 10 s of straight flight the heading misalignment is not yet separable (1.12 deg measured
    # after 20 s, 0.14 deg after 60 s), so only bounded by the prior; this test is about the graph
    assert max(rmse["pitch_deg"], rmse["roll_deg"]) < 0.01 and rmse["heading_deg"] < 1.5, rmse
    assert max(rmse["vel_e_mps"], rmse["vel_n_mps"], rmse["vel_u_mps"]) < 0.01, rmse
    assert max(rmse["lat_m"], rmse["lon_m"]) < 0.01 and rmse["h_m"] < 0.05, rmse
    # the whole /truth/master is in the session (a cut-off one gave a 33.7 m baseline error)
    assert rmse["baseline_m"] < 0.05, rmse
    late = {kv.key: kv.value for kv in counter.ta_status[-1].status[0].values if kv.key.endswith("late_after_finalize")}
    assert not late, late

    # the published antenna poses against /truth/antenna/<name>, stamp by stamp
    for a in ANTENNAS:
        t, p = _positions(counter.received[f"/antenna/{a}/odom"])
        t_true, p_true = _positions(counter.received[f"/truth/antenna/{a}"])
        i = np.searchsorted(t_true, t)  # the truth has the initial epoch too (IMU samples end at their stamp)
        assert len(t) == n_sub and np.all(i < len(t_true)) and np.array_equal(t_true[i], t)
        err_m = np.linalg.norm(p - p_true[i], axis=1)
        assert err_m.max() < 0.05, f"{a}: antenna position error up to {err_m.max():.4f} m"  # measured 0.005 / 0.03 m
