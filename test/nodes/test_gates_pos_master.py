"""pos_master_node's gates on the ifa_node's topics (dpos_core.gates): a foreign
publisher sends /ifa/correction and /ifa/status that fail them; the node refuses each, counts it in
/pos_master/status and keeps its navigation; a second publisher of /ifa/correction is counted.

The node runs with ``device: ros``, ``alignment: ifa`` on 4 s of paper_ifa's master device relayed
from a fake driver (test/support/master_driver.py, as in test_pos_master_node_relay.py); no ifa_node
runs: the test is the foreign publisher. Every wait is bounded; nothing sleeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from master_driver import TIMEOUT_S, MasterDriverGraph  # test/support/master_driver.py
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_wait import spin_until  # test/support/ros_wait.py
from sensor_msgs.msg import Imu

from dpos_core import earth
from dpos_core.units import DEG
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract.qos import NAV_QOS, STATUS_QOS
from dpos_ros.devices.sim_session import load_sim_session

pytestmark = pytest.mark.ros

DURATION_S = 4.0
OVERRIDES = [Parameter("device", value="ros"), Parameter("alignment", value="ifa"), Parameter("aircraft_config", value="paper_ifa")]


def _graph(context: Any, executor: Any) -> MasterDriverGraph:
    """The fake driver, a sink of /master/nav, /dpos/datum and /pos_master/status, the node under test."""
    return MasterDriverGraph(context, executor, OVERRIDES, DURATION_S)


def _correction(t_ns: int, llh: np.ndarray, vel: np.ndarray, q: np.ndarray, datum: np.ndarray,
                sig: tuple[float, float, float]) -> bytes:
    """A serialized /ifa/correction: the state, covariance sigma (position m, attitude deg, velocity m/s)."""
    pos_c, att_c, vel_c = (np.eye(3)[None] * s**2 for s in (sig[0], sig[1] * DEG, sig[2]))
    v = cv.odometry_values_cov(llh[None], vel[None], q[None], datum, None, pos_c, att_c, vel_c)
    return bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([t_ns], dtype=np.int64), v)[0])


def _ifa_status(message: str, heading_sigma_deg: str) -> DiagnosticArray:
    level = DiagnosticStatus.OK if message == "ALIGNED" else DiagnosticStatus.WARN
    return cv.diagnostic_array(Time(), "ifa_node",
                               "master_imu", level, message, {"aligned": "true" if message == "ALIGNED" else "false",
                                                              "heading_sigma_deg": heading_sigma_deg})


def test_pos_master_refuses_foreign_feedback_and_counts_it(ros_context, ros_executor) -> None:
    g = _graph(ros_context, ros_executor)
    foreign = stray = None
    try:
        g.play(g.driver_messages())
        ss = g.session
        imu, gnss = ss.master_imu(), ss.gnss()
        n_after = int((imu.t_s > gnss.t_s[0] + 1e-9).sum())
        spin_until(ros_executor, lambda: len(g.raw["/master/nav"]) >= n_after + 1 and bool(g.datum), TIMEOUT_S,
                   lambda: f"{n_after + 1} /master/nav (got {len(g.raw['/master/nav'])}) and /dpos/datum")
        datum = cv.datum_from_msg(g.datum[-1])
        nav = g.nav(datum)
        mech = g.node.mech
        before = mech.state.copy()
        foreign = Node("foreign_ifa", context=ros_context)
        corr_pub = foreign.create_publisher(Odometry, "/ifa/correction", NAV_QOS)
        status_pub = foreign.create_publisher(DiagnosticArray, "/ifa/status", STATUS_QOS)
        bias_pub = foreign.create_publisher(Imu, "/ifa/imu_bias", NAV_QOS)
        ros_executor.add_node(foreign)
        spin_until(ros_executor, lambda: min(p.get_subscription_count() for p in (corr_pub, status_pub, bias_pub)) >= 1,
                   TIMEOUT_S, "the foreign publishers to match")
        k = len(nav.t_ns) // 2
        t_k, llh_k, vel_k, q_k = int(nav.t_ns[k]), nav.llh[k], nav.vel_n_mps[k], nav.q_nb[k]

        # +1000 m with a covariance of 1e-10 against the node's initial 5 m: refused (size)
        far = earth.offset_llh(llh_k, np.array([1000.0, 0.0, 0.0]))
        corr_pub.publish(_correction(t_k, far, vel_k, q_k, datum, (1e-5, 1e-5, 1e-5)))
        st = g.wait_status(lambda s: s.get("gate/ifa_correction/size") == "1", "the +1000 m correction refused")
        # the same class, another state: +50 m/s of velocity
        corr_pub.publish(_correction(t_k, llh_k, vel_k + np.array([50.0, 0.0, 0.0]), q_k, datum, (0.1, 0.01, 0.01)))
        st = g.wait_status(lambda s: s.get("gate/ifa_correction/size") == "2", "the +50 m/s correction refused")
        # a stamp one hour ahead of the newest IMU sample: refused (future)
        corr_pub.publish(_correction(int(nav.t_ns[-1]) + 3600 * 10**9, llh_k, vel_k, q_k, datum, (0.1, 0.01, 0.01)))
        st = g.wait_status(lambda s: s.get("gate/ifa_correction/future") == "1", "the future correction refused")
        assert mech.corrections == 0 and st["corrections"] == "0"
        # a gyro bias of 1 rad/s on /ifa/imu_bias: refused (size)
        bias = cv.imu_bias_values(np.array([0.0, 0.0, 1.0]), np.zeros(3), np.eye(3) * 1e-12, np.eye(3) * 1e-12)
        bias_pub.publish(bytes(cdr.encode(cdr.layout("imu", cv.MASTER_FRAME), np.array([t_k], dtype=np.int64), bias)[0]))
        st = g.wait_status(lambda s: s.get("gate/ifa_imu_bias/size") == "1", "the 1 rad/s gyro bias refused")
        assert mech.biases == 0
        # /ifa/status ALIGNED with a heading sigma of 100 deg: refused, the flag stays UNALIGNED
        status_pub.publish(_ifa_status("ALIGNED", "100"))
        st = g.wait_status(lambda s: s.get("gate/ifa_status/unsupported") == "1", "the unsupported ALIGNED refused")
        assert st["message"] == "UNALIGNED" and not g.node.aligned
        assert st["gate_refused"] == "5" and "ifa_status/unsupported" in st["last_gate"]
        # ALIGNED with 0.05 deg passes its gate, but the node's own covariance (initial 100 deg) does not support it yet
        status_pub.publish(_ifa_status("ALIGNED", "0.05"))
        st = g.wait_status(lambda s: s.get("ifa_status") == "ALIGNED", "the supported ALIGNED")
        assert st["message"] == "UNALIGNED" and st["gate_refused"] == "5"
        # a consistent correction (the node's own state, a tight covariance): applied; now the flag is supported
        corr_pub.publish(_correction(t_k, llh_k, vel_k, q_k, datum, (0.1, 0.01, 0.01)))
        st = g.wait_status(lambda s: s.get("corrections") == "1", "the consistent correction applied")
        st = g.wait_status(lambda s: s["message"] == "ALIGNED", "ALIGNED once the own covariance supports it")
        # one stamped before it: refused (before_last)
        corr_pub.publish(_correction(int(nav.t_ns[k - 10]), nav.llh[k - 10], nav.vel_n_mps[k - 10], nav.q_nb[k - 10], datum,
                                     (0.1, 0.01, 0.01)))
        st = g.wait_status(lambda s: s.get("gate/ifa_correction/before_last") == "1", "the older correction refused")
        assert mech.corrections == 1 and mech.corrections_lost == 0
        # the navigation was not moved by the refused ones: the state at the end is where it was
        after = mech.state
        assert after.t_s == before.t_s
        assert np.linalg.norm(earth.enu_between(after.llh, before.llh)) < 0.01
        # a second publisher of /ifa/correction (a second graph, a stray process): counted
        stray = Node("stray_ifa", context=ros_context)
        stray.create_publisher(Odometry, "/ifa/correction", NAV_QOS)
        ros_executor.add_node(stray)
        st = g.wait_status(lambda s: s.get("publishers_extra/ifa/correction") == "1", "the second publisher counted")
        assert st["message"] == "ALIGNED"  # (the flag stands; the level says WARN)
    finally:
        for n in [x for x in (stray, foreign) if x is not None] + g.nodes[::-1]:
            ros_executor.remove_node(n)
            n.destroy_node()


def test_a_restarted_pos_master_takes_the_datum_of_the_running_ifa_node(ros_context, ros_executor) -> None:
    """``device: ros`` without ``datum``: when an ifa_node runs (this node was restarted mid-session), the
    session's datum is the one of its /ifa/status (``datum_deg``), not this node's first fix: the
    ifa_node's corrections are in that frame (without it, all of them would be refused by the gate)."""
    foreign = Node("running_ifa", context=ros_context)
    foreign.create_publisher(Odometry, "/ifa/correction", NAV_QOS)  # an ifa_node is in the graph
    status_pub = foreign.create_publisher(DiagnosticArray, "/ifa/status", STATUS_QOS)
    ss = load_sim_session("paper_ifa", "", 1, DURATION_S)
    first_fix = ss.gnss().llh[0]
    session = first_fix + np.array([0.01 * DEG, -0.02 * DEG, -3.0])  # the session's datum, set before the restart
    status_pub.publish(cv.diagnostic_array(Time(), "ifa_node", "master_imu", DiagnosticStatus.OK, "ALIGNED", {
        "aligned": "true", "heading_sigma_deg": "0.02", "fixes_done_ns": str(2**62),
        "datum_deg": f"{session[0] / DEG:.10f} {session[1] / DEG:.10f} {session[2]:.4f}"}))
    ros_executor.add_node(foreign)
    g = _graph(ros_context, ros_executor)
    try:
        g.play(g.driver_messages())
        spin_until(ros_executor, lambda: bool(g.datum), TIMEOUT_S, "/dpos/datum")
        got = cv.datum_from_msg(g.datum[-1])
        np.testing.assert_allclose(got[:2], session[:2], rtol=0, atol=1e-11)  # (the status has 1e-10 deg, 0.1 mm)
        assert got[2] == pytest.approx(session[2], abs=1e-4)
        st = g.wait_status(lambda s: s.get("started") == "True", "the start")
        assert st["message"] == "UNALIGNED"  # the latched ALIGNED is not this node's: its covariance is initial_sigma's
    finally:
        for n in [foreign] + g.nodes[::-1]:
            ros_executor.remove_node(n)
            n.destroy_node()


