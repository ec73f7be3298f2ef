"""transfer_align_node in a live graph: spill, finalize on /session/end, publish antenna poses,
write products equal to dpos-process on its spill; a killed node loses nothing."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from dpos_ros.contract.qos import NAV_QOS, keep_all
from dpos_ros.io import spill
from dpos_ros.runtime.graph import Graph

EXE = Path(sys.executable).parent
DUR = 60.0


def _graph_yaml(tmp: Path, domain: int, out: Path) -> Path:
    common = f"scenario: paper_su, duration: {DUR}, rate_factor: 0.0, min_subscribers: 1, wait_subscribers_s: 8.0"
    g = tmp / "graph.yaml"
    g.write_text(f"""
ros_domain_id: {domain}
ready_timeout_s: 60
nodes:
  - name: transfer_align_node
    executable: transfer_align_node
    parameters: {{method: urtss, output_dir: '{out}', initial_attitude_error_deg: 1.0}}
    ready: {{subscribes: [/master/nav, /sub_imu/sub_r/imu]}}
  - name: pos_master_node
    executable: pos_master_node
    parameters: {{{common}, alignment: reference}}
  - name: sub_r
    executable: pos_sub_node
    parameters: {{name: sub_r, {common}}}
""")
    return g


def _wait(pred, timeout: float, step: float = 0.2) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


def test_live_graph_session_products(tmp_path: Path) -> None:
    domain = int(os.environ["ROS_DOMAIN_ID"])
    out = tmp_path / "out"
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    got: list[bytes] = []
    try:
        node = rclpy.create_node("odom_counter", context=ctx)
        node.create_subscription(Odometry, "/antenna/ant_r/odom", lambda m: got.append(bytes(m)), keep_all(NAV_QOS), raw=True)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        with Graph.from_yaml(_graph_yaml(tmp_path, domain, out), log=lambda n, l: None) as g:
            status = out / "paper_su_seed1" / "status.json"
            ok = False
            end = time.monotonic() + 180
            while time.monotonic() < end and not ok:
                ex.spin_once(timeout_sec=0.2)
                ok = status.is_file() and len(got) >= 6000
            logs = g.logs("transfer_align_node")
            assert ok, f"no products / poses ({len(got)} received); node log: {logs[-15:]}"
        assert g.exit_codes["transfer_align_node"] == 0
    finally:
        rclpy.try_shutdown(context=ctx)
    assert len(got) == 6000  # every antenna pose at the sub-IMU rate, none lost
    st = json.loads(status.read_text())
    assert st["antennas"] == {"ant_r": "estimated"} and st["method"] == "urtss"
    m = json.loads((out / "paper_su_seed1" / "metrics.json").read_text())
    r_ = m["methods"]["urtss"]["mean"]["rmse"]
    # 60 s of straight flight: without a turn the heading misalignment is barely separable from the
    # sub-IMU's heading (measured 0.07 deg); level attitude and velocity are observable at once
    assert r_["heading_deg"] < 0.2 and max(r_["pitch_deg"], r_["roll_deg"]) < 0.01 and r_["vel_n_mps"] < 0.01, r_
    # dpos-process on the node's spill gives the same products
    spills = list((out / "spill").iterdir())
    assert len(spills) == 1 and spill.is_spill(spills[0])
    r = subprocess.run([str(EXE / "dpos-process"), str(spills[0]), "--method", "urtss", "--initial-attitude-error", "1",
                        "--out", str(tmp_path / "offline")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    a = np.loadtxt(out / "paper_su_seed1" / "ant_r.csv", delimiter=",", skiprows=2)
    b = np.loadtxt(tmp_path / "offline" / "paper_su_seed1" / "ant_r.csv", delimiter=",", skiprows=2)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_killed_node_loses_nothing(tmp_path: Path) -> None:
    """SIGKILL transfer_align_node mid-session: its spill holds every sample it received, with
    no gap, and dpos-process turns it into products."""
    domain = int(os.environ["ROS_DOMAIN_ID"])
    out = tmp_path / "out"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    ta = subprocess.Popen([str(EXE / "transfer_align_node"), "--ros-args", "-p", "method:=ukf", "-p", f"output_dir:={out}"],
                          env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    common = ["-p", "scenario:=paper_su", "-p", "duration:=300.0", "-p", "rate_factor:=5.0", "-p", "publish_truth:=false"]
    master = subprocess.Popen([str(EXE / "pos_master_node"), "--ros-args", *common, "-p", "alignment:=reference"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    sub = subprocess.Popen([str(EXE / "pos_sub_node"), "--ros-args", "-r", "__node:=sub_r", "-p", "name:=sub_r", *common],
                           env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        # the spill directory exists a moment before its spill.json: wait for a readable spill
        assert _wait(lambda: (out / "spill").is_dir() and any(spill.is_spill(p) for p in (out / "spill").iterdir()), 60)
        d = next(p for p in (out / "spill").iterdir() if spill.is_spill(p))

        def buffered_s() -> float:
            """Seconds of flight the spill holds of both the sub-IMU and the main POS (on a loaded
            machine one device may run ahead of the other)."""
            raw = spill.read_spill(d)[0]
            ts = [raw[t][1] for t in ("/sub_imu/sub_r/imu", "/master/nav") if t in raw and len(raw[t][1])]
            return (min(x[-1] for x in ts) - max(x[0] for x in ts)) * 1e-9 if len(ts) == 2 else 0.0

        # let it buffer ~15 s of both (3 s wall at 5x), then kill it hard
        assert _wait(lambda: buffered_s() > 15.0, 60)
        os.killpg(ta.pid, signal.SIGKILL)
        ta.wait(10)
    finally:
        for p in (master, sub):
            os.killpg(p.pid, signal.SIGINT)
            p.wait(20)
    raw, custom, sid, warns = spill.read_spill(d)
    t = np.array(raw["/sub_imu/sub_r/imu"][1])
    assert t.size > 1500 and np.all(np.diff(t) == 10_000_000)  # every 100 Hz sample, no gap
    assert "dpos.aircraft_yaml" in custom
    r = subprocess.run([str(EXE / "dpos-process"), str(d), "--method", "ukf", "--out", str(tmp_path / "p")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "p" / sid / "status.json").read_text())["antennas"]["ant_r"] == "estimated"


@contextlib.contextmanager
def _su_graph(tmp: Path, duration_s: float, *ta_params: str,
              master_wait_s: float = 8.0) -> Iterator[tuple[dict[str, subprocess.Popen], Path]]:
    """transfer_align_node (ukf, poses at 1 Hz, its log in ``tmp/ta.log``, more ``-p`` ``ta_params``),
    pos_master_node and sub_r's device on paper_su at 2x real time, as processes; yields them and
    the output directory; at the end every process is continued and stopped.

    Nobody subscribes to /master/imu and /master/gnss here, so the master starts after its
    ``wait_subscribers_s`` (``master_wait_s``), the sub-IMU as soon as transfer_align_node listens."""
    out = tmp / "out"
    env = dict(os.environ)
    with (tmp / "ta.log").open("w") as log:
        ta = subprocess.Popen([str(EXE / "transfer_align_node"), "--ros-args", "-p", "method:=ukf", "-p", f"output_dir:={out}",
                               "-p", "output_rate_hz:=1.0", *ta_params], env=env, stdout=log, stderr=subprocess.STDOUT,
                              start_new_session=True)
        common = ["-p", "scenario:=paper_su", "-p", f"duration:={duration_s}", "-p", "rate_factor:=2.0", "-p", "publish_truth:=false",
                  "-p", "min_subscribers:=1", "-p", "wait_subscribers_s:=30.0"]
        procs = {"ta": ta,
                 "master": subprocess.Popen([str(EXE / "pos_master_node"), "--ros-args", *common, "-p", "alignment:=reference",
                                             "-p", f"wait_subscribers_s:={master_wait_s}"],
                                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True),
                 "sub": subprocess.Popen([str(EXE / "pos_sub_node"), "--ros-args", "-r", "__node:=sub_r", "-p", "name:=sub_r", *common],
                                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)}
        try:
            yield procs, out
        finally:
            for name in ("master", "sub", "ta"):
                p = procs[name]
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGCONT)
                    os.killpg(p.pid, signal.SIGINT)
                p.wait(60)


def _spill_dir(out: Path) -> Path:
    """The session's spill directory, once its spill.json exists (the directory comes a moment before)."""
    assert _wait(lambda: (out / "spill").is_dir() and any(spill.is_spill(p) for p in (out / "spill").iterdir()), 60)
    return next(p for p in (out / "spill").iterdir() if spill.is_spill(p))


