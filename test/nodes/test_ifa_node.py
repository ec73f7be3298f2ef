"""The master loop of the graph: pos_master_node (mechanization with IFA feedback) + ifa_node.

* (the master mechanization with corrections equals the aligner's closed-loop strapdown in any order of
  arrival: test/dpos_core/ifa/test_mechanization.py, no ROS);
* in-process graph (one Context, a MultiThreadedExecutor): the simulated master device + the
  mechanization + ifa_node reach ALIGNED, /master/nav agrees with the truth, and the corrections
  equal dpos_core.ifa.pipeline.run on the same data (the shadow design is deterministic);
* bad GNSS input is rejected with a warning and leaves the filter undisturbed; fixes stamped before
  the aligner's start are skipped quietly and counted (``before_start``);
* (pos_master_node ``device: ros`` + ifa_node on jittered IMU stamps and late fixes: test_ifa_loop_live.py);
* ``alignment: given`` integrates back to the truth from a perfect start.

Every wait is bounded; nothing sleeps for a fixed time.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from typing import Any

import numpy as np
import pytest
from ifa_support import Spinner, llh_err_m, truth_initial  # test/support/ifa_support.py
from rclpy.parameter import Parameter

from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.mechanization import stamp_s
from dpos_core.ifa.pipeline import run
from dpos_core.series import GnssSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG
from dpos_ros.contract import conversions as cv

pytestmark = pytest.mark.ros

GRAPH_TIMEOUT_S = 120.0
#: hang guard of the in-process waits [s] (one process carries the graph: with a CPU-bound neighbour
#: 30 s was measured too short for the first epoch)
WAIT_S = 120.0


# ----------------------------------------------------------------------------- graph helpers


class Probe:
    """A test node's raw subscriptions: /ifa/correction, /master/nav, /ifa/status, /session/end."""

    def __init__(self, context: Any, nav: bool = True) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.node import Node
        from std_msgs.msg import Header

        from dpos_ros.contract.qos import NAV_QOS, STATUS_QOS, keep_all
        from dpos_ros.io.flow import subscribe_draining

        self.node = Node("ifa_probe", context=context)
        self.raw: dict[str, list[bytes]] = defaultdict(list)
        self.statuses: list[Any] = []
        self.changed = threading.Condition()
        topics = ["/ifa/correction", "/session/end"] + (["/master/nav"] if nav else [])
        for topic in topics:
            cls = Header if topic == "/session/end" else Odometry
            # KEEP_ALL and served in batches, as a consumer of the graph must (the nodes in this executor serve theirs so)
            subscribe_draining(self.node, cls, topic, lambda m, t=topic: self._got(t, m), keep_all(NAV_QOS), raw=True)
        subscribe_draining(self.node, DiagnosticArray, "/ifa/status", lambda m: self._got("/ifa/status", m), STATUS_QOS)

    def _got(self, topic: str, msg: Any) -> None:
        with self.changed:
            if topic == "/ifa/status":
                self.statuses.append({kv.key: kv.value for kv in msg.status[0].values} | {"message": msg.status[0].message})
            else:
                self.raw[topic].append(bytes(msg))
            self.changed.notify_all()

    def wait(self, condition, timeout: float, what) -> None:
        deadline = time.monotonic() + timeout
        with self.changed:
            while not condition():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise AssertionError(f"timed out after {timeout} s waiting for {what() if callable(what) else what}")
                self.changed.wait(min(remaining, 0.2))


