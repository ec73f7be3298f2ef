"""An ifa_node restarted mid-flight in the live IFA loop of test_ifa_loop_live.py (pos_master_node
``device: ros``, ``alignment: ifa``, jittered IMU, data as fast as the relay takes them).

The restarted node has its own Context (its own DDS participant, as a restarted process). It joins
the running session: it takes the latched /dpos/datum, learns from the latched /pos_master/status
that pos_master_node runs and was corrected before (a restart), starts UNALIGNED with its prior
covariance from the next GNSS fix (the master's /master/nav start state is long gone), and its
corrections pass pos_master_node's gates (their covariance is wide); pos_master_node is not held
waiting for it and its navigation stays inside its 3 sigma.

Every wait is bounded; nothing sleeps for a fixed time.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ifa_support import Spinner, llh_err_m  # test/support/ifa_support.py
from jittered_master import jittered_master  # test/support/jittered_master.py
from rclpy.parameter import Parameter

from dpos_core.ifa.mechanization import stamp_s

pytestmark = pytest.mark.ros

DURATION_S = 32.0
RESTART_S = 10.0
TIMEOUT_S = 60.0


def _live() -> Any:
    """test_ifa_loop_live.py as a module (its Probe, driver messages and odometry decoding)."""
    spec = importlib.util.spec_from_file_location("ifa_loop_live", Path(__file__).with_name("test_ifa_loop_live.py"))
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_restarted_ifa_node_starts_from_the_next_fix_and_its_corrections_are_accepted(ros_context, ros_domain_id) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from ifa_node.node import IfaNode
    from pos_master_node.node import PosMasterNode

    live = _live()
    jm = jittered_master(DURATION_S, seed=1)
    probe = live.Probe(ros_context)

    def mk_ifa(ctx: Any) -> Any:
        return IfaNode(context=ctx, parameter_overrides=[Parameter("aircraft_config", value="paper_ifa")])

    def own_context() -> Any:  # an ifa_node process: its own DDS participant
        ctx = Context()
        rclpy.init(context=ctx, domain_id=ros_domain_id, signal_handler_options=SignalHandlerOptions.NO)
        return ctx

    # the first ifa_node in the graph's participant (its own executor, stopped cleanly), as in
    # test_ifa_loop_live.py; the restarted one in its own participant
    contexts: list[Any] = []
    ifa = mk_ifa(ros_context)
    ifa_spinner = Spinner(ros_context, [ifa])
    master = PosMasterNode(context=ros_context, cli_args=live.REMAPS, parameter_overrides=[
        Parameter("device", value="ros"), Parameter("alignment", value="ifa"), Parameter("aircraft_config", value="paper_ifa"),
        Parameter("input_reliability", value="reliable"), Parameter("ring_s", value=600.0)])
    spinner = Spinner(ros_context, [probe.node, master])
    try:
        def matched() -> bool:
            return (all(p.get_subscription_count() >= 1 for p in probe.pubs.values())
                    and all(s.publisher.get_subscription_count() >= 1 for s in master.relay._states)
                    and master.nav_pub.get_subscription_count() >= 2 and ifa.pub_correction.get_subscription_count() >= 2)

        probe.wait(matched, TIMEOUT_S, "the graph's matches")
        msgs = live._driver_messages(jm, live.GNSS_LATENCY_S)

        def received() -> int:
            return sum(st.received for st in master.relay.stats.values())

        def feed(part: list[tuple[int, str, Any]]) -> None:
            for lo in range(0, len(part), live.CHUNK):
                n0, chunk = received(), part[lo:lo + live.CHUNK]
                for _, topic, m in chunk:
                    probe.pubs[topic].publish(m)
                probe.wait(lambda n=n0 + len(chunk): received() >= n, TIMEOUT_S, "the relay to take a chunk", poll_s=0.02)

        t_r = jm.start_ns + int(RESTART_S * 1e9)
        feed([m for m in msgs if m[0] <= t_r])
        n_fix_before = int(((jm.fix_ns > jm.fix_ns[0]) & (jm.fix_ns + int(live.GNSS_LATENCY_S * 1e9) <= t_r)).sum())
        probe.wait(lambda: master.mech is not None and master.mech.corrections >= n_fix_before - 1, TIMEOUT_S,
                   lambda: f"the first ifa_node's corrections ({master.mech.corrections if master.mech else None} of {n_fix_before})")

        ifa_spinner.stop()  # the ifa_node stops (its callbacks finished, the node destroyed) ...
        contexts.append(own_context())  # ... and a new process starts
        ifa = mk_ifa(contexts[0])
        ifa_spinner = Spinner(contexts[0], [ifa])
        probe.wait(lambda: matched() and ifa.datum_llh is not None, TIMEOUT_S,
                   lambda: f"the restarted ifa_node's matches and datum ({ifa.datum_llh})")
        np.testing.assert_array_equal(ifa.datum_llh, master.source.input.datum_llh)  # the session's datum (latched)
        corrections_before = master.mech.corrections
        timeouts_before = master.navigator.hold_timeouts
        n_nav_before = len(probe.raw["/master/nav"])
        n_status_before = len(probe.status["/ifa/status"])
        rest = [m for m in msgs if m[0] > t_r]
        feed(rest)
        n_fix_after = int((jm.fix_ns > t_r).sum())
        # its start fix (and any before it) is skipped; every later one is an epoch
        probe.wait(lambda: ifa.al is not None and ifa.epochs + ifa.before_start >= n_fix_after - 1, TIMEOUT_S,
                   lambda: f"the restarted ifa_node's epochs (started: {ifa.al is not None}, {ifa.epochs} epochs, "
                   f"{ifa.before_start} before its start, of {n_fix_after} fixes; received {ifa.imu_samples} IMU samples,"
                   f" {len(ifa._fixes)} fixes waiting, {ifa.discrepancy_checks + len(ifa._navs)} /master/nav)")
        probe.wait(lambda: master.mech.corrections - corrections_before >= ifa.corrections_published
                   and probe.status["/pos_master/status"][-1].get("corrections") == str(master.mech.corrections), TIMEOUT_S,
                   lambda: f"the master to apply the restarted node's {ifa.corrections_published} corrections "
                   f"({probe.status['/pos_master/status'][-1:]})")
        assert ifa.epochs >= n_fix_after - 4, (ifa.epochs, n_fix_after)

        after = probe.status["/ifa/status"][n_status_before:]
        first = next(s for s in after if s.get("start") == "gnss_fix")
        # UNALIGNED, and its covariance says so: the prior heading sigma of a hypothesis of the bank
        assert first["message"] == "ALIGNING" and first["joined_running_session"] == "true", first
        assert float(first["heading_sigma_deg"]) > 10.0, first
        assert not any(s["message"] == "ALIGNED" for s in after), [s["message"] for s in after]

        master_last = probe.status["/pos_master/status"][-1]
        # the restarted node's corrections passed the gates, none lost; the master was not held waiting for it
        # (a hold unanswered is released after 5 s, counted: a node waiting for a /master/nav costs one at least)
        assert master_last.get("gate_refused", "0") == "0", master_last
        assert master_last["corrections_lost"] == "0" and int(master_last["hold_timeouts"]) == timeouts_before, master_last
        assert master.mech.corrections - corrections_before == ifa.corrections_published > 0
        # not flagged aligned by its own covariance (that of the restarted node's corrections)
        assert master_last["message"] == "UNALIGNED" and float(master_last["heading_sigma_deg"]) > 1.0, master_last

        # /master/nav after the restart: every sample published, inside its 3 sigma
        n_nav = int((jm.imu_ns > t_r).sum())
        probe.wait(lambda: len(probe.raw["/master/nav"]) - n_nav_before >= n_nav - 50, TIMEOUT_S, "the /master/nav after the restart")
        nav = live._odometry(probe.raw["/master/nav"][n_nav_before:], master.source.input.datum_llh)
        t = stamp_s(nav.t_ns, jm.start_ns)
        err = llh_err_m(nav.llh, jm.session.truth("master", t).llh)
        sig = np.sqrt(np.trace(nav.pose_cov[:, :3, :3], axis1=1, axis2=2))
        inside = float(np.mean(err < 3.0 * sig))
        assert inside >= 0.99 and err.max() < 10.0, (inside, float(err.max()), float(sig.min()))
    finally:
        spinner.stop()
        if ifa_spinner.thread.is_alive():
            ifa_spinner.stop()
        for ctx in contexts:
            rclpy.try_shutdown(context=ctx)
