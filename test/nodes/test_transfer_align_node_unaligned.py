"""transfer_align_node with a main POS that never reports an aligned attitude: the session is
finalized, the products say why no antenna was estimated, nothing is published on /antenna/*,
and the node stays up for the next session (in-process, bounded waits).  The fake main POS also
publishes /pos_master/status, as pos_master_node does for its GNSS/INS mechanization: the node's
default ``master_error_tau_s`` (auto) takes its errors as correlated (status.json, the spill's metadata)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from repo_paths import REPO
from ros_wait import spin_until, stop_and_destroy  # test/support/ros_wait.py
from std_srvs.srv import Trigger

from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS, STATUS_QOS
from dpos_ros.io import bag
from dpos_ros.io.session import MASTER_SOURCE_KEY
from dpos_ros.io.spill import read_spill
from dpos_ros.products.master_reference import GNSS_INS_ERROR_TAU_S

pytestmark = [pytest.mark.ros]

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
SECONDS = 10.0


def _keep_all(qos: QoSProfile) -> QoSProfile:
    if qos.durability.name == "TRANSIENT_LOCAL":
        return qos
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=qos.reliability, durability=qos.durability)


def test_never_aligned_main_pos(ros_context, tmp_path: Path) -> None:
    from transfer_align_node.node import TransferAlignNode

    raw = bag.read_raw(BAG, ["/dpos/datum", "/master/nav", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu"])
    t_first = raw["/master/nav"][1][0]
    msgs: dict[str, list[bytes]] = {}
    for topic, (_, t_log, data) in raw.items():
        keep = [d for t, d in zip(t_log, data) if topic == "/dpos/datum" or t - t_first <= SECONDS * 1e9]
        if topic == "/master/nav":  # as pos_master_node publishes it before the in-flight alignment: 30 deg sigma
            out = []
            for d in keep:
                m = deserialize_message(d, Odometry)
                cov = np.array(m.pose.covariance).reshape(6, 6)
                cov[3:, 3:] = np.eye(3) * np.deg2rad(30.0) ** 2
                m.pose.covariance = cov.ravel().tolist()
                out.append(serialize_message(m))
            keep = out
        msgs[topic] = keep
    qos = {"/dpos/datum": DATUM_QOS, "/master/nav": NAV_QOS, "/sub_imu/sub_r/imu": SENSOR_QOS, "/sub_imu/sub_l/imu": SENSOR_QOS}
    types = {"/dpos/datum": "sensor_msgs/msg/NavSatFix", "/master/nav": "nav_msgs/msg/Odometry"}
    from dpos_ros.contract.topics import message_class

    executor = MultiThreadedExecutor(num_threads=3, context=ros_context)
    ta = TransferAlignNode(context=ros_context, parameter_overrides=[
        Parameter("method", value="ukf"), Parameter("aircraft_config", value="paper_su_pair"),
        Parameter("output_dir", value=str(tmp_path)), Parameter("finalize_timeout_s", value=5.0)])
    src = Node("fake_devices", context=ros_context)
    odoms = []
    watcher = Node("antenna_watcher", context=ros_context)
    for a in ("ant_r", "ant_l"):
        watcher.create_subscription(Odometry, f"/antenna/{a}/odom", odoms.append, _keep_all(NAV_QOS))
    pubs = {t: src.create_publisher(message_class(types.get(t, "sensor_msgs/msg/Imu")), t, _keep_all(q)) for t, q in qos.items()}
    src.create_publisher(DiagnosticArray, "/pos_master/status", STATUS_QOS)  # (its existence is what counts)
    client = src.create_client(Trigger, "/transfer_align_node/finalize")
    for n in (ta, src, watcher):
        executor.add_node(n)
    try:
        spin_until(executor, lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), 30.0, "transfer_align_node's subscriptions")
        for t, p in pubs.items():
            for d in msgs[t]:
                p.publish(d)
        n_expected = {t: len(v) for t, v in msgs.items()}

        def buffered() -> bool:
            with ta._lock:
                return all(t in ta._streams and ta._streams[t].count == n for t, n in n_expected.items())

        spin_until(executor, buffered, 60.0, lambda: f"buffering; node has { {t: s.count for t, s in ta._streams.items()} }")
        spin_until(executor, client.service_is_ready, 10.0, "the finalize service")
        fut = client.call_async(Trigger.Request())
        spin_until(executor, fut.done, 10.0, "the finalize reply")
        assert fut.result().success, fut.result().message
        status_files = lambda: list(tmp_path.glob("session_*/status.json"))  # noqa: E731
        spin_until(executor, lambda: bool(status_files()) and not ta._finalizing, 120.0, lambda: f"products; {ta._progress}")
    finally:
        stop_and_destroy(executor, (watcher, src, ta))
    st = json.loads(status_files()[0].read_text())
    assert st["antennas"] == {"ant_r": "not estimated: the main POS is never aligned",
                              "ant_l": "not estimated: the main POS is never aligned"}, st
    assert any("never aligned" in w for w in st["warnings"]), st["warnings"]
    assert odoms == [] and ta._device is None  # no antenna-pose device was started (it used to fail on empty streams)
    assert "ready for the next session" in ta._progress
    # the main POS is pos_master_node's (a /pos_master/status publisher): correlated errors, also for dpos-process on the spill
    assert st["master_error_model"]["tau_s"] == GNSS_INS_ERROR_TAU_S and "/pos_master/status" in st["master_error_model"]["why"], st
    (spill,) = (tmp_path / "spill").iterdir()
    assert read_spill(spill)[1][MASTER_SOURCE_KEY] == "mechanized"