def _odometry(raws: list[bytes], datum: np.ndarray) -> cv.OdometryBlock:
    from dpos_ros.contract import cdr

    lay = cdr.layout("odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
    rows = np.stack([np.frombuffer(r, dtype=np.uint8)[: lay.size] for r in raws])
    t_ns, vals = cdr.decode(lay, rows)
    return cv.odometry_from_values(t_ns, vals, datum)


# ----------------------------------------------------------------------------- graph


GRAPH_DURATION_S = 100.0  # ALIGNED at ~72 s with the fixes' own sigmas (seed 1)


def test_graph_aligns_and_equals_the_offline_run(ros_context) -> None:
    """pos_master_node (sim, paper_ifa, rate 0, alignment ifa) + ifa_node in one process: ALIGNED,
    /master/nav at the end within the alignment accuracy of the truth, corrections == run()."""
    from ifa_node.node import IfaNode
    from pos_master_node.node import PosMasterNode

    probe = Probe(ros_context)
    ifa = IfaNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("use_reported_sigma", value=True)])
    t_wall = time.monotonic()
    master = PosMasterNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("seed", value=1), Parameter("duration", value=GRAPH_DURATION_S),
        Parameter("rate_factor", value=0.0), Parameter("alignment", value="ifa"), Parameter("publish_truth", value=False),
        Parameter("min_subscribers", value=1), Parameter("wait_subscribers_s", value=20.0)])
    spinner = Spinner(ros_context, [probe.node, ifa, master])
    try:
        ss = master.session
        n_fix = ss.gnss().t_s.size
        probe.wait(lambda: probe.raw["/session/end"] and len(probe.raw["/ifa/correction"]) >= n_fix
                   and master.mech.corrections >= n_fix, GRAPH_TIMEOUT_S,
                   lambda: f"/session/end and {n_fix} corrections (got {len(probe.raw['/ifa/correction'])}, "
                           f"master applied {master.mech.corrections}, ifa status {probe.statuses[-1:]})")
        wall_s = time.monotonic() - t_wall
        assert master.device.error is None
        # status: WAITING first, ALIGNED reached, nothing rejected
        messages = [s["message"] for s in probe.statuses]
        assert messages[0] == "WAITING" and "ALIGNED" in messages, messages
        last = probe.statuses[-1]
        assert last["rejected_fixes"] == "0" and last["imu_dropped"] == "0" and float(last["heading_sigma_deg"]) < 0.1
        # determinism: the corrections are run()'s corrected states at the epochs
        datum = ss.datum_llh
        corr = _odometry(probe.raw["/ifa/correction"], datum)
        origin = int(cv.stamps_ns(ss.scenario.start_time_s, np.array([0.0]))[0])
        imu, gnss = ss.master_imu(), ss.gnss()
        init = truth_initial(ss, float(ss.scenario.ifa["initial_heading_error_deg"]))
        res = run(imu, gnss, ss.scenario.aircraft.gnss_lever_arm_m, ifa.core_config, "add2", init)
        assert res.aligned and res.status.tolist().count(1) > 0
        t_corr = stamp_s(corr.t_ns, origin)
        np.testing.assert_array_equal(t_corr, gnss.t_s)
        k = np.searchsorted(res.t_s, t_corr)
        pos_err = llh_err_m(corr.llh, res.llh[k])
        assert pos_err.max() < 1e-6, (np.flatnonzero(pos_err > 1e-6), pos_err.max())
        assert np.abs(corr.vel_n_mps - res.vel_n_mps[k]).max() < 1e-9
        assert np.min([np.abs(corr.q_nb - res.q_nb[k]).max(axis=1), np.abs(corr.q_nb + res.q_nb[k]).max(axis=1)], axis=0).max() < 1e-9
        # the master's mechanization after the last correction is the aligner's strapdown
        s = master.mech.state
        assert s.t_s == pytest.approx(res.t_s[-1], abs=1e-9)
        assert llh_err_m(s.llh, res.final.llh) < 1e-6
        assert np.abs(s.vel_n_mps - res.final.vel_n_mps).max() < 1e-9
        # /master/nav: the initial state first, then one per IMU sample; at the end within the alignment accuracy
        nav = _odometry(probe.raw["/master/nav"], datum)
        t_nav = stamp_s(nav.t_ns, origin)
        assert t_nav[0] == 0.0 and np.array_equal(t_nav[1:], imu.t_s)
        truth = ss.truth("master", t_nav[-1:])
        herr = hpr_error(hpr_from_C_nb(cv.quat_to_dcm(nav.q_nb[-1])), hpr_from_C_nb(truth.C_nb[0])) / DEG
        assert abs(herr[0]) < 0.05 and np.all(np.abs(herr[1:]) < 0.02), herr
        assert llh_err_m(nav.llh[-1], truth.llh[0]) < 3.0
        # unaligned flag: the heading sigma of the first nav is the prior's, of the last the filter's
        sig_h = np.sqrt(nav.pose_cov[[0, -1], 5, 5]) / DEG
        assert sig_h[0] == pytest.approx(100.0) and sig_h[1] < 0.1
        print(f"graph {GRAPH_DURATION_S:g} s session: {n_fix} corrections, aligned at {res.aligned_t_s} s, "
              f"final heading error {herr[0]:.4f} deg, corrections == run() to {pos_err.max():.2e} m, wall {wall_s:.1f} s")
    finally:
        spinner.stop()