def _sub_samples(d: Path) -> int:
    """sub_r's messages in the spill ``d`` (with its late ones)."""
    return len(spill.read_spill(d)[0].get("/sub_imu/sub_r/imu", ("", [], []))[1])


def test_sigstopped_sub_imu_catches_up_and_nothing_is_lost(tmp_path: Path) -> None:
    """SIGSTOP the sub-IMU's device for 4 s mid-session, then SIGCONT: it catches up, the spill
    holds every 100 Hz sample without a gap and the session's products are estimated."""
    with _su_graph(tmp_path, 40.0) as (procs, out):
        d = _spill_dir(out)
        assert _wait(lambda: _sub_samples(d) > 1000, 60)
        os.killpg(procs["sub"].pid, signal.SIGSTOP)
        time.sleep(4.0)  # the fault itself: a device frozen for 4 s of wall time
        frozen = _sub_samples(d)
        os.killpg(procs["sub"].pid, signal.SIGCONT)
        assert _wait(lambda: any(out.glob("paper_su_seed1/status.json")), 180)
    t = np.array(spill.read_spill(d)[0]["/sub_imu/sub_r/imu"][1])
    assert t.size == 4000 and np.all(np.diff(t) == 10_000_000) and frozen < 3000, (t.size, frozen)
    st = json.loads((out / "paper_su_seed1" / "status.json").read_text())
    assert st["antennas"]["ant_r"] == "estimated", st


