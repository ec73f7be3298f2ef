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
  cdkf_paper_su_time_ratio     CDKF + its RTS-type smoother (cdkf_rts, [Ye2024]) on the same data / duration;
                               cdvf_paper_su_time_ratio: the CDVF + smoother (cdvf_rts, the conjugate-gradient
                               update); urtss_paper_su_ref_time_ratio: the URTSS in the same run, side by side;
                               cdvf_paper_su_cg_iterations_mean / _max: the CDVF's iterations per update
  wing_paper_wing_time_ratio   the whole paper_wing session (6 sub-IMUs at 200 Hz, 12 antennas: UPS with 100
                               particles, the wing fit) through solve() on 2 workers / session duration (300 s),
                               the workers started and warm (as transfer_align_node and dpos-process have them);
                               wing_paper_wing_cold_time_ratio: the workers started by solve();
                               wing_paper_wing_serial_time_ratio: the same one sub-IMU after the other;
                               *_split_s: seconds of the transfer alignment and of the rest (the wing fit)
  sar_<method>_paper_sar_time_ratio  SINS/SAR filtering of paper_sar (1000 s, 16 states, 1 Hz; dpos_core.sar,
                               docs/sar.md) / duration, for ekf, ukf and the particle filters pf, rpf, mcmc_rpf, mcmc_rpf_literal
                               with 1000 particles (the simulation and the SINS not counted);
                               sar_<method>_paper_sar_cpu_ratio: the same run's CPU time (this process) / duration
  ifa_add2_paper_ifa_time_ratio   in-flight alignment (ADD2, bank of 6 hypotheses) of paper_ifa / duration
  ifa_add2_mems_vehicle_time_ratio  the same on the MEMS scenario (24 states, real-device timing)
  ifa_add2_walk_0827_time_ratio   the same on the real recording walk_0827 (GNSS at 1 Hz)
  graph_loss_count             messages lost by transfer_align_node while the live graph carries master
                               IMU + nav and 6 sub-IMUs at 200 Hz in real time for 60 s (must be 0);
                               graph_cpu_percent: CPU per node over the run
  bagio_write_s_per_million    rosbag2 MCAP writing (dpos_ros.io.bag.write_streams) of a generated bag of 1.2 M
                               fixed-size messages (12 topics at 200 Hz), s per million messages; bagio_read_s_per_million:
                               reading it back (read_raw); bagio_rosbags_write / _read_s_per_million: rosbags' Writer
                               and AnyReader message by message on a tenth of it; bagio_*_speedup_vs_rosbags: the ratios
  replay_speed_factor          data duration / wall time of the fastest zero-loss replay (dpos-play
                               --rate 0) of paper_su with 2 sub-IMUs into transfer_align_node
  soak_duration_s              the soak: the graph of graph_loss_count (the rated load) for --soak-s
                               seconds of data (600; 0 skips it) in real time
  soak_loss_count              messages lost over the soak, counted as for graph_loss_count (must be 0);
                               soak_messages: how many were sent
  soak_rss_mb                  {process: [RSS MB]} (VmRSS; None once the process is gone) sampled every
                               10 s from the graph's start through the data flow, every 1 s through
                               transfer_align_node's finalize (its smoother workers live for seconds);
                               "<node>/workers": the summed RSS of the node's child processes (the
                               smoother workers); soak_rss_t_s: the sampling times, s from the start of
                               the data flow (every device publishing; it ends when every device's
                               messages are acknowledged); soak_rss_phase: start / data / finalize
  soak_peak_rss_mb             {process: peak MB}: its VmHWM (the largest RSS of its life) or the largest
                               sample; transfer_align_node/worker_each: the largest VmHWM of one worker
  soak_rss_growth_mb_per_min   {process: MB/min}: least-squares slope of its samples of the data flow
                               (not the finalize); bounded memory is ~0
  long_flight_<d>_peak_rss_mb  a paper_wing flight (6 sub-IMUs at 200 Hz, 12 antennas; a racetrack of 840 s
                               lines and 60 s turns) of d = 1 h, 2 h, 4 h (--long-flight-s) simulated window by window (dpos-sim --window 60 --no-truth) into a
                               temporary directory (deleted afterwards), then dpos-process (UPS, --workers 2) on it in a
                               subprocess: the largest summed RSS of dpos-process and its workers (/proc, every 0.5 s);
                               long_flight_<d>_largest_process_rss_mb: the largest RSS of
                               one of them; long_flight_<d>_time_ratio: its wall time / flight duration; long_flight_<d>_status: "ok",
                               or why there is no figure (the run killed above --long-flight-rss-cap-mb, 6000, to spare the
                               shared machine; the bag not fitting the disk); long_flight_<d>_sim_*: the simulation's;
                               long_flight_<d>_loadavg: the machine's 1-minute load average before and after
                               dpos-process (2 cores; another engineer's work slows the time ratio);
                               long_flight_peak_rss_mb / long_flight_time_ratio: those of the longest flight;
                               long_flight_<d>_worker_task_peak_rss_mb / _worker_task_s: one worker task alone
                               (bench/worker_memory.py: sub-IMU imu01's read, alignment and rows in a fresh
                               spawned, warmed-up process; its ru_maxrss and wall time), run after dpos-process;
                               --long-flight-bags DIR keeps each simulated recording in DIR/long_wing_<d>s (with
                               its scenario) and reuses it when the scenario there is the same file (no _sim_*
                               figures then, long_flight_<d>_bag_reused true): delete DIR after changing dpos-sim
  soak_processing_time_ratio   finalize processing time (status.json timing.processing_s: the smoothers
                               of the 6 sub-IMUs) / data duration; soak_data_wall_s: wall time of the
                               data flow
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

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
    from dpos_core.evaluation import ta as from_sim
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_core.ta import pipeline
    from dpos_core.ta.model import TAConfig

    ss = SimulatedSession(load_scenario("paper_su"), 1)
    imu, master, ins = from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")
    init = pipeline.initial_from_master(master, ins, (40.0, 40.0, 40.0))
    cfg = TAConfig(attitude_sigma_deg=40.0)
    dur = float(imu.t_s[-1] - imu.t_s[0])
    for method, key in (("urtss", "urtss_paper_su_time_ratio"), ("ups", "ups_paper_su_time_ratio")):
        el = _best_of(lambda: pipeline.run(imu, master, ins, pipeline.TASettings(method=method, particles=100), cfg=cfg, initial=init), 1)
        results[key] = el / dur
        print(f"transfer alignment {method}: {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")


def bench_cdvf(results: dict, repeats: int) -> None:
    """[Ye2024]'s CDKF and CDVF (with their RTS-type smoothers) on urtss_paper_su_time_ratio's data
    (paper_su, sub_r, 40 deg initial errors), the URTSS timed in the same run beside them."""
    from dpos_core.evaluation import ta as from_sim
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_core.ta import pipeline
    from dpos_core.ta.model import TAConfig

    ss = SimulatedSession(load_scenario("paper_su"), 1)
    imu, master, ins = from_sim.sub_imu(ss, "sub_r"), from_sim.master_nav(ss), from_sim.installation(ss, "sub_r")
    init = pipeline.initial_from_master(master, ins, (40.0, 40.0, 40.0))
    cfg = TAConfig(attitude_sigma_deg=40.0)
    dur = float(imu.t_s[-1] - imu.t_s[0])
    for method, key in (("urtss", "urtss_paper_su_ref_time_ratio"), ("cdkf_rts", "cdkf_paper_su_time_ratio"),
                        ("cdvf_rts", "cdvf_paper_su_time_ratio")):
        el = _best_of(lambda: pipeline.run(imu, master, ins, pipeline.TASettings(method=method), cfg=cfg, initial=init), min(repeats, 2))
        results[key] = el / dur
        print(f"transfer alignment {method}: {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f})")
    cg = pipeline.run(imu, master, ins, pipeline.TASettings(method="cdvf"), cfg=cfg, initial=init).cg
    assert cg is not None
    s = cg.summary()
    results["cdvf_paper_su_cg_iterations_mean"], results["cdvf_paper_su_cg_iterations_max"] = s["iterations_mean"], s["iterations_max"]
    print(f"cdvf conjugate gradient: {s['iterations_mean']:.2f} iterations per update (max {s['iterations_max']}), "
          f"{s['stopped_by_gradient']:.3f} stopped by the gradient rule")


def _children_cpu_s(pool) -> float:
    """CPU seconds (user + system) used so far by the live worker processes of ``pool`` (0 without one)."""
    if pool is None:
        return 0.0
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for pid in list(getattr(pool, "_processes", {})):
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        total += int(fields[11]) + int(fields[12])  # utime, stime (fields 14, 15 of proc(5))
    return total / tick


def bench_wing(results: dict, repeats: int) -> None:
    """The whole paper_wing session (300 s, 6 sub-IMUs at 200 Hz, 12 antennas) through solve() as
    dpos-process runs it (UPS, 100 particles, the recording's initial attitude error): the six
    sub-IMUs on 2 workers and, in the same run, one after the other; the wing fit included.  Beside
    the wall-clock ratios, the CPU seconds of this process and of the workers (``..._cpu_s``): on a
    machine shared with other work the wall clock measures the load as much as the code."""
    import resource

    from dpos_core.config import config_text
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_core.ta.pipeline import TASettings
    from dpos_core.ta.warmup import warm_up
    from dpos_ros.devices.sim_streams import session_custom_data, session_streams
    from dpos_ros.io.session import session_from_streams
    from dpos_ros.products.solve import solve
    from dpos_ros.runtime.pool import process_pool, warm_pool

    scenario = load_scenario("paper_wing")
    ss = SimulatedSession(scenario, 1)
    sess = session_from_streams(session_streams(ss), session_custom_data(ss, config_text("aircraft", "paper_wing")), "paper_wing_seed1")
    dur = float(sess.master.t_s[-1] - sess.master.t_s[0])
    err0 = float(scenario.transfer_alignment.get("initial_attitude_error_deg", 0.0))
    # warm: the 2 workers started and loaded the filters before (transfer_align_node starts them with
    # the node, dpos-process while it reads the recording: runtime.pool.warm_pool); cold: started with the timing
    for workers, key in ((2, "wing_paper_wing_time_ratio"), (2, "wing_paper_wing_cold_time_ratio"),
                         (1, "wing_paper_wing_serial_time_ratio")):
        pool = None
        if key == "wing_paper_wing_time_ratio":
            pool, warming = warm_pool(workers, partial(warm_up, "ups"))
            cf.wait(warming)
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        rs0 = _children_cpu_s(pool)
        t0, c0 = time.perf_counter(), time.process_time()
        cold = process_pool(workers) if key == "wing_paper_wing_cold_time_ratio" else None
        ants, timing = solve(sess, scenario.aircraft, TASettings(method="ups", particles=100, seed=0, initial_attitude_error_deg=err0),
                             pool=pool or cold)
        if cold is not None:
            cold.shutdown()
        el, cpu = time.perf_counter() - t0, time.process_time() - c0
        if pool is not None:  # live workers: their CPU from /proc (getrusage counts joined children only)
            cpu_workers = _children_cpu_s(pool) - rs0
            pool.shutdown()
        else:
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the workers, joined at their shutdown
            cpu_workers = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
        n_est = sum(a.rows is not None for a in ants.values())
        results[key] = el / dur
        results[f"{key}_split_s"] = {"transfer_alignment": timing["processing_s"], "antennas_and_wing_fit": el - timing["processing_s"]}
        results[f"{key}_cpu_s"] = {"this_process": cpu, "workers": cpu_workers}
        print(f"paper_wing ups, {len(sess.sub_imus)} sub-IMUs on {workers} worker(s): {dur:.0f} s of session in {el:.2f} s "
              f"(ratio {el / dur:.4f}: transfer alignment {timing['processing_s']:.2f} s, antennas + wing fit "
              f"{el - timing['processing_s']:.2f} s; {n_est}/{len(ants)} antennas estimated; CPU {cpu:.2f} s here + "
              f"{cpu_workers:.2f} s in workers)")


def bench_sar(results: dict, repeats: int) -> None:
    """[Yan2016]'s filters on one paper_sar run (dpos_core.sar): processing time / data duration, wall
    clock and this process's CPU time (the machine is shared: the CPU ratio is the load-independent one)."""
    from dpos_core.evaluation.sar import problem
    from dpos_core.sar.pipeline import METHODS, run
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession

    prob = problem(SimulatedSession(load_scenario("paper_sar"), 1))
    dur = float(prob.model.track.t_s[-1] - prob.model.track.t_s[0])
    warm = prob.model.project(np.repeat(prob.x0[None], 2, axis=0))  # load the model's compiled kernels outside the timing
    prob.model.f(0, warm)
    for k in (int(np.argmax(prob.model.meas.sar)), int(np.argmin(prob.model.meas.sar))):
        prob.model.h(k, warm)
        prob.model.loglik(k, warm)
    for m in METHODS:
        el = cpu = np.inf
        for _ in range(max(1, min(repeats, 2))):
            t0, c0 = time.perf_counter(), time.process_time()
            run(m, prob.model, prob.x0, prob.P0, n_particles=1000, rng=np.random.default_rng(1))
            el, cpu = min(el, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
        results[f"sar_{m}_paper_sar_time_ratio"] = el / dur
        results[f"sar_{m}_paper_sar_cpu_ratio"] = cpu / dur
        print(f"SINS/SAR {m}: paper_sar {dur:.0f} s of data in {el:.2f} s (ratio {el / dur:.4f}; CPU {cpu:.2f} s, "
              f"ratio {cpu / dur:.4f})")


def bench_ifa(results: dict, repeats: int) -> None:
    from dpos_core.evaluation.ifa import initial_state
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
    from dpos_core.evaluation.ifa import filter_config
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


def _graph_spec(tmp: Path, dur: float) -> tuple[Any, Path, list[str]]:
    """The rated load: pos_master_node + one pos_sub_node per sub-IMU of paper_wing at 200 Hz (its
    steady flight made ``dur`` s long when it is shorter) in real time for ``dur`` s, transfer_align_node (ukf; products and spill in ``tmp/out``) and a
    dpos-record of /master/imu (``tmp/rec``; /master/imu has no other consumer in this graph).
    Returns (GraphSpec, scenario file, sub-IMU names)."""
    import yaml

    from dpos_core.config import config_text
    from dpos_core.sim.scenario import load_scenario
    from dpos_ros.runtime.graph import GraphSpec, NodeSpec

    sc = yaml.safe_load(config_text("scenarios", "paper_wing"))
    sc["rates_hz"] = {"master_imu_hz": 200.0, "master_nav_hz": 200.0, "sub_imu_hz": 200.0}
    sc["aircraft"] = "paper_wing"
    steady = sc["flight"]["segments"][-1]  # paper_wing is 300 s of steady flight: longer for a longer soak
    steady["duration_s"] += max(0.0, dur - sum(seg["duration_s"] for seg in sc["flight"]["segments"]))
    scen = tmp / "wing200.yaml"
    scen.write_text(yaml.safe_dump(sc))
    subs = [s.name for s in load_scenario(scen).aircraft.sub_imus]
    common = {"scenario": str(scen), "aircraft_config": "paper_wing", "duration": dur, "rate_factor": 1.0,
              "publish_truth": False, "min_subscribers": 1, "wait_subscribers_s": 10.0}
    spec = GraphSpec(nodes=[
        NodeSpec("transfer_align_node", "transfer_align_node",
                 {"method": "ukf", "aircraft_config": "paper_wing", "output_dir": str(tmp / "out")},
                 ready_subscribes=("/master/nav",)),
        NodeSpec("pos_master_node", "pos_master_node", {**common, "alignment": "reference"}),
        *[NodeSpec(n, "pos_sub_node", {**common, "name": n}) for n in subs],
        # /master/imu has no consumer in this graph (no ifa_node with alignment: reference): a recorder counts it
        NodeSpec("recorder", "dpos-record", args=("--out", str(tmp / "rec"), "--until-session-end", "/master/imu", "/session/end"),
                 ready_subscribes=("/master/imu",)),
    ], ros_domain_id=150 + os.getpid() % 50, ready_timeout_s=60.0, stop_timeout_s=30.0)
    return spec, scen, subs


def _graph_done(g: Any, tmp: Path) -> bool:
    """transfer_align_node wrote the session's products and the recorder closed its bag."""
    return any((tmp / "out").glob("*/status.json")) and g.procs["recorder"].popen.poll() is not None


def _graph_loss(tmp: Path, scen: Path, subs: list[str], dur: float) -> tuple[int, int]:
    """(messages lost, messages expected) of /master/nav and the sub-IMUs (counted in
    transfer_align_node's spill) and /master/imu (counted in the recorder's bag)."""
    from dpos_core.sim.scenario import load_scenario
    from dpos_core.sim.session import SimulatedSession
    from dpos_ros.devices.sim_streams import device_streams
    from dpos_ros.io import bag, spill

    ss = SimulatedSession(load_scenario(scen), 1, dur)
    expected = {s.topic: len(s) for dev in ["master"] + [f"sub_imu/{n}" for n in subs]
                for s in device_streams(ss, dev, truth=False) if s.topic in ("/master/nav", "/master/imu") or s.topic.startswith("/sub_imu/")}
    d = next((tmp / "out" / "spill").iterdir())
    raw, _, _, _ = spill.read_spill(d)
    counts = {t: len(v[2]) for t, v in raw.items()}
    del raw
    counts.update({t: len(v[2]) for t, v in bag.read_raw(tmp / "rec", ["/master/imu"]).items()})
    lost = sum(n - counts.get(t, 0) for t, n in expected.items())
    return int(lost), int(sum(expected.values()))


def bench_graph(results: dict, repeats: int) -> None:
    import tempfile

    from dpos_ros.runtime.graph import Graph

    dur = 60.0
    tmp = Path(tempfile.mkdtemp(prefix="dpos_bench_graph_"))
    spec, scen, subs = _graph_spec(tmp, dur)
    cpu0, cpu1 = {}, {}
    with Graph(spec, log=lambda n, l: None) as g:
        for name, p in g.procs.items():
            cpu0[name] = _cpu_s(p.popen.pid)
        t0 = time.perf_counter()
        deadline = time.monotonic() + dur + 240
        while time.monotonic() < deadline and not _graph_done(g, tmp):
            time.sleep(0.5)
        wall = time.perf_counter() - t0
        for name, p in g.procs.items():
            if name != "recorder":
                cpu1[name] = _cpu_s(p.popen.pid)
    cpu0.pop("recorder", None)
    lost, n_msgs = _graph_loss(tmp, scen, subs, dur)
    results["graph_loss_count"] = lost
    results["graph_messages"] = n_msgs
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


#: seconds between two memory samples of the soak while the data flow, and while transfer_align_node
#: finalizes the session (seconds: its smoother workers live only that long)
SOAK_SAMPLE_S = 10.0
SOAK_FINALIZE_SAMPLE_S = 1.0


def _proc_mem_mb(pid: int) -> tuple[float, float] | None:
    """(VmRSS, VmHWM) [MB] of a live process from /proc/<pid>/status; None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            kv = dict(line.split(":", 1) for line in f if line.startswith(("VmRSS:", "VmHWM:")))
        return int(kv["VmRSS"].split()[0]) / 1024.0, int(kv["VmHWM"].split()[0]) / 1024.0
    except (OSError, KeyError, ValueError):
        return None


def _descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (the smoother workers of transfer_align_node and their
    multiprocessing helpers), from /proc/<pid>/task/*/children."""
    out: list[int] = []
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for t in tasks:
            try:
                with open(f"/proc/{p}/task/{t}/children") as f:
                    kids = [int(c) for c in f.read().split()]
            except (OSError, ValueError):
                continue
            out += kids
            todo += kids
    return out


class _MemSampler:
    """RSS of every process of a running Graph (and the summed RSS of each one's descendants,
    as ``<name>/workers``), one sample per call; VmHWM kept from the last read."""

    def __init__(self, g: Any) -> None:
        self.g = g
        self.times: list[float] = []  # time.monotonic() of each sample
        self.rss: list[dict[str, float]] = []  # per sample: process label -> VmRSS [MB]
        self.hwm: dict[str, float] = {}  # process label -> VmHWM [MB] (monotone: the last read)
        self.worker_hwm: dict[int, float] = {}  # descendant pid -> VmHWM [MB]

    def __call__(self) -> None:
        rss: dict[str, float] = {}
        for name, p in self.g.procs.items():
            m = _proc_mem_mb(p.popen.pid) if p.popen.poll() is None else None
            if m is None:
                continue
            rss[name], self.hwm[name] = m
            kids = {k: km for k in _descendants(p.popen.pid) if (km := _proc_mem_mb(k)) is not None}
            if kids:
                rss[f"{name}/workers"] = sum(km[0] for km in kids.values())
                for k, km in kids.items():
                    self.worker_hwm[k] = max(self.worker_hwm.get(k, 0.0), km[1])
        self.times.append(time.monotonic())
        self.rss.append(rss)

    def labels(self) -> list[str]:
        return list(dict.fromkeys(k for r in self.rss for k in r))


def bench_soak(results: dict, repeats: int, soak_s: float = 600.0) -> None:
    """The graph benchmark's graph for ``soak_s`` s of data in real time; every process's memory
    sampled every SOAK_SAMPLE_S s while the data flow and every SOAK_FINALIZE_SAMPLE_S s while
    transfer_align_node finalizes."""
    import tempfile

    from dpos_ros.runtime.graph import Graph

    if soak_s <= 0:
        print("soak: skipped (--soak-s 0)")
        return
    dur = float(soak_s)
    tmp = Path(tempfile.mkdtemp(prefix="dpos_bench_soak_"))
    spec, scen, subs = _graph_spec(tmp, dur)
    devices = [n.name for n in spec.nodes if n.executable in ("pos_master_node", "pos_sub_node")]
    # the data flow: from the last device that starts publishing in real time to the last one
    # whose messages are all acknowledged (SimDevice's log lines "publishing ..." / "published ...")
    started: dict[str, float] = {}
    finished: dict[str, float] = {}
    log_path = tmp / "graph.log"
    print(f"soak: {len(spec.nodes)} processes, {dur:.0f} s of data at 200 Hz in real time; logs in {log_path}", flush=True)
    with log_path.open("w") as log_file:
        def log(name: str, line: str) -> None:
            now = time.monotonic()
            log_file.write(f"{now:.1f} [{name}] {line}\n")
            if name in devices and ": publishing " in line:
                started.setdefault(name, now)
            elif name in devices and ": published " in line:
                finished.setdefault(name, now)

        with Graph(spec, log=log) as g:
            sample = _MemSampler(g)
            t_ready = time.monotonic()
            # device start-up (stream generation) + data + finalize (the ukf of 6 sub-IMUs on 2
            # busy cores: about the data duration) + margin
            budget = 120.0 + 4.0 * dur + 300.0
            next_sample = t_ready
            while time.monotonic() < t_ready + budget and not _graph_done(g, tmp):
                now = time.monotonic()
                if len(finished) == len(devices):  # the finalize: sample it closely from now on
                    next_sample = min(next_sample, now + SOAK_FINALIZE_SAMPLE_S)
                if now >= next_sample:
                    sample()
                    next_sample += SOAK_SAMPLE_S if len(finished) < len(devices) else SOAK_FINALIZE_SAMPLE_S
                time.sleep(0.2)
            sample()  # the end of the finalize: the products are written
            done = _graph_done(g, tmp)
    if not done:
        raise RuntimeError(f"soak: no products after {budget:.0f} s; see {log_path}")
    if set(started) != set(devices) or set(finished) != set(devices):
        raise RuntimeError(f"soak: devices that never started / finished publishing: {sorted(set(devices) - set(started))} / "
                           f"{sorted(set(devices) - set(finished))}; see {log_path}")
    t_data0, t_data1 = max(started.values()), max(finished.values())
    timing = json.loads(next((tmp / "out").glob("*/status.json")).read_text()).get("timing", {})
    lost, n_msgs = _graph_loss(tmp, scen, subs, dur)

    labels = sample.labels()
    rel = [t - t_data0 for t in sample.times]
    phase = ["start" if t < t_data0 else "data" if t <= t_data1 else "finalize" for t in sample.times]
    rss_mb: dict[str, list[float | None]] = {k: [round(r[k], 1) if k in r else None for r in sample.rss] for k in labels}
    peak = {k: round(max([sample.hwm.get(k, 0.0)] + [v for v in rss_mb[k] if v is not None]), 1) for k in labels}
    if sample.worker_hwm:
        peak["transfer_align_node/worker_each"] = round(max(sample.worker_hwm.values()), 1)
    growth: dict[str, float | None] = {}
    for k in labels:
        pts = np.array([(r / 60.0, v) for r, ph, v in zip(rel, phase, rss_mb[k]) if ph == "data" and v is not None])
        growth[k] = round(float(np.polyfit(pts[:, 0], pts[:, 1], 1)[0]), 3) if len(pts) >= 2 else None
    processing_s = float(timing.get("processing_s", np.nan))
    results["soak_duration_s"] = dur
    results["soak_loss_count"] = lost
    results["soak_messages"] = n_msgs
    results["soak_rss_mb"] = rss_mb
    results["soak_rss_t_s"] = [round(r, 1) for r in rel]
    results["soak_rss_phase"] = phase
    results["soak_peak_rss_mb"] = peak
    results["soak_rss_growth_mb_per_min"] = growth
    results["soak_processing_time_ratio"] = processing_s / dur
    results["soak_data_wall_s"] = round(t_data1 - t_data0, 1)

    print(f"soak: {n_msgs} messages of /master/imu, /master/nav + 6 sub-IMUs at 200 Hz over {dur:.0f} s of data "
          f"(every device publishing for {t_data1 - t_data0:.0f} s wall): lost {lost}; finalize {processing_s:.1f} s "
          f"(ratio {processing_s / dur:.3f}); {len(rel)} memory samples (every {SOAK_SAMPLE_S:g} s, "
          f"{SOAK_FINALIZE_SAMPLE_S:g} s in the finalize)")
    data_i = [i for i, ph in enumerate(phase) if ph == "data"]
    fin_i = [i for i, ph in enumerate(phase) if ph == "finalize"]
    cols = [data_i[0], data_i[len(data_i) // 2], data_i[-1]] if data_i else [None, None, None]

    def mb(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    w = max(len(k) for k in labels)
    print(f"  {'RSS [MB]':<{w}}  {'start':>7} {'middle':>7} {'end':>7}  {'finalize':>8} {'VmHWM':>7}  {'MB/min':>7}")
    for k in labels:
        fin = [v for i in fin_i if (v := rss_mb[k][i]) is not None]
        gk = growth[k]
        print(f"  {k:<{w}}  " + " ".join(f"{mb(None if i is None else rss_mb[k][i]):>7}" for i in cols)
              + f"  {mb(max(fin) if fin else None):>8} {peak[k]:>7.1f}  {'-' if gk is None else f'{gk:+.3f}':>7}")
    print(f"  (start / middle / end: samples of the data flow, t = {', '.join(mb(None if i is None else rel[i]) for i in cols)} s; "
          "finalize: the largest sample after it; VmHWM: the peak of the process's life; MB/min: least-squares slope "
          "over the data flow"
          + (f"; workers: the smoother processes of transfer_align_node summed, {len(sample.worker_hwm)} process(es), "
             f"the largest VmHWM {peak['transfer_align_node/worker_each']:.1f} MB" if sample.worker_hwm else "") + ")")


def bench_bagio(results: dict, repeats: int) -> None:
    """rosbag2 MCAP writing and reading (dpos_ros.io.bag, the fast path) on a generated bag of 1.2 M
    fixed-size messages (6 Imu and 6 Odometry topics at 200 Hz, 500 s), and rosbags' Writer /
    AnyReader message by message on a tenth of it, side by side: seconds per million messages."""
    import shutil
    import tempfile

    from dpos_ros.contract import cdr
    from dpos_ros.io import bag
    from dpos_ros.io.streams import TopicStream

    def values(rng: np.random.Generator, n: int, n_doubles: int, varying: list[int]) -> np.ndarray:
        """Noisy values in the ``varying`` columns, the covariances constant (as the products write them)."""
        v = np.tile(np.linspace(1e-6, 1e-3, n_doubles), (n, 1))
        v[:, varying] = rng.normal(size=(n, len(varying)))
        return v

    def streams(n: int) -> list[TopicStream]:
        rng = np.random.default_rng(1)
        t = 1_600_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 5_000_000
        out = []
        for k in range(6):  # Imu: orientation, rate and acceleration vary; odometry: pose and twist
            imu = cdr.layout("imu", f"sub_imu_{k}")
            vals = values(rng, n, cdr.IMU_DOUBLES, [*range(4), *range(13, 16), *range(25, 28)])
            out.append(TopicStream(f"/sub_imu/s{k}/imu", "sensor_msgs/msg/Imu", t, rows=cdr.encode(imu, t, vals)))
            odom = cdr.layout("odometry", "enu", f"antenna_{k}")
            vals = values(rng, n, cdr.ODOM_DOUBLES, [*range(7), *range(43, 49)])
            out.append(TopicStream(f"/antenna/a{k}/odom", "nav_msgs/msg/Odometry", t, rows=cdr.encode(odom, t, vals)))
        return out

    tmp = Path(tempfile.mkdtemp(prefix="bench_bagio_"))
    try:
        full, tenth = streams(100_000), streams(10_000)
        n_full, n_tenth = sum(len(s) for s in full), sum(len(s) for s in tenth)
        for s, name in ((full, "fast"), (tenth, "small")):  # numba kernels compiled / loaded
            bag.write_streams(tmp / f"warm_{name}", s[:2])
            bag.read_raw(tmp / f"warm_{name}")
        t0 = time.perf_counter()
        bag.write_streams(tmp / "fast", full)
        w_fast = time.perf_counter() - t0
        t0 = time.perf_counter()
        raw = bag.read_raw(tmp / "fast")
        r_fast = time.perf_counter() - t0
        assert sum(len(v.blobs) for v in raw.values()) == n_full
        del raw
        t0 = time.perf_counter()
        bag.write_streams_rosbags(tmp / "ref", tenth)
        w_ref = time.perf_counter() - t0
        t0 = time.perf_counter()
        raw = bag.read_raw_rosbags(tmp / "ref")
        r_ref = time.perf_counter() - t0
        assert sum(len(v.blobs) for v in raw.values()) == n_tenth
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    per_m = {"write": w_fast / n_full * 1e6, "read": r_fast / n_full * 1e6,
             "rosbags_write": w_ref / n_tenth * 1e6, "rosbags_read": r_ref / n_tenth * 1e6}
    for k, v in per_m.items():
        results[f"bagio_{k}_s_per_million"] = v
    results["bagio_write_speedup_vs_rosbags"] = per_m["rosbags_write"] / per_m["write"]
    results["bagio_read_speedup_vs_rosbags"] = per_m["rosbags_read"] / per_m["read"]
    print(f"bag io: {n_full} messages written in {w_fast:.2f} s, read in {r_fast:.2f} s "
          f"({per_m['write']:.2f} / {per_m['read']:.2f} s per million); rosbags on {n_tenth}: "
          f"{per_m['rosbags_write']:.1f} / {per_m['rosbags_read']:.1f} s per million "
          f"(x{results['bagio_write_speedup_vs_rosbags']:.1f} / x{results['bagio_read_speedup_vs_rosbags']:.1f})")


def _run_watched(cmd: list[str], cap_mb: float, log: Path, single: dict[str, float] | None = None) -> tuple[int | None, float, float, str]:
    """Run ``cmd`` (stdout and stderr to ``log``), sampling the summed RSS of its process tree
    every 0.5 s; kill the tree if it exceeds ``cap_mb``.  Returns (exit status or None when
    killed, wall s, peak summed RSS MB, status); ``single["mb"]``: the largest RSS of one process."""
    import signal
    import subprocess

    t0 = time.perf_counter()
    with log.open("w") as out:
        p = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        peak = 0.0
        status = "ok"
        while p.poll() is None:
            mems = [m[0] for q in [p.pid, *_descendants(p.pid)] if (m := _proc_mem_mb(q)) is not None]
            peak = max(peak, sum(mems))
            if single is not None and mems:
                single["mb"] = max(single.get("mb", 0.0), max(mems))
            if peak > cap_mb:
                status = f"killed at {time.perf_counter() - t0:.0f} s: summed RSS {peak:.0f} MB > cap {cap_mb:.0f} MB"
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
                return None, time.perf_counter() - t0, peak, status
            time.sleep(0.5)
    return p.returncode, time.perf_counter() - t0, peak, status


def _long_scenario(path: Path, duration_s: float) -> Path:
    """A paper_wing scenario (its aircraft, rates, sensors) of ``duration_s`` seconds: a racetrack
    of imaging lines (840 s straight, named) joined by 60 s 180-degree coordinated turns."""
    import yaml

    d = yaml.safe_load((REPO / "src/dpos_core/dpos_core/config/scenarios/paper_wing.yaml").read_text())
    segs, names, t = [], [], 0.0
    while t < duration_s - 1e-9:
        line = min(840.0, duration_s - t)
        names.append(f"line{len(names) + 1:03d}")
        segs.append({"name": names[-1], "duration_s": line})
        t += line
        if t < duration_s - 1e-9:
            turn = min(60.0, duration_s - t)
            segs.append({"duration_s": turn, "heading_change_deg": 180.0 * turn / 60.0})
            t += turn
    d.update(name=f"long_wing_{duration_s:g}s", source="bench/run_bench.py long_flight",
             description=f"paper_wing's aircraft and sensors, {duration_s:g} s of racetrack", imaging_segments=names)
    d["flight"]["segments"] = segs
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


def _flight_label(d_s: float) -> str:
    return f"{d_s / 3600:g}h" if d_s % 3600 == 0 else f"{d_s:g}s"


def bench_long_flight(results: dict, repeats: int, durations_s: tuple[float, ...] = (3600.0, 7200.0, 14400.0),
                      rss_cap_mb: float = 6000.0, tmp_root: str | None = None, bags_dir: Path | None = None) -> None:
    """The long flights (module docstring, ``long_flight_*``): a run per duration, not repeated.
    ``bags_dir``: where the simulated recordings are kept and reused (module docstring)."""
    import shutil
    import tempfile

    bindir = Path(sys.executable).parent
    last = None
    for d in sorted(durations_s):
        key = f"long_flight_{_flight_label(d)}"
        tmp = Path(tempfile.mkdtemp(prefix="dpos_long_", dir=tmp_root))
        try:
            need = 0.3e6 * d  # the bag without truth: about 0.25 MB per second of paper_wing
            free = shutil.disk_usage(tmp).free
            if free < 2 * need:
                results[f"{key}_status"] = f"not run: the bag (~{need / 1e9:.1f} GB) does not fit {tmp} ({free / 1e9:.1f} GB free)"
                print(f"{key}: {results[f'{key}_status']}")
                continue
            scen = _long_scenario(tmp / "long_wing.yaml", d)
            keep = None if bags_dir is None else Path(bags_dir) / f"long_wing_{d:g}s"
            reuse = (keep is not None and (keep / "bag" / "metadata.yaml").is_file() and (keep / "long_wing.yaml").is_file()
                     and (keep / "long_wing.yaml").read_text() == scen.read_text())
            bag = keep / "bag" if keep is not None else tmp / "bag"
            results[f"{key}_bag_reused"] = reuse
            if not reuse:
                if keep is not None:
                    shutil.rmtree(keep, ignore_errors=True)
                    keep.mkdir(parents=True)
                rc, wall, peak, status = _run_watched([str(bindir / "dpos-sim"), "--scenario", str(scen),
                                                       "--window", "60", "--no-truth", "--out", str(bag)], rss_cap_mb, tmp / "sim.log")
                results[f"{key}_sim_peak_rss_mb"], results[f"{key}_sim_time_ratio"] = round(peak, 1), round(wall / d, 5)
                if rc != 0:
                    results[f"{key}_status"] = f"simulation failed: {status if rc is None else (tmp / 'sim.log').read_text()[-500:]}"
                    print(f"{key}: {results[f'{key}_status']}")
                    continue
                if keep is not None:  # (written last: a recording cut short by a failure is not reused)
                    shutil.copyfile(scen, keep / "long_wing.yaml")
            results[f"{key}_bag_mb"] = round(sum(f.stat().st_size for f in bag.iterdir()) / 1e6, 1)
            one: dict[str, float] = {}
            load0 = os.getloadavg()[0]
            rc, wall, peak, status = _run_watched([str(bindir / "dpos-process"), str(bag), "--out", str(tmp / "products"),
                                                   "--workers", "2", "--stream", "on"], rss_cap_mb, tmp / "process.log", one)
            results[f"{key}_largest_process_rss_mb"] = round(one.get("mb", 0.0), 1)
            results[f"{key}_loadavg"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
            if rc not in (0, 1):  # 1: some antenna not estimated (products written)
                status = status if rc is None else f"dpos-process exit {rc}: {(tmp / 'process.log').read_text()[-500:]}"
            results[f"{key}_status"] = status
            wm = tmp / "worker.json"  # one worker task alone (memory flat with the flight)
            if subprocess.run([sys.executable, str(Path(__file__).with_name("worker_memory.py")), str(bag), "--json", str(wm)],
                              capture_output=True).returncode == 0:
                w = json.loads(wm.read_text())
                results[f"{key}_worker_task_peak_rss_mb"] = round(w["peak_rss_mb"], 1)
                results[f"{key}_worker_task_s"] = round(w["wall_s"], 1)
            results[f"{key}_peak_rss_mb"] = round(peak, 1) if rc in (0, 1) else None
            results[f"{key}_time_ratio"] = round(wall / d, 5) if rc in (0, 1) else None
            print(f"{key}: dpos-process peak {peak:.0f} MB, {wall:.0f} s (ratio {wall / d:.4f}, load {load0:.1f} -> "
                  f"{os.getloadavg()[0]:.1f}), {status}; "
                  + (f"recording reused from {bag}" if reuse else f"simulation peak {results[f'{key}_sim_peak_rss_mb']:.0f} MB, "
                     f"ratio {results[f'{key}_sim_time_ratio']:.4f}") + f"; bag {results[f'{key}_bag_mb']} MB")
            last = key
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    if last is not None:
        results["long_flight_peak_rss_mb"] = results.get(f"{last}_peak_rss_mb")
        results["long_flight_time_ratio"] = results.get(f"{last}_time_ratio")
        results["long_flight_duration_s"] = max(durations_s)


BENCHES: dict[str, Callable[..., None]] = {
    "strapdown": bench_strapdown,
    "sim": bench_sim,
    "transfer_alignment": bench_transfer_alignment,
    "cdvf": bench_cdvf,
    "wing": bench_wing,
    "ifa": bench_ifa,
    "sar": bench_sar,
    "bagio": bench_bagio,
    "graph": bench_graph,
    "replay": bench_replay,
    "soak": bench_soak,
    "long_flight": bench_long_flight,
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=sorted(BENCHES), action="append", help="run only these benchmarks")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--soak-s", type=float, default=600.0, metavar="S",
                    help="seconds of data of the soak benchmark (600; 0 skips it)")
    ap.add_argument("--long-flight-s", default="3600,7200,14400", metavar="S,S,...",
                    help="flight durations [s] of the long_flight benchmark (default 1 h, 2 h, 4 h)")
    ap.add_argument("--long-flight-bags", type=Path, default=None, metavar="DIR",
                    help="keep the long_flight recordings in DIR and reuse them (the same scenario); default: simulated and deleted each run")
    ap.add_argument("--long-flight-rss-cap-mb", type=float, default=6000.0, metavar="MB",
                    help="kill a long_flight run whose summed RSS exceeds this (the machine is shared)")
    args = ap.parse_args(argv)
    options: dict[str, dict[str, Any]] = {
        "soak": {"soak_s": args.soak_s},
        "long_flight": {"durations_s": tuple(float(x) for x in args.long_flight_s.split(",")), "rss_cap_mb": args.long_flight_rss_cap_mb,
                        "bags_dir": args.long_flight_bags}}
    results: dict = {}
    for name, fn in BENCHES.items():
        if args.only and name not in args.only:
            continue
        fn(results, args.repeats, **options.get(name, {}))
    results["machine"] = {"cpus": os.cpu_count(), "python": sys.version.split()[0]}
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
