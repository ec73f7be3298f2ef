"""Errors that say what went wrong (issue "the house", item 5), in the nodes and the recorder:

* ifa_node: a rejected GNSS fix is warned about (input and reason) and counted in /ifa/status; a
  shape bug in the filter propagates out of the handler (it is not a rejected fix); a numerical
  failure is an ERROR log and an ERROR status, and the node carries on; a heading hypothesis
  dropped by the core is logged and counted;
* transfer_align_node: a sub-IMU whose smoother fails gets ``failed: <reason>``, the status goes
  to ERROR naming it, the other antenna is estimated and published;
* dpos_ros.io.record: a publisher QoS profile that cannot be stored is a counted, logged warning.

In-process; the ifa_node handlers are called directly (no DDS timing); every wait is bounded.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from repo_paths import REPO

from dpos_core.errors import DposError, NumericalFailure
from dpos_core.ifa.mechanization import initial_state_from_truth
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG
from dpos_ros.contract import conversions as cv

pytestmark = pytest.mark.ros


class FakeLogger:
    """Stands in for a node's rclpy logger: keeps (level, text)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def _log(self, level: str):
        return lambda text, *a, **kw: self.lines.append((level, str(text)))

    def __getattr__(self, level: str):
        if level in ("debug", "info", "warning", "warn", "error", "fatal"):
            return self._log(level)
        raise AttributeError(level)

    def at(self, level: str) -> list[str]:
        return [t for lv, t in self.lines if lv == level]


class StatusTap:
    """Stands in for a status publisher: keeps the published DiagnosticArrays as dicts."""

    def __init__(self) -> None:
        self.sent: list[dict[str, Any]] = []

    def publish(self, arr: Any) -> None:
        st = arr.status[0]
        self.sent.append({kv.key: kv.value for kv in st.values} | {"message": st.message, "level": st.level})


# ----------------------------------------------------------------------------- ifa_node


def _fed_ifa_node(ros_context, monkeypatch, imu_from_s: float = 0.0):
    """An ifa_node fed directly (the test plays pos_master_node): the initial /master/nav at t = 0
    and the IMU of 6 s of paper_ifa from ``imu_from_s`` on. Returns (node, session, logger, status tap)."""
    from ifa_node.node import IfaNode

    ss = SimulatedSession(load_scenario("paper_ifa"), 1, duration_s=6.0)
    imu, datum = ss.master_imu(), ss.datum_llh
    origin = int(cv.stamps_ns(ss.scenario.start_time_s, np.array([0.0]))[0])
    tr = ss.truth("master", np.array([0.0]))
    init = initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, 30.0)
    node = IfaNode(context=ros_context, parameter_overrides=[
        Parameter("scenario", value="paper_ifa"), Parameter("datum", value=[datum[0] / DEG, datum[1] / DEG, float(datum[2])])])
    log, tap = FakeLogger(), StatusTap()
    monkeypatch.setattr(node, "get_logger", lambda: log)
    node.pub_status = tap
    v0 = cv.odometry_values_cov(init.llh[None], init.vel_n_mps[None], init.q_nb[None], datum, None, np.eye(3), np.eye(3), np.eye(3))
    node._on_nav(bytes(cv.odometry_rows(cv.WORLD_FRAME, cv.MASTER_FRAME, np.array([origin]), v0)[0]))
    k = imu.t_s >= imu_from_s
    for row in cv.imu_rows(cv.MASTER_FRAME, cv.stamps_ns(ss.scenario.start_time_s, imu.t_s[k]), imu.omega_radps[k], imu.f_mps2[k], 1e-6, 1e-4):
        node._on_imu(bytes(row))
    return node, ss, log, tap


