"""The /dpos/datum gate (dpos_core.gates.check_datum) in transfer_align_node and ifa_node: a datum
that changes within a session is refused (warned, counted in the status), the first is kept and spilled; the next
session may have another. In-process: the subscription callbacks are called directly with the
sample bag's serialized messages (test/support/ta_inprocess.py, as in test_transfer_align_faults.py);
every wait is bounded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import NavSatFix
from ta_inprocess import TOPICS, bag_messages, finalize, make_node, stamp_ns, status  # test/support/ta_inprocess.py

from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T

pytestmark = [pytest.mark.ros, pytest.mark.slow]  # (a finalize: the smoothers run)

SECONDS = 2.0


def _moved(datum: bytes, dlat_deg: float = 0.0, dh_m: float = 0.0, lat_deg: float | None = None) -> bytes:
    m = deserialize_message(datum, NavSatFix)
    m.latitude = m.latitude + dlat_deg if lat_deg is None else lat_deg
    m.altitude += dh_m
    return bytes(serialize_message(m))


def test_a_datum_that_changes_within_a_session_is_refused_and_the_first_kept(ros_context, tmp_path: Path,
                                                                               monkeypatch) -> None:
    msgs = {topic: data for topic, (_, data) in bag_messages(SECONDS).items()}
    ta = make_node(ros_context, tmp_path / "out", monkeypatch)
    try:
        cbs = ta.cbs
        datum = msgs[T.DATUM][0]
        first = cv.datum_from_msg(deserialize_message(datum, NavSatFix))
        cbs[T.DATUM](datum)
        half = len(msgs[T.MASTER_NAV]) // 2
        for d in msgs[T.MASTER_NAV][:half]:
            cbs[T.MASTER_NAV](d)
        # a foreign latched datum 10 deg north (the probe's case), 5 m up, and one that is no position
        for bad in (_moved(datum, dlat_deg=10.0), _moved(datum, dh_m=5.0), _moved(datum, lat_deg=float("nan"))):
            cbs[T.DATUM](bad)
        cbs[T.DATUM](datum)  # the same datum again (a second latched copy): accepted
        for topic in TOPICS[1:]:
            for d in msgs[topic][half if topic == T.MASTER_NAV else 0:]:
                cbs[topic](d)
        st = status(ta)
        assert st["gate/datum/changed"] == "2" and st["gate/datum/nonfinite"] == "1" and st["gate_refused"] == "3", st
        assert st["level"] >= 1 and st["last_gate"].startswith("datum/nonfinite"), st
        with ta._lock:
            kept = cv.datum_from_msg(deserialize_message(ta._datum[1], NavSatFix))
        np.testing.assert_array_equal(kept, first)
        # the session closes: the next one may have another datum (a new flight)
        finalize(ta, max(stamp_ns(d) for d in msgs[T.MASTER_NAV]), "gated")
        cbs[T.DATUM](_moved(datum, dlat_deg=1.0))
        assert status(ta)["gate_refused"] == "3"
        with ta._lock:
            now = cv.datum_from_msg(deserialize_message(ta._datum[1], NavSatFix))
        assert now[0] == pytest.approx(first[0] + np.deg2rad(1.0), abs=1e-12)
    finally:
        ta.destroy_node()


def test_ifa_node_keeps_its_first_datum_and_detects_a_second_graph(ros_context, ros_executor) -> None:
    """ifa_node: another /dpos/datum after the first is refused and counted; /master/imu stamps from two
    sources interleaving and a second publisher of /master/nav (a second graph on the domain) are
    warned about and counted."""
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from ros_wait import spin_until  # test/support/ros_wait.py

    from dpos_ros.contract.qos import NAV_QOS
    from ifa_node.node import IfaNode

    ifa = IfaNode(context=ros_context, parameter_overrides=[Parameter("aircraft_config", value="paper_ifa")])
    graphs = [Node(f"pos_master_node_{k}", context=ros_context) for k in "ab"]
    try:
        m = NavSatFix()
        m.latitude, m.longitude, m.altitude = 40.0, 116.0, 1000.0
        ifa._on_datum(m)
        first = ifa.datum_llh.copy()
        for lat, h in ((50.0, 1000.0), (40.0, 1010.0), (float("inf"), 0.0)):
            bad = NavSatFix()
            bad.latitude, bad.longitude, bad.altitude = lat, 116.0, h
            ifa._on_datum(bad)
        ifa._on_datum(m)  # the same one again: not a refusal
        np.testing.assert_array_equal(ifa.datum_llh, first)
        assert ifa.gates.by_reason == {"datum/changed": 2, "datum/nonfinite": 1}
        for g in graphs:
            g.create_publisher(Odometry, T.MASTER_NAV, NAV_QOS)
        # /master/imu from two devices interleaving (stamps 10 ms apart each, offset 5 s): detected once
        from dpos_ros.contract import cdr
        lay = cdr.layout("imu", cv.MASTER_FRAME)
        vals = cv.imu_bias_values(np.zeros(3), np.array([0.0, 0.0, 9.8]), np.eye(3) * 1e-8, np.eye(3) * 1e-6)
        t0 = 1_700_000_000 * 10**9
        for k in range(100):
            for offset in (0, 5 * 10**9):  # graph B's device is 5 s ahead
                ifa._on_imu(bytes(cdr.encode(lay, np.array([t0 + offset + k * 10**7], dtype=np.int64), vals)[0]))
        assert ifa.imu_interleave.episodes == 1 and ifa.imu_dropped == 99  # graph A's samples after B's first
        ros_executor.add_node(ifa)
        spin_until(ros_executor, lambda: ifa.publisher_watch.extra.get(T.MASTER_NAV) == 1, 30.0,
                   lambda: f"the second /master/nav publisher counted ({ifa.publisher_watch.values()})")
    finally:
        ros_executor.remove_node(ifa)
        for n in [*graphs, ifa]:
            n.destroy_node()