def test_fixes_that_wait_for_the_running_ifa_nodes_datum_still_start_the_mechanization(ros_context, ros_executor) -> None:
    """A restart where the ifa_node's /ifa/status comes only after three fixes (a busy machine): the
    fixes wait for its datum (sources.DATUM_WAIT_FIXES) and are not consumed meanwhile; once it has
    come, /master/nav starts at the first of them, in the running ifa_node's datum."""
    foreign = Node("running_ifa", context=ros_context)
    foreign.create_publisher(Odometry, "/ifa/correction", NAV_QOS)  # an ifa_node is in the graph, its status not seen yet
    status_pub = foreign.create_publisher(DiagnosticArray, "/ifa/status", STATUS_QOS)
    ros_executor.add_node(foreign)
    g = _graph(ros_context, ros_executor)
    try:
        gnss_t_ns = g.streams["/gnss/fix"].t_ns
        assert len(gnss_t_ns) >= 4
        session = g.session.gnss().llh[0] + np.array([0.01 * DEG, -0.02 * DEG, -3.0])
        g.play(g.driver_messages(upto_ns=int(gnss_t_ns[2])))  # three fixes (and their IMU) before the status
        relay_status: list[DiagnosticArray] = []  # the relay's, every 1 s: the node's timers (its start tick) ran meanwhile
        g.sink.create_subscription(DiagnosticArray, "/pos_master_node/status", relay_status.append, STATUS_QOS)
        spin_until(ros_executor, lambda: len(relay_status) >= 3, TIMEOUT_S, "three relay statuses")
        assert not g.datum and not g.node.navigator.started  # waiting for the datum, not started without one
        status_pub.publish(cv.diagnostic_array(Time(), "ifa_node", "master_imu", DiagnosticStatus.OK, "ALIGNED", {
            "aligned": "true", "heading_sigma_deg": "0.02", "fixes_done_ns": str(2**62),
            "datum_deg": f"{session[0] / DEG:.10f} {session[1] / DEG:.10f} {session[2]:.4f}"}))
        spin_until(ros_executor, lambda: g.node.navigator.ifa_status != "none", TIMEOUT_S, "the ifa_node's status received")
        g.play(g.driver_messages(after_ns=int(gnss_t_ns[2])))
        g.wait_status(lambda s: s.get("started") == "True", "the start")
        spin_until(ros_executor, lambda: bool(g.datum) and bool(g.raw["/master/nav"]), TIMEOUT_S, "/dpos/datum and /master/nav")
        got = cv.datum_from_msg(g.datum[-1])
        np.testing.assert_allclose(got[:2], session[:2], rtol=0, atol=1e-11)
        assert g.nav(got).t_ns[0] == int(gnss_t_ns[0])  # started at the first fix, which waited for the datum
    finally:
        for n in [foreign] + g.nodes[::-1]:
            ros_executor.remove_node(n)
            n.destroy_node()
