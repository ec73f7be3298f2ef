"""transfer_align_node in a live graph with `fit` antennas (the least-squares wing fit).

A short paper_wing flight with three of its sub-IMUs (imu03, imu05, imu07, their antennas) and the
`fit` antennas ant04 and ant06 between them and ant08 beyond the outermost, simulated by dpos-sim
(10 s) and replayed by dpos-play as fast as the node takes it, through DDS on the test session's
ROS_DOMAIN_ID, into transfer_align_node (real processes).  After /session/end the node's workers
align the sub-IMUs and the node fits the wing: the `fit` antennas' /antenna/<name>/odom arrive
with a finite pose and positive covariances, their CSVs have every row with the wing-fit flag
(ant08 also the extrapolated one), status.json names them estimated by the wing fit, and each lies
where the wing puts it: at its lever arm's span from the (true) main POS, between its neighbours
along the span, near the wing line through them and the simulated truth.  Every wait is bounded;
nothing sleeps.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from nav_msgs.msg import Odometry
from node_process import NodeProcess  # test/support/node_process.py
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.serialization import deserialize_message
from ros_wait import spin_until  # test/support/ros_wait.py

from dpos_core.attitude import quat_to_dcm
from dpos_core.config.files import config_text
from dpos_core.ta import flags as F
from dpos_ros.cli.sim import main as sim_main
from dpos_ros.contract.qos import NAV_QOS
from dpos_ros.io import bag

pytestmark = [pytest.mark.ros, pytest.mark.slow]

EXE = Path(sys.executable).parent
SUBS = ("imu03", "imu05", "imu07")
FIT = {"ant04": 4.0, "ant06": 6.0, "ant08": 8.0}  # name -> span [m]
IMU_ANTENNAS = ("ant03", "ant05", "ant07")
SESSION = "paper_wing_seed2"
DURATION_S, OUTPUT_HZ = 10.0, 10.0
TIMEOUT_S = 120.0


def _aircraft(tmp: Path) -> Path:
    """paper_wing (modal wing) with three of its sub-IMUs and the antennas from 3 to 8 m."""
    d = yaml.safe_load(config_text("aircraft", "paper_wing"))
    d["name"] = "paper_wing_3"
    d["sub_imus"] = [s for s in d["sub_imus"] if s["name"] in SUBS]
    d["antennas"] = [a for a in d["antennas"] if a["name"] in (*IMU_ANTENNAS, *FIT)]
    p = tmp / "paper_wing_3.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def _odoms(raws: list[bytes]) -> list[Odometry]:
    return [deserialize_message(r, Odometry) for r in raws]


def _stamp_ns(m: Odometry) -> int:
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def _poses(msgs: list[Odometry]) -> dict[int, np.ndarray]:
    """stamp [ns] -> position in enu (3,)."""
    return {_stamp_ns(m): np.array([m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z]) for m in msgs}


def test_fit_antennas_in_a_live_graph(ros_context, tmp_path: Path, figures_on) -> None:
    t_start = time.monotonic()
    aircraft = _aircraft(tmp_path)
    rec, out = tmp_path / "rec", tmp_path / "out"
    got: dict[str, list[bytes]] = defaultdict(list)
    node = rclpy.create_node("wing_odom_counter", context=ros_context)
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=NAV_QOS.reliability, durability=NAV_QOS.durability)
    for a in (*IMU_ANTENNAS, *FIT):
        node.create_subscription(Odometry, f"/antenna/{a}/odom", lambda raw, a=a: got[a].append(raw), keep_all, raw=True)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    # the node starts while the recording is simulated (in this process: no interpreter start)
    ta = NodeProcess("transfer_align_node", ["--ros-args", "-p", "method:=urtss", "-p", f"aircraft_config:={aircraft}",
                                             "-p", f"output_dir:={out}", "-p", f"output_rate_hz:={OUTPUT_HZ}",
                                             "-p", "initial_attitude_error_deg:=1.0", "-p", "finalize_timeout_s:=30.0"])
    play = None
    products = out / SESSION
    try:
        assert sim_main(["--scenario", "paper_wing", "--aircraft", str(aircraft), "--seed", "2", "--duration", str(DURATION_S),
                         "--out", str(rec)]) == 0
        t_sim = time.monotonic() - t_start
        ta.wait_for_line("finalize on /session/end", 60)
        topics = ["/dpos/datum", "/master/nav", *(f"/sub_imu/{s}/imu" for s in SUBS), "/session/end"]
        play = subprocess.Popen([str(EXE / "dpos-play"), str(rec), "--rate", "0", "--no-clock", "--min-subscribers", "1",
                                 "--wait-subscribers", "30", "--topics", *topics],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

        def rows(a: str) -> int:
            p = products / f"{a}.csv"
            return sum(1 for _ in p.open()) - 2 if p.is_file() else -1

        # the node publishes every antenna pose before it writes the products: then wait for the last
        # poses still on their way (bounded)
        spin_until(ex, lambda: (products / "status.json").is_file(), TIMEOUT_S,
                   lambda: f"the products; transfer_align_node's log: {ta.lines[-15:]}")
        spin_until(ex, lambda: all(len(got[a]) >= rows(a) for a in (*IMU_ANTENNAS, *FIT)), 30.0,
                   lambda: f"every antenna pose; received { {a: len(v) for a, v in got.items()} }")
        t_poses = time.monotonic() - t_start
        play_out, _ = play.communicate(timeout=60)
        assert play.returncode == 0, play_out
    finally:
        if play is not None and play.poll() is None:
            play.kill()
            play.wait(10)
        if ta.proc.poll() is None:
            ta.send_signal()
        code = ta.wait(60)
        ex.remove_node(node)
        node.destroy_node()
        ex.shutdown(timeout_sec=5.0)
    wall_s = time.monotonic() - t_start
    assert code == 0, ta.lines[-20:]

    # status.json: estimated by the wing fit, from the three sub-IMUs
    st = json.loads((products / "status.json").read_text())
    for a in IMU_ANTENNAS:
        assert st["antennas"][a] == "estimated", st["antennas"]
    for a in FIT:
        assert st["antennas"][a].startswith("estimated (least-squares wing fit, polynomial in span"), st["antennas"][a]
        assert st["antennas"][a].endswith("from sub-IMUs imu03, imu05, imu07)"), st["antennas"][a]
    assert st["wing_fit"]["right"]["sub_imus"] == list(SUBS)

    # the quality control (no truth read): every antenna summarized, a figure each
    assert set(st["qc"]["antennas"]) == {*IMU_ANTENNAS, *FIT} and (products / "qc.md").is_file()
    assert all((products / "qc" / f"{a}_qc.png").is_file() for a in (*IMU_ANTENNAS, *FIT))
    assert all("nis" in st["qc"]["antennas"][a] for a in IMU_ANTENNAS) and all("wing_fit" in st["qc"]["antennas"][a] for a in FIT)

    # the CSVs: a row per output epoch of the session, every fit row flagged, ant08 (1 m beyond imu07) extrapolated
    # (the quality control's bits aside: the modal wing may well make the innovations inconsistent)
    n_rows = int(DURATION_S * OUTPUT_HZ) + 1
    for a in (*IMU_ANTENNAS, *FIT):
        tab = list(csv.DictReader(ln for ln in (products / f"{a}.csv").open() if not ln.startswith('#')))
        assert len(tab) == n_rows, (a, len(tab))
        fl = np.array([int(r["flags"]) for r in tab]) & ~(F.MASTER_UNALIGNED | F.INCONSISTENT_INNOVATIONS)
        if a in FIT:
            want = F.WING_FIT | (F.EXTRAPOLATED if a == "ant08" else 0)
            assert np.all(fl == want), (a, [F.describe(f) for f in sorted(set(fl.tolist()))])
            assert all(float(r[k]) > 0 for r in tab for k in ("sigma_north_m", "sigma_h_m", "sigma_heading_deg", "sigma_vel_e_mps"))
        else:
            assert np.all(fl == 0), a

    # /antenna/<fit>/odom: every row, finite pose, positive covariances
    msgs = {a: _odoms(got[a]) for a in (*IMU_ANTENNAS, *FIT)}
    for a in FIT:
        assert len(msgs[a]) == n_rows, (a, len(msgs[a]))
        for m in msgs[a]:
            assert m.header.frame_id == "enu" and m.child_frame_id.endswith(a), (m.header.frame_id, m.child_frame_id)
            p, q = m.pose.pose.position, m.pose.pose.orientation
            v = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w, m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z])
            assert np.all(np.isfinite(v)) and abs(np.linalg.norm(v[3:7]) - 1.0) < 1e-9, (a, v)
            pose_cov = np.array(m.pose.covariance).reshape(6, 6)
            twist_cov = np.array(m.twist.covariance).reshape(6, 6)
            assert np.all(np.diag(pose_cov) > 0) and np.all(np.diag(twist_cov)[:3] > 0), (a, np.diag(pose_cov), np.diag(twist_cov))
            assert np.all(np.linalg.eigvalsh(pose_cov) > 0), (a, np.linalg.eigvalsh(pose_cov))

    # physics.  10 s of straight flight do not make a converged transfer alignment: the sub-IMUs'
    # heading (unobservable without a manoeuvre, 1-2.5 deg) turns their lever arms, and the IMU
    # antennas are 0.07-0.15 m off the truth at 3-7 m (measured; dpos-process on the same recording
    # alike; 120 s: mm).  The fit antennas are derived from them, so the checks are (a) along the
    # span, where the heading does not act: each lies at its lever arm's span from the true main POS
    # and between its neighbours, and (b) in 3D: it is as close to the wing line through its
    # neighbours, and to the truth, as the neighbours are to the truth.
    pos = {a: _poses(msgs[a]) for a in msgs}
    stamps = sorted(pos["ant04"])
    P = {a: np.array([pos[a][t] for t in stamps]) for a in pos}
    raw = bag.read_raw(rec, ["/truth/master", *(f"/truth/antenna/{a}" for a in (*IMU_ANTENNAS, *FIT))])
    tm = {_stamp_ns(m): m for m in _odoms(raw["/truth/master"][2])}
    assert set(stamps) <= set(tm)
    C_wb = np.array([quat_to_dcm([o.w, o.x, o.y, o.z]) for o in (tm[t].pose.pose.orientation for t in stamps)])
    p_m = np.array([[q.x, q.y, q.z] for q in (tm[t].pose.pose.position for t in stamps)])
    body = {a: np.einsum("tji,tj->ti", C_wb, P[a] - p_m) for a in P}  # from the true main POS, in its axes (FLU)
    lever = {a["name"]: np.array(a["lever_arm_m"], dtype=float) for a in yaml.safe_load(aircraft.read_text())["antennas"]}
    span_err = {a: float(np.max(np.abs(body[a][:, 1] - lever[a][1]))) for a in FIT}
    assert all(e < 0.15 for e in span_err.values()), f"span coordinate against the lever arm [m]: {span_err}"
    order = ["ant03", "ant04", "ant05", "ant06", "ant07", "ant08"]  # FLU y: more negative outward on the right wing
    assert np.all(np.diff(np.stack([body[a][:, 1] for a in order], -1), axis=1) < -0.5), "antennas out of order along the span"
    err = {}
    for a in (*IMU_ANTENNAS, *FIT):
        tru = _poses(_odoms(raw[f"/truth/antenna/{a}"][2]))
        assert set(stamps) <= set(tru)
        err[a] = float(np.max(np.linalg.norm(P[a] - np.array([tru[t] for t in stamps]), axis=1)))
    line = {"ant04": (0.5 * (P["ant03"] + P["ant05"]), ("ant03", "ant05")),
            "ant06": (0.5 * (P["ant05"] + P["ant07"]), ("ant05", "ant07")),
            "ant08": (1.5 * P["ant07"] - 0.5 * P["ant05"], ("ant05", "ant07"))}  # s = 8: 5 + 1.5 (7 - 5)
    miss = {a: float(np.max(np.linalg.norm(P[a] - q, axis=1))) for a, (q, _) in line.items()}
    for a, (_, nb) in line.items():
        bound = max(err[n] for n in nb) * (2.0 if a == "ant08" else 1.0) + 0.05  # ant08: 1 m beyond imu07, extrapolated
        assert miss[a] < bound and err[a] < bound, (a, f"off the line through {nb} by {miss[a]:.3f} m, truth error {err[a]:.3f} m, "
                                                       f"bound {bound:.3f} m; errors {err}")
    print(f"\nwall {wall_s:.1f} s (simulated by {t_sim:.1f} s, poses at {t_poses:.1f} s); span {span_err}; line {miss}; truth {err}")