@pytest.fixture
def ifa(ros_context, monkeypatch):
    """An ifa_node fed directly (the test plays pos_master_node and the GNSS receiver): initial
    /master/nav and 6 s of IMU given; ``fix(j, ...)`` hands GNSS epoch j to the handlers."""
    node, ss, log, tap = _fed_ifa_node(ros_context, monkeypatch)
    g = ss.gnss()
    assert node.al is not None and node.imu_samples == ss.master_imu().t_s.size
    assert not [w for w in log.at("warning") if "after the start state" in w]  # the IMU starts with the state: no warning
    t_g = cv.stamps_ns(ss.scenario.start_time_s, g.t_s)

    def fix(j: int, llh=None) -> None:
        node._on_fix(cv.navsatfix_msg(int(t_g[j]), cv.GNSS_FRAME, g.llh[j] if llh is None else llh, g.pos_sigma_m[j]))
        node._on_vel(cv.gnss_vel_msg(int(t_g[j]), g.vel_n_mps[j], g.vel_sigma_mps[j]))  # the pair is complete: the epoch runs

    node.fix, node.g, node.log, node.tap = fix, g, log, tap
    try:
        yield node
    finally:
        node.destroy_node()


def test_ifa_first_imu_long_after_the_start_state_is_warned(ros_context, monkeypatch) -> None:
    """A replay started before ifa_node subscribed: its first IMU sample is 3 s after the start
    state. The node says so (the navigation integrates across the unmeasured motion) and reports
    the gap in its status."""
    node, _, log, tap = _fed_ifa_node(ros_context, monkeypatch, imu_from_s=3.0)
    try:
        assert node.al is not None
        warned = [w for w in log.at("warning") if "first /master/imu sample after the start state" in w]
        assert len(warned) == 1 and "is 3.000 s after it" in warned[0], log.lines
        node._publish_status()
        assert abs(float(tap.sent[-1]["imu_start_gap_s"]) - 3.0) < 0.011, tap.sent[-1]
    finally:
        node.destroy_node()


def test_ifa_rejected_fix_is_warned_and_counted_in_the_status(ifa) -> None:
    ifa.fix(0)
    assert ifa.epochs == 1
    ifa.fix(1, llh=np.array([np.nan, ifa.g.llh[1, 1], ifa.g.llh[1, 2]]))
    assert ifa.epochs == 1 and ifa.rejected == 1
    warned = [t for t in ifa.log.at("warning") if "rejected" in t]
    assert len(warned) == 1 and warned[0].startswith("GNSS fix rejected (nan)") and "llh is not finite" in warned[0], warned
    st = ifa.tap.sent[-1]
    assert st["rejected_fixes"] == "1" and st["rejected/nan"] == "1" and "llh is not finite" in st["last_rejection"]
    assert st["numerical_failures"] == "0" and st["hypotheses_failed"] == "0" and st["chol_jitter_repairs"] == "0"
    ifa.fix(1)  # the next good fix (same epoch, now valid) is taken
    assert ifa.epochs == 2 and ifa.tap.sent[-1]["epochs"] == "2"


def test_ifa_shape_bug_propagates_and_is_not_a_rejected_fix(ifa, monkeypatch) -> None:
    ifa.fix(0)

    def buggy_update(fix):
        return np.zeros(15) + np.zeros(13)  # a shape bug deep in the filter

    monkeypatch.setattr(ifa.al, "update", buggy_update)
    with pytest.raises(ValueError, match="operands could not be broadcast") as ei:
        ifa.fix(1)
    assert not isinstance(ei.value, DposError)
    assert ifa.rejected == 0 and ifa.numerical_failures == 0 and not [t for t in ifa.log.at("warning") if "rejected" in t]


def test_ifa_numerical_failure_is_an_error_and_the_node_carries_on(ifa, monkeypatch) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    ifa.fix(0)
    assert ifa.tap.sent[-1]["level"] == DiagnosticStatus.WARN  # ALIGNING

    def diverged(fix):
        raise NumericalFailure(f"GNSS fix at t={fix.t_s}: the update failed numerically in every heading hypothesis",
                               what="IFA filter", t_s=fix.t_s)

    real = ifa.al.update
    monkeypatch.setattr(ifa.al, "update", diverged)
    ifa.fix(1)
    errors = ifa.log.at("error")
    assert len(errors) == 1 and errors[0].startswith("IFA filter failed numerically") and "every heading hypothesis" in errors[0]
    st = ifa.tap.sent[-1]
    assert st["level"] == DiagnosticStatus.ERROR and st["message"] == "ALIGNING"
    assert st["numerical_failures"] == "1" and "every heading hypothesis" in st["last_failure"] and st["rejected_fixes"] == "0"
    monkeypatch.setattr(ifa.al, "update", real)
    ifa.fix(2)  # the filter kept its state: the next epoch works and the level is back to normal
    assert ifa.epochs == 2 and ifa.tap.sent[-1]["level"] == DiagnosticStatus.WARN and ifa.tap.sent[-1]["numerical_failures"] == "1"


