"""Replay through the graph: dpos-sim bag -> dpos-play -> transfer_align_node -> products equal
to dpos-process on the same bag; no message lost; finalize through the service."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from std_srvs.srv import Trigger

from dpos_ros.io import bag, spill

EXE = Path(sys.executable).parent
TOPICS = ["/dpos/datum", "/master/nav", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu", "/truth/master",
          "/truth/sub_imu/sub_r", "/truth/sub_imu/sub_l", "/truth/antenna/ant_r", "/truth/antenna/ant_l"]


def _sim(tmp: Path, duration: float) -> Path:
    b = tmp / "bag"
    r = subprocess.run([str(EXE / "dpos-sim"), "--scenario", "paper_su", "--aircraft", "paper_su_pair", "--seed", "3",
                        "--duration", str(duration), "--out", str(b)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return b


def _start_ta(out: Path, env: dict) -> subprocess.Popen:
    return subprocess.Popen([str(EXE / "transfer_align_node"), "--ros-args", "-p", "method:=urtss", "-p", "aircraft_config:=paper_su_pair",
                             "-p", f"output_dir:={out}", "-p", "initial_attitude_error_deg:=1.0"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _wait(pred, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.2)
    return pred()


def _stop(p: subprocess.Popen) -> int:
    import signal

    if p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
    return p.wait(60)


def test_replay_through_the_graph_equals_dpos_process(tmp_path: Path) -> None:
    b = _sim(tmp_path, 30.0)  # (what is checked is the transport and the equality: no accuracy)
    env = dict(os.environ)
    out = tmp_path / "live"
    ta = _start_ta(out, env)
    try:
        play = subprocess.run([str(EXE / "dpos-play"), str(b), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30",
                               "--topics", *TOPICS, "/session/end"], capture_output=True, text=True, timeout=300, env=env)
        assert play.returncode == 0, play.stdout + play.stderr
        status = out / "paper_su_seed3" / "status.json"
        assert _wait(status.is_file, 120), "no products from transfer_align_node"
    finally:
        assert _stop(ta) == 0
    # no message lost: the node's spill holds every message of the bag, per topic, byte for byte
    raw = bag.read_raw(b, TOPICS)
    d = next((out / "spill").iterdir())
    got, _, _, warns = spill.read_spill(d)
    assert not warns
    for t in TOPICS:
        assert len(got[t][2]) == len(raw[t][2]), t
        assert got[t][2] == raw[t][2], t
    # the same products as dpos-process on the bag
    r = subprocess.run([str(EXE / "dpos-process"), str(b), "--method", "urtss", "--initial-attitude-error", "1", "--out", str(tmp_path / "off")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    for ant in ("ant_r", "ant_l"):
        a = np.loadtxt(out / "paper_su_seed3" / f"{ant}.csv", delimiter=",", skiprows=2)
        o = np.loadtxt(tmp_path / "off" / "paper_su_seed3" / f"{ant}.csv", delimiter=",", skiprows=2)
        assert a.shape == o.shape == (3000, 23)
        np.testing.assert_allclose(a, o, rtol=0, atol=1e-12)


def test_finalize_through_the_service(tmp_path: Path) -> None:
    """Without /session/end, the finalize service ends the session: the session up to the last
    stamp the node has received when it is called, so the test calls it once the node's status
    counts every message of the bag (dpos-play returns when the readers acknowledged them; the
    node may still be taking them from its queues on a loaded machine)."""
    from diagnostic_msgs.msg import DiagnosticArray

    from dpos_ros.contract import topics as T
    from dpos_ros.contract.qos import STATUS_QOS
    from dpos_ros.io.session import message_counts

    b = _sim(tmp_path, 20.0)
    want = {t: n for t, n in message_counts(b).items() if t in TOPICS and t != "/dpos/datum"}
    env = dict(os.environ)
    out = tmp_path / "svc"
    ta = _start_ta(out, env)
    try:
        play = subprocess.run([str(EXE / "dpos-play"), str(b), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30",
                               "--topics", *TOPICS], capture_output=True, text=True, timeout=300, env=env)
        assert play.returncode == 0, play.stdout + play.stderr
        ctx = Context()
        rclpy.init(context=ctx)
        try:
            from rclpy.executors import SingleThreadedExecutor

            node = rclpy.create_node("finalize_client", context=ctx)
            counts: dict[str, int] = {}

            def on_status(msg: DiagnosticArray) -> None:
                for st in msg.status:
                    counts.update({kv.key[:-len("/count")]: int(kv.value) for kv in st.values if kv.key.endswith("/count")})

            node.create_subscription(DiagnosticArray, T.TRANSFER_ALIGN_STATUS, on_status, STATUS_QOS)
            ex = SingleThreadedExecutor(context=ctx)
            ex.add_node(node)
            end = time.monotonic() + 120
            while any(counts.get(t, 0) < n for t, n in want.items()) and time.monotonic() < end:
                ex.spin_once(timeout_sec=0.2)
            assert all(counts.get(t, 0) == n for t, n in want.items()), (counts, want)
            cli = node.create_client(Trigger, "/transfer_align_node/finalize")
            assert cli.wait_for_service(timeout_sec=30)
            fut = cli.call_async(Trigger.Request())
            end = time.monotonic() + 30
            while not fut.done() and time.monotonic() < end:
                ex.spin_once(timeout_sec=0.1)
            assert fut.done() and fut.result().success, fut.result()
        finally:
            rclpy.try_shutdown(context=ctx)
        sessions = lambda: [p for p in out.iterdir() if p.name != "spill" and (p / "status.json").is_file()]  # noqa: E731
        assert _wait(lambda: out.is_dir() and bool(sessions()), 120)
    finally:
        assert _stop(ta) == 0
    st = json.loads((sessions()[0] / "status.json").read_text())
    assert st["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}
