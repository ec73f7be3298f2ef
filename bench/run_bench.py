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
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dpos_core.analytic_trajectory import CoordinatedTurnClimb  # noqa: E402
from dpos_core.attitude import dcm_to_quat  # noqa: E402
from dpos_core.frames import hpr_from_C_nb  # noqa: E402
from dpos_core.strapdown import NavState, Strapdown  # noqa: E402

RESULTS = Path(__file__).with_name("results.json")


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


BENCHES: dict[str, Callable[[dict, int], None]] = {
    "strapdown": bench_strapdown,
    "sim": bench_sim,
    "transfer_alignment": bench_transfer_alignment,
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