# ----------------------------------------------------------------------------- bad GNSS input


def _spin_until(executor: Any, condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        executor.spin_once(timeout_sec=0.02)


def test_bad_gnss_is_rejected_and_leaves_the_filter_undisturbed(ros_context, ros_executor) -> None:
    """The test plays the master: initial /master/nav, the IMU, then GNSS fixes with a duplicate,
    an out-of-order, a NaN and a zero-covariance fix among them: each is rejected with a warning and
    counted; the corrections equal run() on the good fixes only."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, NavSatFix

    from dpos_ros.contract.qos import NAV_QOS, SENSOR_QOS, STATUS_QOS
    from ifa_node.node import IfaNode

    ss = SimulatedSession(load_scenario("paper_ifa"), 1, duration_s=6.0)
    imu, g = ss.master_imu(), ss.gnss()
    datum = ss.datum_llh
    origin = int(cv.stamps_ns(ss.scenario.start_time_s, np.array([0.0]))[0])
    init = truth_initial(ss, 30.0)
    # the test publishes the whole IMU first and the fixes one by one: a fix that comes later than
    # outage_wait_s of wall time (a busy machine) would be an outage, and the fix after it stale
    ifa = IfaNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("datum", value=[datum[0] / DEG, datum[1] / DEG, float(datum[2])]),
        Parameter("outage_wait_s", value=3600.0)])
    node = Node("fake_master", context=ros_context)
    pub = {"nav": node.create_publisher(Odometry, "/master/nav", NAV_QOS), "imu": node.create_publisher(Imu, "/master/imu", SENSOR_QOS),
           "fix": node.create_publisher(NavSatFix, "/gnss/fix", SENSOR_QOS),
           "vel": node.create_publisher(TwistWithCovarianceStamped, "/gnss/vel", SENSOR_QOS)}
    statuses: list[dict[str, str]] = []
    corrections: list[bytes] = []
    node.create_subscription(DiagnosticArray, "/ifa/status",
                             lambda m: statuses.append({kv.key: kv.value for kv in m.status[0].values} | {"message": m.status[0].message}),
                             STATUS_QOS)
    node.create_subscription(Odometry, "/ifa/correction", lambda m: corrections.append(bytes(m)), NAV_QOS, raw=True)
    for n in (ifa, node):
        ros_executor.add_node(n)
    try:
        _spin_until(ros_executor, lambda: all(p.get_subscription_count() >= 1 for p in pub.values()), WAIT_S, "the ifa_node's subscriptions")
        _spin_until(ros_executor, lambda: statuses and statuses[-1]["message"] == "WAITING", WAIT_S, "WAITING")
        v0 = cv.odometry_values_cov(init.llh[None], init.vel_n_mps[None], init.q_nb[None], datum, None, np.eye(3), np.eye(3), np.eye(3))
        pub["nav"].publish(bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([origin]), v0)[0]))
        t_imu = cv.stamps_ns(ss.scenario.start_time_s, imu.t_s)
        for row in cv.imu_rows(cv.MASTER_FRAME, t_imu, imu.omega_radps, imu.f_mps2, 1e-6, 1e-4):
            pub["imu"].publish(bytes(row))
        _spin_until(ros_executor, lambda: ifa.imu_samples == imu.t_s.size and ifa.al is not None, WAIT_S, "the IMU samples")
        t_g = cv.stamps_ns(ss.scenario.start_time_s, g.t_s)

        def fix(j: int, llh=None, sigma=None, with_vel: bool = True) -> None:
            llh = g.llh[j] if llh is None else llh
            pub["fix"].publish(cv.navsatfix_msg(int(t_g[j]), cv.GNSS_FRAME, llh, g.pos_sigma_m[j] if sigma is None else sigma))
            if with_vel:
                pub["vel"].publish(cv.gnss_vel_msg(int(t_g[j]), g.vel_n_mps[j], g.vel_sigma_mps[j]))

        def accepted(j: int) -> None:
            n = ifa.epochs
            fix(j)
            _spin_until(ros_executor, lambda: ifa.epochs == n + 1 and len(corrections) == n + 1, WAIT_S, f"epoch {j}")

        def rejected(reason: str, **kw) -> None:
            n, e = ifa.rejected, ifa.epochs
            fix(**kw)
            _spin_until(ros_executor, lambda: ifa.rejected == n + 1, WAIT_S, f"the rejection ({reason})")
            assert ifa.epochs == e
            assert reason in ifa.last_rejection, ifa.last_rejection

        accepted(0)
        accepted(1)
        rejected("duplicate", j=1, llh=g.llh[1] + [1e-5, 0, 0], with_vel=False)
        rejected("out-of-order", j=0, with_vel=False)
        rejected("not finite", j=2, llh=np.array([np.nan, g.llh[2, 1], g.llh[2, 2]]))
        accepted(2)
        rejected("zero or negative covariance", j=3, sigma=np.zeros(3))
        accepted(3)
        accepted(4)
        _spin_until(ros_executor, lambda: statuses[-1].get("epochs") == "5", WAIT_S, "the status of epoch 5")
        assert statuses[-1]["rejected_fixes"] == "4" and statuses[-1]["imu_dropped"] == "0"
        good = GnssSeries(g.t_s[:5], g.llh[:5], g.pos_sigma_m[:5], g.vel_n_mps[:5], g.vel_sigma_mps[:5])
        res = run(imu, good, ss.scenario.aircraft.gnss_lever_arm_m, ifa.core_config, "add2", init)
        corr = _odometry(corrections, datum)
        np.testing.assert_array_equal(stamp_s(corr.t_ns, origin), good.t_s)
        k = np.searchsorted(res.t_s, good.t_s - 1e-9)
        assert llh_err_m(corr.llh, res.llh[k]).max() < 1e-6
        assert np.abs(corr.vel_n_mps - res.vel_n_mps[k]).max() < 1e-9
    finally:
        for n in (ifa, node):
            ros_executor.remove_node(n)
            n.destroy_node()


def test_fixes_before_the_start_are_skipped_quietly(ros_context, ros_executor) -> None:
    """The master starts from a fix once the vehicle moves; the fixes stamped before
    (standing still) and the start fix itself reach ifa_node before its initial state: they are
    skipped and counted (``before_start``), not rejected, and the later fixes are epochs."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, NavSatFix

    from dpos_ros.contract.qos import NAV_QOS, SENSOR_QOS, STATUS_QOS
    from ifa_node.node import IfaNode

    ss = SimulatedSession(load_scenario("paper_ifa"), 1, duration_s=4.0)
    imu, g = ss.master_imu(), ss.gnss()
    datum = ss.datum_llh
    start_ns = int(cv.stamps_ns(ss.scenario.start_time_s, np.array([0.0]))[0])
    init = truth_initial(ss, 30.0)
    # the test publishes the whole IMU first and the fixes one by one: a fix that comes later than
    # outage_wait_s of wall time (a busy machine) would be an outage, and the fix after it stale
    ifa = IfaNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("datum", value=[datum[0] / DEG, datum[1] / DEG, float(datum[2])]),
        Parameter("outage_wait_s", value=3600.0)])
    node = Node("fake_master_before_start", context=ros_context)
    pub = {"nav": node.create_publisher(Odometry, "/master/nav", NAV_QOS), "imu": node.create_publisher(Imu, "/master/imu", SENSOR_QOS),
           "fix": node.create_publisher(NavSatFix, "/gnss/fix", SENSOR_QOS),
           "vel": node.create_publisher(TwistWithCovarianceStamped, "/gnss/vel", SENSOR_QOS)}
    statuses: list[dict[str, str]] = []
    node.create_subscription(DiagnosticArray, "/ifa/status",
                             lambda m: statuses.append({kv.key: kv.value for kv in m.status[0].values} | {"message": m.status[0].message}),
                             STATUS_QOS)
    for n in (ifa, node):
        ros_executor.add_node(n)
    try:
        _spin_until(ros_executor, lambda: all(p.get_subscription_count() >= 1 for p in pub.values()), WAIT_S, "the ifa_node's subscriptions")
        # 6 fixes before the start (1 Hz, standing: the same position, zero velocity), the start fix at t = 0
        n_before = 7
        for k in range(n_before):
            t_ns = start_ns - (n_before - 1 - k) * 1_000_000_000
            pub["fix"].publish(cv.navsatfix_msg(t_ns, cv.GNSS_FRAME, g.llh[0], g.pos_sigma_m[0]))
            pub["vel"].publish(cv.gnss_vel_msg(t_ns, np.zeros(3), g.vel_sigma_mps[0]))
        _spin_until(ros_executor, lambda: ifa._newest_fix_ns == start_ns and len(ifa._vels) == n_before, WAIT_S, "the early fixes")
        v0 = cv.odometry_values_cov(init.llh[None], init.vel_n_mps[None], init.q_nb[None], datum, None, np.eye(3), np.eye(3), np.eye(3))
        pub["nav"].publish(bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([start_ns]), v0)[0]))
        t_imu = cv.stamps_ns(ss.scenario.start_time_s, imu.t_s)
        for row in cv.imu_rows(cv.MASTER_FRAME, t_imu, imu.omega_radps, imu.f_mps2, 1e-6, 1e-4):
            pub["imu"].publish(bytes(row))
        t_g = cv.stamps_ns(ss.scenario.start_time_s, g.t_s)
        for j in range(3):  # 1, 2, 3 s: epochs (the IMU goes on to 4 s)
            pub["fix"].publish(cv.navsatfix_msg(int(t_g[j]), cv.GNSS_FRAME, g.llh[j], g.pos_sigma_m[j]))
            pub["vel"].publish(cv.gnss_vel_msg(int(t_g[j]), g.vel_n_mps[j], g.vel_sigma_mps[j]))
        _spin_until(ros_executor, lambda: ifa.epochs == 3 and statuses and statuses[-1].get("epochs") == "3", WAIT_S,
                    lambda: f"3 epochs (got {ifa.epochs}, {statuses[-1:]})")
        last = statuses[-1]
        assert last["before_start"] == str(n_before) and last["rejected_fixes"] == "0" and last["unpaired"] == "0", last
        assert not ifa._fixes and not ifa._vels  # nothing left over (their velocities went with them)
    finally:
        for n in (ifa, node):
            ros_executor.remove_node(n)
            n.destroy_node()