def test_ifa_dropped_hypothesis_is_logged_and_counted(ifa, monkeypatch) -> None:
    ifa.fix(0)
    victim = ifa.al.hyps[1]

    def diverge(fix):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(victim, "_epoch", diverge)
    ifa.fix(1)
    assert ifa.epochs == 2 and victim not in ifa.al.hyps
    warned = [t for t in ifa.log.at("warning") if "heading hypothesis" in t]
    assert len(warned) == 1 and "+60 deg failed" in warned[0] and "Singular matrix" in warned[0], warned
    assert ifa.tap.sent[-1]["hypotheses_failed"] == "1" and ifa.tap.sent[-1]["numerical_failures"] == "0"


# ----------------------------------------------------------------------------- transfer_align_node


BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
SECONDS = 10.0


def test_ta_failing_sub_imu_smoother_is_an_error_and_the_other_antenna_is_estimated(ros_context, tmp_path: Path, monkeypatch) -> None:
    """Two wings; the left sub-IMU's smoother fails numerically (injected in-process): ant_l is
    ``failed: ...``, the status is ERROR naming sub_l, ant_r is estimated, written and published."""
    import concurrent.futures as cf

    from diagnostic_msgs.msg import DiagnosticStatus
    from nav_msgs.msg import Odometry
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile
    from ros_wait import spin_until, stop_and_destroy  # test/support/ros_wait.py
    from std_srvs.srv import Trigger

    import transfer_align_node.node as tan
    from dpos_core.ta import pipeline
    from dpos_ros.contract.qos import DATUM_QOS, NAV_QOS, SENSOR_QOS
    from dpos_ros.contract.topics import message_class
    from dpos_ros.io import bag

    real_run = pipeline.run

    def run(imu, master, install, *a, **kw):
        if install.lever_arm_m[1] > 0:  # the left wing (FLU y > 0)
            raise NumericalFailure("the smoothed covariance lost positive definiteness (injected)", what="URTSS smoother")
        return real_run(imu, master, install, *a, **kw)

    monkeypatch.setattr(pipeline, "run", run)
    monkeypatch.setattr(tan, "_pool", lambda n: cf.ThreadPoolExecutor(max_workers=max(1, n)))  # in-process: the patch applies

    def keep_all(qos: QoSProfile) -> QoSProfile:
        if qos.durability.name == "TRANSIENT_LOCAL":
            return qos
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=qos.reliability, durability=qos.durability)

    raw = bag.read_raw(BAG, ["/dpos/datum", "/master/nav", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu"])
    t_first = raw["/master/nav"][1][0]
    msgs = {topic: [d for t, d in zip(t_log, data) if topic == "/dpos/datum" or t - t_first <= SECONDS * 1e9]
            for topic, (_, t_log, data) in raw.items()}
    qos = {"/dpos/datum": DATUM_QOS, "/master/nav": NAV_QOS, "/sub_imu/sub_r/imu": SENSOR_QOS, "/sub_imu/sub_l/imu": SENSOR_QOS}
    types = {"/dpos/datum": "sensor_msgs/msg/NavSatFix", "/master/nav": "nav_msgs/msg/Odometry"}

    executor = MultiThreadedExecutor(num_threads=3, context=ros_context)
    ta = tan.TransferAlignNode(context=ros_context, parameter_overrides=[
        Parameter("method", value="urtss"), Parameter("aircraft_config", value="paper_su_pair"),
        Parameter("output_dir", value=str(tmp_path)), Parameter("finalize_timeout_s", value=5.0)])
    log = FakeLogger()
    monkeypatch.setattr(ta, "get_logger", lambda: log)
    src = Node("fake_devices", context=ros_context)
    odoms: dict[str, list[Any]] = {"ant_r": [], "ant_l": []}
    watcher = Node("antenna_watcher", context=ros_context)
    for a in odoms:
        watcher.create_subscription(Odometry, f"/antenna/{a}/odom", odoms[a].append, keep_all(NAV_QOS))
    pubs = {t: src.create_publisher(message_class(types.get(t, "sensor_msgs/msg/Imu")), t, keep_all(q)) for t, q in qos.items()}
    client = src.create_client(Trigger, "/transfer_align_node/finalize")
    for n in (ta, src, watcher):
        executor.add_node(n)
    status_files = lambda: list(tmp_path.glob("session_*/status.json"))  # noqa: E731
    try:
        spin_until(executor, lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), 30.0, "transfer_align_node's subscriptions")
        for t, p in pubs.items():
            for d in msgs[t]:
                p.publish(d)

        def buffered() -> bool:
            with ta._lock:
                return all(t in ta._streams and ta._streams[t].count == len(v) for t, v in msgs.items())

        spin_until(executor, buffered, 120.0, lambda: f"buffering; node has { {t: s.count for t, s in ta._streams.items()} }")
        spin_until(executor, client.service_is_ready, 30.0, "the finalize service")
        fut = client.call_async(Trigger.Request())
        spin_until(executor, fut.done, 30.0, "the finalize reply")
        assert fut.result().success, fut.result().message
        spin_until(executor, lambda: bool(status_files()) and not ta._finalizing, 120.0, lambda: f"products; {ta._progress}")
        n_r = sum(1 for _ in (status_files()[0].parent / "ant_r.csv").open()) - 2
        spin_until(executor, lambda: len(odoms["ant_r"]) == n_r, 30.0, lambda: f"{n_r} ant_r poses ({len(odoms['ant_r'])} so far)")
        tap = StatusTap()
        ta._status_pub = tap
        ta._publish_status()
    finally:
        stop_and_destroy(executor, (watcher, src, ta))
    st = json.loads(status_files()[0].read_text())
    assert st["antennas"]["ant_r"] == "estimated", st
    assert st["antennas"]["ant_l"].startswith("failed: NumericalFailure: the smoothed covariance lost positive definiteness"), st
    assert any("sub-IMU sub_l" in w and "failed" in w for w in st["warnings"]), st["warnings"]
    assert st["chol_jitter_repairs"] == {"ant_r": 0}
    assert n_r > 900 and odoms["ant_l"] == []  # ant_r's poses at the sub-IMU rate; nothing for the failed antenna
    s = tap.sent[-1]
    assert s["level"] == DiagnosticStatus.ERROR and s["failed"] == "sub_l" and "NumericalFailure" in s["last_error"], s
    assert "failed sub-IMU(s) sub_l (ant_l)" in s["message"] and s["chol_jitter_repairs"] == "0", s
    errors = log.at("error")
    assert any(e.startswith("sub-IMU sub_l: the urtss smoother failed: NumericalFailure") and "Traceback" in e for e in errors), errors


# ----------------------------------------------------------------------------- dpos_ros.io.record


def test_record_unstorable_qos_profile_is_a_counted_warning(ros_context, tmp_path: Path, monkeypatch) -> None:
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    from dpos_ros.io import record

    def broken(p):
        raise ValueError("unknown history policy 7")

    monkeypatch.setattr(record, "_rosbags_qos", broken)
    node = Node("recorder_under_test", context=ros_context)
    rec = record.BagRecorder(node, tmp_path / "rec", ["/dpos_test/imu"])
    log = FakeLogger()
    rec._log = log
    try:
        rec._subscribe("/dpos_test/imu", "sensor_msgs/msg/Imu", [QoSProfile(depth=5), QoSProfile(depth=7)])
        assert "/dpos_test/imu" in rec.types  # recorded all the same
    finally:
        rec.close()
        node.destroy_node()
    assert rec.problems == {"offered_qos": 2}
    warned = log.at("warning")
    assert len(warned) == 1 and warned[0].startswith("/dpos_test/imu: a publisher's QoS profile is not stored") and \
        "ValueError: unknown history policy 7" in warned[0], warned
