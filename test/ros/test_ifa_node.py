"""The master loop of the graph: pos_master_node (mechanization with IFA feedback) + ifa_node (issue #5).

* dpos_ros.master_nav: the master mechanization with corrections equals the aligner's closed-loop
  strapdown (no ROS);
* in-process graph (one Context, a MultiThreadedExecutor): the simulated master device + the
  mechanization + ifa_node reach ALIGNED, /master/nav agrees with the truth, and the corrections
  equal dpos_core.ifa.pipeline.run on the same data (the shadow design is deterministic);
* bad GNSS input is rejected with a warning and leaves the filter undisturbed;
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
from rclpy.parameter import Parameter

from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.model import GnssFix, IfaConfig
from dpos_core.ifa.pipeline import InFlightAligner, run
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import GnssSeries, SimulatedSession
from dpos_core.strapdown import NavState
from dpos_ros import conversions as cv
from dpos_ros.master_nav import MasterMechanization, initial_state_from_truth, stamp_s

pytestmark = pytest.mark.ros

DEG = np.pi / 180.0
R_EARTH_M = 6.378e6
GRAPH_TIMEOUT_S = 120.0
WAIT_S = 30.0


def _initial(ss: SimulatedSession, heading_err_deg: float) -> NavState:
    tr = ss.truth("master", np.array([0.0]))
    return initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, heading_err_deg)


def _llh_err_m(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Approximate position difference [m] of llh arrays (..., 3)."""
    d = np.asarray(a) - np.asarray(b)
    return np.linalg.norm(d * np.array([R_EARTH_M, R_EARTH_M * np.cos(0.7), 1.0]), axis=-1)


# ----------------------------------------------------------------------------- no ROS


def test_master_mechanization_equals_the_aligner_closed_loop() -> None:
    """Random IMU batches, the master running ahead of delayed corrections and bias compensations:
    after each correction the re-integrated navigation equals InFlightAligner's (and run's)."""
    ss = SimulatedSession(load_scenario("paper_ifa"), 3, duration_s=40.0)
    imu, g = ss.master_imu(), ss.gnss()
    init = _initial(ss, 60.0)
    lever = ss.scenario.aircraft.gnss_lever_arm_m
    cfg = IfaConfig(use_reported_sigma=True)
    res = run(imu, g, lever, cfg, "add2", init)
    al = InFlightAligner(init, lever, cfg, "add2", float(np.median(np.diff(imu.t_s))))
    mm = MasterMechanization(init, ring_s=5.0)
    rng = np.random.default_rng(0)
    n, i, ia = imu.t_s.size, 0, 0
    fake_bias = (np.array([1e-6, -2e-6, 3e-6]), np.array([1e-4, 2e-4, -3e-4]))
    for j in range(g.t_s.size):
        fix = GnssFix(g.t_s[j], g.llh[j], g.pos_sigma_m[j], g.vel_n_mps[j], g.vel_sigma_mps[j])
        i1 = int(np.searchsorted(imu.t_s, fix.t_s + 0.005, side="right"))
        al.propagate(imu.t_s[ia:i1], imu.omega_radps[ia:i1], imu.f_mps2[ia:i1])
        ia = i1
        al.update(fix)
        if j == 20:  # a bias compensation from here on, in the aligner and in the master
            al.model.gyro_bias_comp, al.model.accel_bias_comp = fake_bias
        target = min(n, i1 + int(rng.integers(1, 150)))
        while i < target:
            b = min(int(rng.integers(1, 40)), target - i)
            mm.add(imu.t_s[i:i + b], imu.omega_radps[i:i + b], imu.f_mps2[i:i + b])
            i += b
        if j == 20:
            assert mm.set_bias(al.nav.t_s, *fake_bias) is None
        assert mm.correct(al.nav) is None
        nav = mm.nav()
        k = np.searchsorted(nav.t_s, al.nav.t_s - 1e-9)
        assert abs(nav.t_s[k] - al.nav.t_s) < 1e-9
        assert _llh_err_m(nav.llh[k], al.nav.llh) < 1e-9
        if j < 20:  # no bias yet: the stored samples up to the next epoch are run()'s too
            k1 = int(np.searchsorted(nav.t_s, g.t_s[j + 1] - 1e-9))
            assert k1 > k + 1
            r = np.searchsorted(res.t_s, nav.t_s[k:k1])
            assert np.all(_llh_err_m(nav.llh[k:k1], res.llh[r]) < 1e-9)
            assert np.abs(nav.q_nb[k:k1] - res.q_nb[r]).max() < 1e-12
            assert np.abs(nav.vel_n_mps[k:k1] - res.vel_n_mps[r]).max() < 1e-9
    if i < n:
        mm.add(imu.t_s[i:], imu.omega_radps[i:], imu.f_mps2[i:])
    al.propagate(imu.t_s[ia:], imu.omega_radps[ia:], imu.f_mps2[ia:])
    s, f = mm.state, al.nav
    assert s.t_s == f.t_s and _llh_err_m(s.llh, f.llh) < 1e-9
    assert np.abs(s.q_nb - f.q_nb).max() < 1e-12 and np.abs(s.vel_n_mps - f.vel_n_mps).max() < 1e-9
    assert mm.corrections == g.t_s.size
    # the ring keeps ~ring_s seconds; an old correction is refused with a reason, nothing changes
    assert "not a stored IMU sample" in mm.correct(NavState(1.0, f.q_nb, f.vel_n_mps, f.llh))
    # bad IMU input: dropped with warnings, good samples kept
    t_last = mm.t_s
    _, keep, warnings = mm.add([t_last + 0.01, t_last + 0.01, t_last + 0.005, t_last + 0.02],
                               [[0, 0, 0], [0, 0, 0], [0, 0, 0], [np.nan, 0, 0]], np.zeros((4, 3)))
    assert keep.tolist() == [True, False, False, False]
    assert len(warnings) == 3 and "duplicate" in " ".join(warnings) and "out-of-order" in " ".join(warnings)
    assert "non-finite" in " ".join(warnings)


