"""An ifa_node restarted mid-flight in the live IFA loop of test_ifa_loop_live.py (pos_master_node
``device: ros``, ``alignment: ifa``, jittered IMU, data as fast as the relay takes them).

The restarted node is a new process started from its console script (``ifa_node``), as a restart
on the aircraft is: its own DDS participant, and the middleware profile its ``main()`` applies
(``dpos_ros.io.flow.use_device_fastdds_profile``: reader resource limits unlimited). It joins the
running session: it takes the latched /dpos/datum, learns from the latched /pos_master/status
that pos_master_node runs and was corrected before (a restart), starts UNALIGNED with its prior
covariance from the next GNSS fix (the master's /master/nav start state is long gone), and its
corrections pass pos_master_node's gates (their covariance is wide); pos_master_node is not held
waiting for it and its navigation stays inside its 3 sigma. Observed through its topics only
(/ifa/status, /ifa/correction).

Early (10 s of data) and late: 54 s of data, more messages (about 5700 on /master/imu and on
/master/nav) than Fast DDS's default reader resource limit (``max_samples`` 5000). A VOLATILE reader
that matches a writer counts every sequence number the writer sent before it as missing, and
Fast DDS refuses every sample while that count reaches ``max_samples`` (DataReaderHistory::
can_change_be_added_nts): with the default limits the restarted node got none of /master/imu and
/master/nav (docs/reliability.md, G13). The node's own profile lifts the limit; the late case
keeps it so.

The data go as fast as the relay takes them up to the restart, at the pace of their stamps after it.
Every wait is bounded; nothing sleeps for a fixed time.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ifa_support import Spinner, llh_err_m  # test/support/ifa_support.py
from jittered_master import jittered_master  # test/support/jittered_master.py
from rclpy.parameter import Parameter

from dpos_core.ifa.mechanization import stamp_s
from dpos_core.units import DEG
from dpos_ros.contract import topics as T

pytestmark = pytest.mark.ros

EXE = Path(sys.executable).parent
TIMEOUT_S = 60.0
#: (flight duration, restart) [s of data]: early; late, after more than 5000 messages on each stream
CASES = [(24.0, 10.0), (68.0, 54.0)]


def _live() -> Any:
    """test_ifa_loop_live.py as a module (its Probe, driver messages and odometry decoding)."""
    spec = importlib.util.spec_from_file_location("ifa_loop_live", Path(__file__).with_name("test_ifa_loop_live.py"))
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _start_ifa_process(log: Path) -> subprocess.Popen:
    """The console script ``ifa_node`` (on this test session's ROS_DOMAIN_ID), with the middleware
    profile of its ``main()``: no Fast DDS profile file of the caller's environment."""
    env = {k: v for k, v in os.environ.items() if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")}
    with log.open("w") as out:
        return subprocess.Popen([str(EXE / "ifa_node"), "--ros-args", "-p", "aircraft_config:=paper_ifa"], env=env, stdout=out,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _stop(p: subprocess.Popen) -> int:
    if p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
    try:
        return p.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        return p.wait(10)


def _tail(log: Path, n: int = 15) -> str:
    return "\n".join(log.read_text(errors="replace").splitlines()[-n:]) if log.is_file() else ""


@pytest.mark.parametrize(("duration_s", "restart_s"), CASES, ids=["early", "late"])
def test_a_restarted_ifa_node_starts_from_the_next_fix_and_its_corrections_are_accepted(duration_s: float, restart_s: float,
                                                                                         ros_context, tmp_path: Path) -> None:
    from ifa_node.node import IfaNode
    from pos_master_node.node import PosMasterNode

    live = _live()
    jm = jittered_master(duration_s, seed=1)
    probe = live.Probe(ros_context)
    log = tmp_path / "ifa_node_restarted.log"
    proc: subprocess.Popen | None = None

    # the first ifa_node in the graph's participant (its own executor, stopped cleanly), as in test_ifa_loop_live.py
    ifa = IfaNode(context=ros_context, parameter_overrides=[Parameter("aircraft_config", value="paper_ifa")])
    ifa_spinner = Spinner(ros_context, [ifa])
    master = PosMasterNode(context=ros_context, cli_args=live.REMAPS, parameter_overrides=[
        Parameter("device", value="ros"), Parameter("alignment", value="ifa"), Parameter("aircraft_config", value="paper_ifa"),
        Parameter("input_reliability", value="reliable"), Parameter("ring_s", value=600.0)])
    spinner = Spinner(ros_context, [probe.node, master])
    try:
        def relay_matched() -> bool:  # the driver -> relay, and the relay's outputs to an ifa_node
            return (all(p.get_subscription_count() >= 1 for p in probe.pubs.values())
                    and all(s.publisher.get_subscription_count() >= 1 for s in master.relay._states)
                    and master.nav_pub.get_subscription_count() >= 2)

        probe.wait(lambda: relay_matched() and ifa.pub_correction.get_subscription_count() >= 2, TIMEOUT_S, "the graph's matches")
        msgs = live._driver_messages(jm, live.GNSS_LATENCY_S)

        def received() -> int:
            return sum(st.received for st in master.relay.stats.values())

        def feed(part: list[tuple[int, str, Any]]) -> None:
            for lo in range(0, len(part), live.CHUNK):
                n0, chunk = received(), part[lo:lo + live.CHUNK]
                for _, topic, m in chunk:
                    probe.pubs[topic].publish(m)
                probe.wait(lambda n=n0 + len(chunk): received() >= n, TIMEOUT_S, "the relay to take a chunk", poll_s=0.02)

        t_r = jm.start_ns + int(restart_s * 1e9)
        feed([m for m in msgs if m[0] <= t_r])
        n_fix_before = int(((jm.fix_ns > jm.fix_ns[0]) & (jm.fix_ns + int(live.GNSS_LATENCY_S * 1e9) <= t_r)).sum())
        probe.wait(lambda: master.mech is not None and master.mech.corrections >= n_fix_before - 1, TIMEOUT_S,
                   lambda: f"the first ifa_node's corrections ({master.mech.corrections if master.mech else None} of {n_fix_before})")
        imu_relayed = master.relay.stats[T.MASTER_IMU].relayed
        ifa_spinner.stop()  # the ifa_node stops (its callbacks finished, the node destroyed) ...
        n_status_before = len(probe.status["/ifa/status"])
        proc = _start_ifa_process(log)  # ... and a new process starts

        def new_status() -> list[dict[str, str]]:  # (a status of the first node still on its way started from /master/nav)
            return [s for s in probe.status["/ifa/status"][n_status_before:] if s.get("start") != "/master/nav"]

        def new_last() -> dict[str, str]:
            st = new_status()
            return st[-1] if st else {}

        # matched: the relay's outputs (the only /master/imu reader), its /ifa/status and its /ifa/correction
        # at pos_master_node
        probe.wait(lambda: proc.poll() is None and relay_matched() and bool(new_status())
                   and master.count_publishers(T.IFA_CORRECTION) >= 1, TIMEOUT_S,
                   lambda: f"the restarted ifa_node's matches (exit {proc.poll()}; {new_last()}; log:\n{_tail(log)})")
        corrections_before = master.mech.corrections
        n_corr_before = len(probe.raw["/ifa/correction"])  # (the new node publishes none before the data go on)
        timeouts_before = master.navigator.hold_timeouts
        n_nav_before = len(probe.raw["/master/nav"])
        # the rest of the flight at the pace of its stamps, as a restarted node gets it in flight (as fast as
        # possible, a fix can reach the other process more than outage_wait_s after the IMU around it: the
        # writers here lack the short heartbeat of the nodes' own profile, a lost message waits for the next one)
        rest = [m for m in msgs if m[0] > t_r]
        t_wall, t0_ns = time.monotonic(), rest[0][0]
        for t_ns, topic, m in rest:
            due = t_wall + (t_ns - t0_ns) * 1e-9
            with probe.changed:  # a bounded wait on the driver's clock
                while (left := due - time.monotonic()) > 0:
                    probe.changed.wait(left)
            probe.pubs[topic].publish(m)
        n_fix_after = int((jm.fix_ns > t_r).sum())
        n_imu_after = int((jm.imu_ns > t_r).sum())

        def handled() -> int:  # its start fix (and any before it) is skipped; every later one is an epoch
            st = new_last()
            return int(st.get("epochs", 0)) + int(st.get("before_start", 0)) if st.get("start") == "gnss_fix" else 0

        probe.wait(lambda: handled() >= n_fix_after - 1, TIMEOUT_S,
                   lambda: f"the restarted ifa_node's epochs ({handled()} of {n_fix_after} fixes handled; its status {new_last()};"
                   f" /master/imu relayed before the restart {imu_relayed}; log:\n{_tail(log)})")
        last = new_last()
        # it got the remaining flight: every IMU sample after the restart up to its last epoch's fix (its
        # status is published per epoch), none dropped
        n_imu_done = int(((jm.imu_ns > t_r) & (jm.imu_ns <= int(last["fixes_done_ns"]))).sum())
        assert int(last["imu_samples"]) >= n_imu_done and last["imu_dropped"] == "0", (last, n_imu_done)

        def corrections_new() -> int:
            return len(probe.raw["/ifa/correction"]) - n_corr_before

        probe.wait(lambda: master.mech.corrections - corrections_before >= corrections_new()
                   and probe.status["/pos_master/status"][-1].get("corrections") == str(master.mech.corrections), TIMEOUT_S,
                   lambda: f"the master to apply the restarted node's {corrections_new()} corrections "
                   f"({probe.status['/pos_master/status'][-1:]})")
        assert int(last["epochs"]) >= n_fix_after - 4, (last, n_fix_after)

        after = new_status()
        first = next(s for s in after if s.get("start") == "gnss_fix")
        # UNALIGNED, and its covariance says so: the prior heading sigma of a hypothesis of the bank
        assert first["message"] == "ALIGNING" and first["joined_running_session"] == "true", first
        assert float(first["heading_sigma_deg"]) > 10.0, first
        d = master.source.input.datum_llh
        assert first["datum_deg"] == f"{d[0] / DEG:.10f} {d[1] / DEG:.10f} {d[2]:.4f}", first  # the session's (latched)
        assert not any(s["message"] == "ALIGNED" for s in after), [s["message"] for s in after]

        master_last = probe.status["/pos_master/status"][-1]
        # the restarted node's corrections passed the gates, none lost; the master was not held waiting for it
        # (a hold unanswered is released after 5 s, counted: a node waiting for a /master/nav costs one at least)
        assert master_last.get("gate_refused", "0") == "0", master_last
        assert master_last["corrections_lost"] == "0" and int(master_last["hold_timeouts"]) == timeouts_before, master_last
        assert master.mech.corrections - corrections_before == corrections_new() > 0
        # not flagged aligned by its own covariance (that of the restarted node's corrections)
        assert master_last["message"] == "UNALIGNED" and float(master_last["heading_sigma_deg"]) > 1.0, master_last

        # /master/nav after the restart: every sample published, inside its 3 sigma
        probe.wait(lambda: len(probe.raw["/master/nav"]) - n_nav_before >= n_imu_after - 50, TIMEOUT_S, "the /master/nav after the restart")
        nav = live._odometry(probe.raw["/master/nav"][n_nav_before:], master.source.input.datum_llh)
        t = stamp_s(nav.t_ns, jm.start_ns)
        err = llh_err_m(nav.llh, jm.session.truth("master", t).llh)
        sig = np.sqrt(np.trace(nav.pose_cov[:, :3, :3], axis1=1, axis2=2))
        inside = float(np.mean(err < 3.0 * sig))
        print(f"\nrestart at {restart_s:g} s of {duration_s:g} s ({imu_relayed} /master/imu relayed before): the restarted node got "
              f"{last['imu_samples']} of {n_imu_after} IMU samples, {last['epochs']} epochs of {n_fix_after} fixes, "
              f"{corrections_new()} corrections applied; /master/nav after the restart {err.max():.2f} m max, {inside:.3f} inside 3 sigma")
        assert inside >= 0.99 and err.max() < 10.0, (inside, float(err.max()), float(sig.min()))
        assert _stop(proc) == 0, _tail(log)
    finally:
        if proc is not None:
            _stop(proc)
        spinner.stop()
        if ifa_spinner.thread.is_alive():
            ifa_spinner.stop()


def test_an_ifa_node_that_gets_no_imu_of_a_published_stream_says_why(ros_context, ros_domain_id) -> None:
    """/master/imu has a publisher but none of its samples reaches the node (what a late reader with
    Fast DDS's default resource limits sees, module docstring; here the publisher sends nothing,
    which the node cannot tell apart), while GNSS fixes come: the node says why it cannot start,
    once (status ``imu_starved``, level WARN)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import Imu, NavSatFix

    from dpos_ros.contract import conversions as cv
    from dpos_ros.contract.qos import SENSOR_QOS
    from ifa_node.node import IMU_STARVED_S, IfaNode

    probe = _live().Probe(ros_context)  # its /ifa/status log
    pub_imu = probe.node.create_publisher(Imu, T.MASTER_IMU, SENSOR_QOS)
    pub_fix = probe.node.create_publisher(NavSatFix, T.GNSS_FIX, SENSOR_QOS)
    spinner = Spinner(ros_context, [probe.node])
    ctx = Context()  # its own participant, as a restarted process
    rclpy.init(context=ctx, domain_id=ros_domain_id, signal_handler_options=SignalHandlerOptions.NO)
    ifa = IfaNode(context=ctx, parameter_overrides=[Parameter("aircraft_config", value="paper_ifa")])
    ifa_spinner = Spinner(ctx, [ifa])
    try:
        probe.wait(lambda: pub_imu.get_subscription_count() >= 1 and pub_fix.get_subscription_count() >= 1, TIMEOUT_S,
                   "the node's subscriptions")
        t0_ns, t_start = 1_700_000_000_000_000_000, time.monotonic()
        k = 0
        while not ifa.imu_starved and time.monotonic() - t_start < IMU_STARVED_S + 20.0:  # a fix per 0.1 s of wall time
            k += 1
            pub_fix.publish(cv.navsatfix_msg(t0_ns + k * 1_000_000_000, cv.GNSS_FRAME, np.array([0.7, 2.0, 1000.0]), np.ones(3)))
            with probe.changed:  # (a bounded pause on the driver's clock)
                probe.changed.wait(0.1)
        assert ifa.imu_starved and ifa.imu_samples == 0, (ifa.imu_starved, ifa.imu_samples, k)
        assert time.monotonic() - t_start >= IMU_STARVED_S  # not before
        probe.wait(lambda: any(s.get("imu_starved") == "true" for s in probe.status["/ifa/status"]), TIMEOUT_S, "the status")
        st = next(s for s in probe.status["/ifa/status"] if s.get("imu_starved") == "true")
        assert st["message"] == "WAITING" and st["imu_samples"] == "0", st
        assert not any("imu_starved" in s for s in probe.status["/ifa/status"][:1]), probe.status["/ifa/status"][:1]
    finally:
        ifa_spinner.stop()
        spinner.stop()
        rclpy.try_shutdown(context=ctx)
