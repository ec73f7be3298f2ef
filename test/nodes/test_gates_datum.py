"""The /dpos/datum gate (dpos_core.gates.check_datum) in transfer_align_node and ifa_node: a datum
that changes within a session is refused (warned, counted in the status), the first is kept and spilled; the next
session may have another. In-process: the subscription callbacks are called directly with the
sample bag's serialized messages (as test_transfer_align_faults.py); every wait is bounded.
"""

from __future__ import annotations

import concurrent.futures as cf
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from repo_paths import REPO
from sensor_msgs.msg import NavSatFix

from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io import bag

pytestmark = [pytest.mark.ros, pytest.mark.slow]  # (a finalize: the smoothers run)

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
SECONDS = 2.0
TOPICS = [T.DATUM, T.MASTER_NAV, T.sub_imu("sub_r"), T.sub_imu("sub_l")]
TYPES = {T.DATUM: T.NAVSATFIX, T.MASTER_NAV: T.ODOMETRY, T.sub_imu("sub_r"): T.IMU, T.sub_imu("sub_l"): T.IMU}


def _stamp(d: bytes) -> int:
    return int.from_bytes(d[4:8], "little", signed=True) * 1_000_000_000 + int.from_bytes(d[8:12], "little")


class Tap:
    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []

    def publish(self, arr: Any) -> None:
        st = arr.status[0]
        level = st.level if isinstance(st.level, int) else int.from_bytes(st.level, "little")
        self.sent.append({kv.key: kv.value for kv in st.values} | {"message": st.message, "level": level})


def _moved(datum: bytes, dlat_deg: float = 0.0, dh_m: float = 0.0, lat_deg: float | None = None) -> bytes:
    m = deserialize_message(datum, NavSatFix)
    m.latitude = m.latitude + dlat_deg if lat_deg is None else lat_deg
    m.altitude += dh_m
    return bytes(serialize_message(m))


def test_a_datum_that_changes_within_a_session_is_refused_and_the_first_kept(ros_context, tmp_path: Path,
                                                                               monkeypatch) -> None:
    import transfer_align_node.node as tan

    monkeypatch.setattr(tan, "_pool", lambda n: cf.ThreadPoolExecutor(max_workers=max(1, n)))
    raw = bag.read_raw(BAG, TOPICS)
    t_first = raw[T.MASTER_NAV][1][0]
    msgs = {topic: [d for t, d in zip(t_log, data) if topic == T.DATUM or t - t_first <= SECONDS * 1e9]
            for topic, (_, t_log, data) in raw.items()}
    over = {"method": "urtss", "aircraft_config": "paper_su_pair", "output_dir": str(tmp_path / "out"),
            "finalize_timeout_s": 2.0, "output_rate_hz": 10.0}
    ta = tan.TransferAlignNode(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
    try:
        ta._status_pub = Tap()
        cbs = {t: ta._make_cb(t, mt) for t, mt in TYPES.items()}
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
        ta._publish_status()
        st = ta._status_pub.sent[-1]
        assert st["gate/datum/changed"] == "2" and st["gate/datum/nonfinite"] == "1" and st["gate_refused"] == "3", st
        assert st["level"] >= 1 and st["last_gate"].startswith("datum/nonfinite"), st
        with ta._lock:
            kept = cv.datum_from_msg(deserialize_message(ta._datum[1], NavSatFix))
        np.testing.assert_array_equal(kept, first)
        # the session closes: the next one may have another datum (a new flight)
        end = max(_stamp(d) for d in msgs[T.MASTER_NAV])
        assert ta._start_finalize(end, "gated")
        ta._finalize_thread.join(timeout=180)
        assert not ta._finalize_thread.is_alive(), ta._progress
        cbs[T.DATUM](_moved(datum, dlat_deg=1.0))
        ta._publish_status()
        assert ta._status_pub.sent[-1]["gate_refused"] == "3"
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
