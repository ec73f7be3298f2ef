#!/usr/bin/env python3
"""dpos benchmarks: prints the figures and writes bench/results.json (not tracked by git).

Every figure is a throughput or a ratio measured within this one run (the machines are
shared and noisy): report them side by side, never as absolute pass/fail thresholds.

Keys (in order):
  strapdown_samples_per_s      local-level strapdown, rate input, coning + sculling on, one core,
                               one hour of 200 Hz data (720,000 samples), best of 5
  strapdown_hour_200hz_s       seconds to integrate that hour
  pyins_samples_per_s          the same flight through python-ins (pyins) increments + numba
                               integrator, when python-ins is installed (requirements-bench.txt)
  strapdown_speedup_vs_pyins   ratio of the two, measured side by side
  sim_paper_su_time_ratio      simulating paper_su (1300 s, one sub-IMU, every topic) / data duration
  urtss_paper_su_time_ratio    UKF + URTSS of one sub-IMU over paper_su (40 deg initial errors) / duration
  ups_paper_su_time_ratio      UPF (100 particles) + FFBSm of one sub-IMU over paper_su / duration
  ifa_add2_paper_ifa_time_ratio   in-flight alignment (ADD2, bank of 6 hypotheses) of paper_ifa / duration
  ifa_add2_mems_vehicle_time_ratio  the same on the MEMS scenario (24 states, real-device timing)
  ifa_add2_walk_0827_time_ratio   the same on the real recording walk_0827 (GNSS at 1 Hz)
  graph_loss_count             messages lost by transfer_align_node while the live graph carries master
                               IMU + nav and 6 sub-IMUs at 200 Hz in real time for 60 s (must be 0);
                               graph_cpu_percent: CPU per node over the run
  replay_speed_factor          data duration / wall time of the fastest zero-loss replay (dpos-play
                               --rate 0) of paper_su with 2 sub-IMUs into transfer_align_node
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dpos_core.analytic_trajectory import CoordinatedTurnClimb  # noqa: E402
from dpos_core.attitude import dcm_to_quat  # noqa: E402
from dpos_core.frames import hpr_from_C_nb  # noqa: E402
from dpos_core.strapdown import NavState, Strapdown  # noqa: E402

RESULTS = Path(__file__).with_name("results.json")
REPO = Path(__file__).resolve().parents[1]


def _best_of(fn: Callable[[], object], repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _flight(n: int, fs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, NavState]:
    traj = CoordinatedTurnClimb()
    t = np.arange(n) / fs
    om, f = traj.imu_rates(t)
    llh, vel, C = traj.truth(t[:1])
    return t, om, f, NavState(0.0, dcm_to_quat(C[0]), vel[0], llh[0])


def bench_strapdown(results: dict, repeats: int) -> None:
    fs, n = 200.0, 720_000
    t, om, f, s0 = _flight(n + 1, fs)
    Strapdown(s0).run_rates(t[:100], om[:100], f[:100])  # JIT warm-up (cached on disk after the first run)
    elapsed = _best_of(lambda: Strapdown(s0, coning=True, sculling=True).run_rates(t, om, f), repeats)
    results["strapdown_samples_per_s"] = n / elapsed
    results["strapdown_hour_200hz_s"] = elapsed
    print(f"strapdown: {n} samples (1 h @ 200 Hz) in {elapsed:.3f} s -> {n / elapsed:,.0f} samples/s")

    try:
        import pandas as pd
        import pyins.strapdown as pst
    except ImportError:
        print("pyins (python-ins) not installed: side-by-side comparison skipped "
              "(pip install -r requirements-bench.txt)")
        return
    # pyins works in NED / FRD with degrees; same flight, same samples
    frd = np.array([1.0, -1.0, -1.0])
    imu = pd.DataFrame(
        np.hstack([om * frd, f * frd]), index=t,
        columns=["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"],
    )
    hpr = np.rad2deg(hpr_from_C_nb(s0.C_nb))
    pva = pd.Series({
        "lat": np.rad2deg(s0.llh[0]), "lon": np.rad2deg(s0.llh[1]), "alt": s0.llh[2],
        "VN": s0.vel_n_mps[1], "VE": s0.vel_n_mps[0], "VD": -s0.vel_n_mps[2],
        "roll": hpr[2], "pitch": hpr[1], "heading": hpr[0],
    })

    def run_pyins() -> None:
        inc = pst.compute_increments_from_imu(imu, "rate")
        pst.Integrator(pva).integrate(inc)

    pst.Integrator(pva).integrate(pst.compute_increments_from_imu(imu.iloc[:100], "rate"))  # warm-up
    el_pyins = _best_of(run_pyins, max(1, repeats // 2))
    results["pyins_samples_per_s"] = n / el_pyins
    results["strapdown_speedup_vs_pyins"] = el_pyins / elapsed
    print(f"pyins:     {n} samples in {el_pyins:.3f} s -> {n / el_pyins:,.0f} samples/s "
          f"(dpos is {el_pyins / elapsed:.1f}x faster, same run)")


def bench_sim(results: dict, repeats: int) -> None:
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession

    def run() -> None:
        ss = SimulatedSession(load_scenario("paper_su"), 1)
        ss.master_imu(), ss.sub_imu("sub_r"), ss.gnss(), ss.master_nav_reference()
        for b in ss.bodies():
            ss.truth(b)

    el = _best_of(run, 1)
    results["sim_paper_su_time_ratio"] = el / 1300.0
    print(f"simulator: paper_su 1300 s in {el:.2f} s (ratio {el / 1300.0:.4f})")


def bench_transfer_alignment(results: dict, repeats: int) -> None:
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_core.ta import from_sim, pipeline
    from dpos_core.ta.model import TAConfig

    ss = SimulatedSession(load_scenario("paper_su"), 1)
    imu, master, ins = from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")
    init = pipeline.initial_from_master(master, ins, (40.0, 40.0, 40.0))
    cfg = TAConfig(attitude_sigma_deg=40.0)
    dur = float(imu.t_s[-1] - imu.t_s[0])
    for method, key in (("urtss", "urtss_paper_su_time_ratio"), ("ups", "ups_paper_su_time_ratio")):
        el = _best_of(lambda: pipeline.run(imu, master, ins, cfg, method, particles=100, initial=init), 1)
        results[key] = el / dur
        print(f"transfer alignment {method}: {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")


def bench_ifa(results: dict, repeats: int) -> None:
    from dpos_core.ifa.evaluate import initial_state
    from dpos_core.ifa.pipeline import run as ifa_run
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession

    ss = SimulatedSession(load_scenario("paper_ifa"), 1)
    imu, gnss = ss.master_imu(), ss.gnss()
    init = initial_state(ss, 30.0)
    dur = float(imu.t_s[-1] - init.t_s)
    el = _best_of(lambda: ifa_run(imu, gnss, ss.scenario.aircraft.gnss_lever_arm_m, method="add2", initial=init), repeats)
    results["ifa_add2_paper_ifa_time_ratio"] = el / dur
    print(f"in-flight alignment add2: paper_ifa {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")

    # a MEMS unit (24 states: gyro scale / misalignment), real-device timing, started from the data
    from dpos_core.ifa.evaluate import filter_config
    from dpos_core.ifa.reference import initial_state as data_initial_state
    from dpos_core.series import GnssSeries

    sc = load_scenario("mems_vehicle")
    ss = SimulatedSession(sc, 1)
    imu, gnss = ss.master_imu(), ss.gnss()
    cfg = filter_config(sc)
    g = GnssSeries(gnss.t_s - cfg.gnss_time_offset_s, gnss.llh, gnss.pos_sigma_m, gnss.vel_n_mps, gnss.vel_sigma_mps)
    init = data_initial_state(imu, g, 0.0)
    dur = float(imu.t_s[-1] - init.t_s)
    el = _best_of(lambda: ifa_run(imu, gnss, sc.aircraft.gnss_lever_arm_m, cfg, "add2", init), repeats)
    results["ifa_add2_mems_vehicle_time_ratio"] = el / dur
    print(f"in-flight alignment add2: mems_vehicle (24 states) {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")

    # the real recording walk_0827 (15 states), its ifa_node parameters

    from dpos_core.config import load_aircraft
    from dpos_core.imports.logs import decimate_mask, read_imu_csv, read_pos, read_tag
    from ifa_node.params import IfaConfig

    walk = REPO / "data" / "real" / "walk_0827"
    log = read_imu_csv(walk / "imu_1730.csv", tag=read_tag(walk / "imu_1730.csv.tag"))
    pos = read_pos(walk / "gnss_1730_sf.pos")
    origin = int(log.t_ns[0])
    g = pos.series(origin, decimate_mask(pos.t_ns, 1.0))
    w_imu = log.series(origin)
    node_cfg = IfaConfig.from_params_file(walk / "ifa_node.yaml")
    vehicle = load_aircraft(REPO / node_cfg.aircraft_config)
    wcfg = node_cfg.core_config(vehicle.master_imu)
    winit = data_initial_state(w_imu, g, 0.0)
    dur = float(w_imu.t_s[-1] - winit.t_s)
    el = _best_of(lambda: ifa_run(w_imu, g, vehicle.gnss_lever_arm_m, wcfg, "add2", winit), repeats)
    results["ifa_add2_walk_0827_time_ratio"] = el / dur
    print(f"in-flight alignment add2: real walk_0827 {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def bench_graph(results: dict, repeats: int) -> None:
    import tempfile

    import yaml

    from dpos_core.config import config_text
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_ros.devices.sim_streams import device_streams
    from dpos_ros.io import spill
    from dpos_ros.runtime.graph import Graph, GraphSpec, NodeSpec

    dur = 60.0
    tmp = Path(tempfile.mkdtemp(prefix="dpos_bench_graph_"))
    sc = yaml.safe_load(config_text("scenarios", "paper_wing"))
    sc["rates_hz"] = {"master_imu_hz": 200.0, "master_nav_hz": 200.0, "sub_imu_hz": 200.0}
    sc["aircraft"] = "paper_wing"
    scen = tmp / "wing200.yaml"
    scen.write_text(yaml.safe_dump(sc))
    subs = [s.name for s in load_scenario(scen).aircraft.sub_imus]
    common = {"scenario": str(scen), "aircraft_config": "paper_wing", "duration": dur, "rate_factor": 1.0,
              "publish_truth": False, "min_subscribers": 1, "wait_subscribers_s": 10.0}
    out = tmp / "out"
    spec = GraphSpec(nodes=[
        NodeSpec("transfer_align_node", "transfer_align_node", {"method": "ukf", "aircraft_config": "paper_wing", "output_dir": str(out)},
                 ready_subscribes=("/master/nav",)),
        NodeSpec("pos_master_node", "pos_master_node", {**common, "alignment": "reference"}),
        *[NodeSpec(n, "pos_sub_node", {**common, "name": n}) for n in subs],
        # /master/imu has no consumer in this graph (no ifa_node with alignment: reference): a recorder counts it
        NodeSpec("recorder", "dpos-record", args=("--out", str(tmp / "rec"), "--until-session-end", "/master/imu", "/session/end"),
                 ready_subscribes=("/master/imu",)),
    ], ros_domain_id=150 + os.getpid() % 50, ready_timeout_s=60.0, stop_timeout_s=30.0)
    cpu0, cpu1 = {}, {}
    with Graph(spec, log=lambda n, l: None) as g:
        for name, p in g.procs.items():
            cpu0[name] = _cpu_s(p.popen.pid)
        t0 = time.perf_counter()
        status_dir = out
        deadline = time.monotonic() + dur + 240
        while time.monotonic() < deadline and not (any(status_dir.glob("*/status.json")) and g.procs["recorder"].popen.poll() is not None):
            time.sleep(0.5)
        wall = time.perf_counter() - t0
        for name, p in g.procs.items():
            if name != "recorder":
                cpu1[name] = _cpu_s(p.popen.pid)
    cpu0.pop("recorder", None)
    ss = SimulatedSession(load_scenario(scen), 1, dur)
    expected = {s.topic: len(s) for dev in ["master"] + [f"sub_imu/{n}" for n in subs]
                for s in device_streams(ss, dev, truth=False) if s.topic in ("/master/nav", "/master/imu") or s.topic.startswith("/sub_imu/")}
    d = next((out / "spill").iterdir())
    raw, _, _, _ = spill.read_spill(d)
    from dpos_ros.io import bag

    raw.update({t: v for t, v in bag.read_raw(tmp / "rec").items() if t == "/master/imu"})
    lost = sum(expected[t] - len(raw.get(t, ("", [], []))[2]) for t in expected)
    n_msgs = sum(expected.values())
    results["graph_loss_count"] = int(lost)
    results["graph_messages"] = int(n_msgs)
    results["graph_cpu_percent"] = {n: round(100.0 * (cpu1[n] - cpu0[n]) / wall, 1) for n in cpu0}
    print(f"graph: {n_msgs} messages of /master/imu, /master/nav + 6 sub-IMUs at 200 Hz over {dur:.0f} s real time: lost {lost}")
    print("graph CPU % per node over the session and its processing: " + ", ".join(f"{k} {v}" for k, v in results["graph_cpu_percent"].items()))


def bench_replay(results: dict, repeats: int) -> None:
    import subprocess
    import tempfile

    from dpos_ros.io import bag, spill

    tmp = Path(tempfile.mkdtemp(prefix="dpos_bench_replay_"))
    exe = Path(sys.executable).parent
    b = tmp / "bag"
    subprocess.run([str(exe / "dpos-sim"), "--scenario", "paper_su", "--aircraft", "paper_su_pair", "--seed", "1", "--no-truth",
                    "--out", str(b)], check=True, capture_output=True, timeout=600)
    topics = ["/dpos/datum", "/master/nav", "/master/imu", "/gnss/fix", "/gnss/vel", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu", "/session/end"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(200 + os.getpid() % 30))
    out = tmp / "out"
    ta = subprocess.Popen([str(exe / "transfer_align_node"), "--ros-args", "-p", "method:=ukf", "-p", "aircraft_config:=paper_su_pair",
                           "-p", f"output_dir:={out}"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        t0 = time.perf_counter()
        r = subprocess.run([str(exe / "dpos-play"), str(b), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30",
                            "--topics", *topics], env=env, capture_output=True, text=True, timeout=1800)
        wall = time.perf_counter() - t0
    finally:
        import signal

        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any(out.glob("*/status.json")):
            time.sleep(0.5)
        os.killpg(ta.pid, signal.SIGINT)
        ta.wait(60)
    raw = bag.read_raw(b, ["/master/nav", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu"])
    d = next((out / "spill").iterdir())
    got, _, _, _ = spill.read_spill(d)
    lost = sum(len(raw[t][2]) - len(got.get(t, ("", [], []))[2]) for t in raw)
    results["replay_speed_factor"] = 1300.0 / wall if lost == 0 and r.returncode == 0 else 0.0
    results["replay_lost"] = int(lost)
    n = sum(len(v[2]) for v in got.values())
    print(f"replay: paper_su 1300 s, 2 sub-IMUs ({n} messages into transfer_align_node) in {wall:.1f} s: "
          f"{1300.0 / wall:.1f}x real time, lost {lost}")


BENCHES: dict[str, Callable[[dict, int], None]] = {
    "strapdown": bench_strapdown,
    "sim": bench_sim,
    "transfer_alignment": bench_transfer_alignment,
    "ifa": bench_ifa,
    "graph": bench_graph,
    "replay": bench_replay,
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=sorted(BENCHES), action="append", help="run only these benchmarks")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    results: dict = {}
    for name, fn in BENCHES.items():
        if args.only and name not in args.only:
            continue
        fn(results, args.repeats)
    results["machine"] = {"cpus": os.cpu_count(), "python": sys.version.split()[0]}
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