def test_sub_imu_frozen_past_the_session_end_its_late_data_are_kept_and_used_by_dpos_process(tmp_path: Path) -> None:
    """SIGSTOP the sub-IMU's device until the master has ended the session and finalize gave up
    waiting (finalize_timeout_s 2 s), then SIGCONT: its remaining samples arrive after the session
    closed. They are kept in <spill>/late, counted in status.json, and dpos-process on the spill
    has every sample of the flight.

    The freeze is kept well below the DDS participant lease (Fast DDS: 20 s): a device frozen longer
    is dropped from discovery, and what it sends in the moment before it is rediscovered is lost in
    transport before any node sees it (measured: the whole 15 s tail, with the master starting 30 s
    after the sub-IMU). So the master starts a few seconds after the sub-IMU, and the sub-IMU is
    frozen near the end of its flight: about 10 s frozen, 6-8 s of late data."""
    with _su_graph(tmp_path, 30.0, "-p", "finalize_timeout_s:=2.0", master_wait_s=5.0) as (procs, out):
        d = _spill_dir(out)
        assert _wait(lambda: _sub_samples(d) > 2200, 60)
        os.killpg(procs["sub"].pid, signal.SIGSTOP)
        # the master ends the session, finalize waits 2 s for sub_r and closes the spill without its tail
        assert _wait(lambda: any(out.glob("paper_su_seed1/status.json")), 120)
        os.killpg(procs["sub"].pid, signal.SIGCONT)
        _wait(lambda: _sub_samples(d) >= 3000, 90)  # read_spill merges late/
    assert _sub_samples(d) == 3000, (_sub_samples(d), (tmp_path / "ta.log").read_text().splitlines()[-12:])
    st = json.loads((out / "paper_su_seed1" / "status.json").read_text())
    n_late = st["late_after_close"]["messages"]["/sub_imu/sub_r/imu"]
    own = len(spill.read_spill(d, include_late=False)[0]["/sub_imu/sub_r/imu"][1])
    assert own + n_late == 3000 and n_late > 100 and st["late_after_close"]["used"] is False, (own, st["late_after_close"])
    r = subprocess.run([str(EXE / "dpos-process"), str(d), "--method", "ukf", "--output-rate", "1", "--out", str(tmp_path / "p")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"{n_late} message(s) arrived after the session was closed" in r.stderr, r.stderr
    p = json.loads((tmp_path / "p" / "paper_su_seed1" / "status.json").read_text())
    assert p["antennas"]["ant_r"] == "estimated", p  # the whole flight, no gap
    t = np.loadtxt(tmp_path / "p" / "paper_su_seed1" / "ant_r.csv", delimiter=",", skiprows=2, usecols=0)
    t_own = np.loadtxt(out / "paper_su_seed1" / "ant_r.csv", delimiter=",", skiprows=2, usecols=0)
    assert t[-1] - t[0] > t_own[-1] - t_own[0] + 1.0  # the re-run covers the tail the node did not have