# ----------------------------------------------------------------------------- graph helpers


class Probe:
    """A test node's raw subscriptions: /ifa/correction, /master/nav, /ifa/status, /session/end."""

    def __init__(self, context: Any, nav: bool = True) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.node import Node
        from std_msgs.msg import Header

        from dpos_ros.qos import NAV_QOS, STATUS_QOS

        self.node = Node("ifa_probe", context=context)
        self.raw: dict[str, list[bytes]] = defaultdict(list)
        self.statuses: list[Any] = []
        self.changed = threading.Condition()
        topics = ["/ifa/correction", "/session/end"] + (["/master/nav"] if nav else [])
        for topic in topics:
            cls = Header if topic == "/session/end" else Odometry
            self.node.create_subscription(cls, topic, lambda m, t=topic: self._got(t, m), NAV_QOS, raw=True)
        self.node.create_subscription(DiagnosticArray, "/ifa/status", lambda m: self._got("/ifa/status", m), STATUS_QOS)

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


class Spinner:
    """A MultiThreadedExecutor spinning the nodes in a background thread."""

    def __init__(self, context: Any, nodes: list[Any]) -> None:
        from rclpy.executors import MultiThreadedExecutor

        self.executor = MultiThreadedExecutor(num_threads=4, context=context)
        self.nodes = nodes
        for n in nodes:
            self.executor.add_node(n)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def stop(self) -> None:
        for n in self.nodes:
            if hasattr(n, "device") and n.device is not None:
                n.device.stop()
        self.executor.shutdown(timeout_sec=5.0)
        self.thread.join(10.0)
        for n in self.nodes:
            n.destroy_node()


def _odometry(raws: list[bytes], datum: np.ndarray) -> cv.OdometryBlock:
    from dpos_ros import cdr

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
        init = _initial(ss, float(ss.scenario.ifa["initial_heading_error_deg"]))
        res = run(imu, gnss, ss.scenario.aircraft.gnss_lever_arm_m, ifa.core_config, "add2", init)
        assert res.aligned and res.status.tolist().count(1) > 0
        t_corr = stamp_s(corr.t_ns, origin)
        np.testing.assert_array_equal(t_corr, gnss.t_s)
        k = np.searchsorted(res.t_s, t_corr)
        pos_err = _llh_err_m(corr.llh, res.llh[k])
        assert pos_err.max() < 1e-6, (np.flatnonzero(pos_err > 1e-6), pos_err.max())
        assert np.abs(corr.vel_n_mps - res.vel_n_mps[k]).max() < 1e-9
        assert np.min([np.abs(corr.q_nb - res.q_nb[k]).max(axis=1), np.abs(corr.q_nb + res.q_nb[k]).max(axis=1)], axis=0).max() < 1e-9
        # the master's mechanization after the last correction is the aligner's strapdown
        s = master.mech.state
        assert s.t_s == pytest.approx(res.t_s[-1], abs=1e-9)
        assert _llh_err_m(s.llh, res.final.llh) < 1e-6
        assert np.abs(s.vel_n_mps - res.final.vel_n_mps).max() < 1e-9
        # /master/nav: the initial state first, then one per IMU sample; at the end within the alignment accuracy
        nav = _odometry(probe.raw["/master/nav"], datum)
        t_nav = stamp_s(nav.t_ns, origin)
        assert t_nav[0] == 0.0 and np.array_equal(t_nav[1:], imu.t_s)
        truth = ss.truth("master", t_nav[-1:])
        herr = hpr_error(hpr_from_C_nb(cv.quat_to_dcm(nav.q_nb[-1])), hpr_from_C_nb(truth.C_nb[0])) / DEG
        assert abs(herr[0]) < 0.05 and np.all(np.abs(herr[1:]) < 0.02), herr
        assert _llh_err_m(nav.llh[-1], truth.llh[0]) < 3.0
        # unaligned flag: the heading sigma of the first nav is the prior's, of the last the filter's
        sig_h = np.sqrt(nav.pose_cov[[0, -1], 5, 5]) / DEG
        assert sig_h[0] == pytest.approx(100.0) and sig_h[1] < 0.1
        print(f"graph {GRAPH_DURATION_S:g} s session: {n_fix} corrections, aligned at {res.aligned_t_s} s, "
              f"final heading error {herr[0]:.4f} deg, corrections == run() to {pos_err.max():.2e} m, wall {wall_s:.1f} s")
    finally:
        spinner.stop()
