"""Measurement (not a test): restart pos_master_node (``master``) or ifa_node (``ifa``) mid-flight in the
live IFA loop of test_ifa_loop_live.py (``device: ros``, jittered IMU, data as fast as the relay takes
them, or at the pace of the stamps after the restart with RT=1) and print the restarted graph's
/master/nav error against the truth, its 3-D sigma and the share inside 3 sigma per 5 s, and the
nodes' last statuses (docs/reliability.md, G12).

    .venv/bin/python test/nodes/restart_measure.py master   # env: DUR (130 s), TR (restart, 95 s), DATUM=1, RT=1, DOM
    .venv/bin/python test/nodes/restart_measure.py ifa      # the restarted ifa_node has its own Context (a new process)

The restart removes the node from the executor and destroys it after a pause (a measurement, not a
test: a callback still running may fail; rerun then).
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "test" / "support")]


def main(which: str) -> None:
    import rclpy
    from ifa_support import Spinner, llh_err_m
    from jittered_master import jittered_master
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from dpos_core.ifa.mechanization import stamp_s
    from ifa_node.node import IfaNode
    from pos_master_node.node import PosMasterNode

    spec = importlib.util.spec_from_file_location("live", ROOT / "test" / "nodes" / "test_ifa_loop_live.py")
    assert spec is not None and spec.loader is not None
    live: Any = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(live)
    dur, t_restart_s = float(os.environ.get("DUR", 130)), float(os.environ.get("TR", 95))
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ.get("DOM", 91)), signal_handler_options=SignalHandlerOptions.NO)
    jm = jittered_master(dur, seed=1)
    g0 = jm.gnss.llh[0]
    datum_param = [Parameter("datum", value=[float(np.rad2deg(g0[0])), float(np.rad2deg(g0[1])), float(g0[2])])]

    def mk_ifa(c: Any = ctx) -> Any:
        return IfaNode(context=c, parameter_overrides=[Parameter("aircraft_config", value="paper_ifa")])

    def mk_master() -> Any:
        return PosMasterNode(context=ctx, cli_args=live.REMAPS, parameter_overrides=[
            Parameter("device", value="ros"), Parameter("alignment", value="ifa"), Parameter("aircraft_config", value="paper_ifa"),
            Parameter("input_reliability", value="reliable"), Parameter("ring_s", value=600.0)]
            + (datum_param if os.environ.get("DATUM") else []))

    probe = live.Probe(ctx)
    ifa, master = mk_ifa(), mk_master()
    sp = Spinner(ctx, [probe.node, ifa, master])
    probe.wait(lambda: all(p.get_subscription_count() >= 1 for p in probe.pubs.values())
               and master.nav_pub.get_subscription_count() >= 2 and ifa.pub_correction.get_subscription_count() >= 2, 60.0,
               "matches")
    msgs = live._driver_messages(jm, live.GNSS_LATENCY_S)
    t_r = jm.start_ns + int(t_restart_s * 1e9)

    def feed(part: list[tuple[int, str, Any]]) -> None:
        def received() -> int:
            return sum(st.received for st in master.relay.stats.values())
        for lo in range(0, len(part), 50):
            n0, chunk = received(), part[lo:lo + 50]
            for _, topic, m in chunk:
                probe.pubs[topic].publish(m)
            probe.wait(lambda n=n0 + len(chunk): received() >= n, 120, "relay", poll_s=0.02)

    feed([m for m in msgs if m[0] <= t_r])
    time.sleep(3.0)
    print("before the restart: master", probe.status["/pos_master/status"][-1].get("message"),
          "ifa", probe.status["/ifa/status"][-1].get("message"), flush=True)
    if which == "ifa":
        sp.executor.remove_node(ifa)
        sp.nodes.remove(ifa)
        time.sleep(0.5)
        ifa.destroy_node()
        ctx2 = Context()  # its own DDS participant, as a restarted process has
        rclpy.init(context=ctx2, domain_id=int(os.environ.get("DOM", 91)), signal_handler_options=SignalHandlerOptions.NO)
        ifa = mk_ifa(ctx2)
        sp2 = Spinner(ctx2, [ifa])
        probe.wait(lambda: ifa.pub_correction.get_subscription_count() >= 2 and master.nav_pub.get_subscription_count() >= 2,
                   60, "the new ifa_node's matches")
    else:
        sp.executor.remove_node(master)
        sp.nodes.remove(master)
        time.sleep(0.5)
        master.source.stop()
        master.destroy_node()
        master = mk_master()
        sp.executor.add_node(master)
        sp.nodes.append(master)
        probe.wait(lambda: all(s.publisher.get_subscription_count() >= 1 for s in master.relay._states)
                   and master.nav_pub.get_subscription_count() >= 2, 60, "the new master's matches")
    n_before = len(probe.raw["/master/nav"])
    rest = [m for m in msgs if m[0] > t_r]
    if os.environ.get("RT"):
        t_wall, t0 = time.monotonic(), rest[0][0]
        for t_ns, topic, m in rest:
            while (left := t_wall + (t_ns - t0) * 1e-9 - time.monotonic()) > 0:
                time.sleep(min(left, 0.005))
            probe.pubs[topic].publish(m)
    else:
        feed(rest)
    time.sleep(8.0)
    nav = live._odometry(probe.raw["/master/nav"][n_before:], master.source.input.datum_llh)
    t = stamp_s(nav.t_ns, jm.start_ns)
    err = llh_err_m(nav.llh, jm.session.truth("master", t).llh)
    sig = np.sqrt(np.trace(nav.pose_cov[:, :3, :3], axis1=1, axis2=2))
    for a in np.arange(t_restart_s, dur, 5.0):
        k = (t >= a) & (t < a + 5)
        if k.any():
            print(f"t {a:5.0f}-{a + 5:.0f} s: error max {err[k].max():8.3f} m, 3-D sigma {sig[k].mean():8.3f} m, "
                  f"inside 3 sigma {np.mean(err[k] < 3 * sig[k]):.2f}")
    print("ifa_node after the restart:", [s.get("message") for s in probe.status["/ifa/status"][-3:]])
    if which == "ifa":
        print(f"the restarted ifa_node received {ifa.discrepancy_checks + len(ifa._navs)} /master/nav messages (start: {ifa.start_source})")
    ifa_keys = ("message", "start", "joined_running_session", "epochs", "before_start", "heading_sigma_deg", "aligned_t_s", "t_s")
    print("ifa_node last:", {k: v for k, v in probe.status["/ifa/status"][-1].items() if k in ifa_keys})
    keys = ("message", "corrections", "gate_refused", "last_gate", "corrections_lost", "heading_sigma_deg", "hold_timeouts",
            "corrections_late")
    print("pos_master_node last:", {k: v for k, v in probe.status["/pos_master/status"][-1].items() if k in keys or k.startswith("gate/")})
    sp.stop()
    rclpy.try_shutdown(context=ctx)
    if which == "ifa":
        sp2.stop()
        rclpy.try_shutdown(context=ctx2)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "master")