# ----------------------------------------------------------------------------- alignment given


def test_given_alignment_integrates_back_to_the_truth(ros_context) -> None:
    """alignment given from the truth (no ifa_node): /master/nav follows /truth/master within what
    the master IMU's errors allow over 5 s; /pos_master/status says GIVEN."""
    from diagnostic_msgs.msg import DiagnosticArray

    from dpos_ros.contract.qos import STATUS_QOS
    from pos_master_node.node import PosMasterNode

    probe = Probe(ros_context)
    for topic in ("/truth/master",):
        from nav_msgs.msg import Odometry

        from dpos_ros.contract.qos import NAV_QOS

        probe.node.create_subscription(Odometry, topic, lambda m, t=topic: probe._got(t, m), NAV_QOS, raw=True)
    master_status: list[str] = []
    probe.node.create_subscription(DiagnosticArray, "/pos_master/status", lambda m: master_status.append(m.status[0].message), STATUS_QOS)
    master = PosMasterNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("duration", value=5.0), Parameter("rate_factor", value=0.0),
        Parameter("alignment", value="given")])
    spinner = Spinner(ros_context, [probe.node, master])
    try:
        ss = master.session
        n_imu = ss.master_imu().t_s.size
        probe.wait(lambda: probe.raw["/session/end"] and len(probe.raw["/master/nav"]) >= n_imu + 1
                   and len(probe.raw["/truth/master"]) >= n_imu + 1, WAIT_S,
                   lambda: f"the session (nav {len(probe.raw['/master/nav'])}, truth {len(probe.raw['/truth/master'])})")
        nav = _odometry(probe.raw["/master/nav"], ss.datum_llh)
        tru = _odometry(probe.raw["/truth/master"], ss.datum_llh)
        np.testing.assert_array_equal(nav.t_ns, tru.t_ns)
        pos = llh_err_m(nav.llh, tru.llh)
        att = np.abs(hpr_error(hpr_from_C_nb(cv.quat_to_dcm(nav.q_nb)), hpr_from_C_nb(cv.quat_to_dcm(tru.q_nb)))) / DEG
        vel = np.abs(nav.vel_n_mps - tru.vel_n_mps)
        # the master IMU's 100 ug and 0.02 deg/h biases over 5 s: 5 mm/s, 1.2 cm, 3e-5 deg (measured: 5.1 mm/s, 3e-5 deg)
        assert pos[0] < 1e-6 and pos.max() < 0.03, pos.max()
        assert vel.max() < 0.01 and att.max() < 1e-3, (vel.max(), att.max())
        assert master_status and master_status[-1] == "GIVEN"
    finally:
        spinner.stop()
