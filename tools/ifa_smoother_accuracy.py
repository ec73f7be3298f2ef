"""Forward-only vs RTS-smoothed main POS against the truth.

    .venv/bin/python tools/ifa_smoother_accuracy.py --scenario paper_ifa --seeds 1,2,3,4,5,6 --window 100:380

Per seed: the in-flight alignment (ADD2, the scenario's filter, 30 deg initial heading error) run
forward with the smoother's record, smoothed (dpos_core.ifa.smoother), and both navigations at the
IMU rate against the truth over the window: RMSE of heading / pitch / roll [deg], velocity E, N, U
[m/s], position E, N, U [m].  Prints a markdown table (per seed and the RMS over the seeds) and
writes the numbers as JSON with --json.

    .venv/bin/python tools/ifa_smoother_accuracy.py --bags /tmp/su_s1,/tmp/su_s2

With ``--bags`` (dpos-sim recordings with /truth/master): the main-POS references of
``dpos-process --master-reference`` (recorded, forward, smoothed; products/master_reference.py)
against the truth over the recording's imaging segments (the transfer alignment's evaluation
window; the whole recording without segments).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from dpos_core.attitude import quat_to_dcm
from dpos_core.earth import dllh_to_enu
from dpos_core.evaluation.ifa import filter_config, initial_state
from dpos_core.frames import hpr_error, hpr_from_C_nb
from dpos_core.ifa.pipeline import run
from dpos_core.ifa.smoother import smooth
from dpos_core.series import NavSeries
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.units import DEG

COLS = ("heading_deg", "pitch_deg", "roll_deg", "vel_e", "vel_n", "vel_u", "pos_e", "pos_n", "pos_u")


def errors(nav: NavSeries, truth: NavSeries) -> np.ndarray:
    """(N, 9): heading / pitch / roll [deg], velocity [m/s], position [m] errors (est - true)."""
    att = hpr_error(hpr_from_C_nb(quat_to_dcm(nav.q_nb)), hpr_from_C_nb(quat_to_dcm(truth.q_nb))) / DEG
    return np.concatenate([att, nav.vel_n_mps - truth.vel_n_mps, dllh_to_enu(nav.llh - truth.llh, truth.llh)], axis=1)


def plot(path: Path, sm, truth: NavSeries, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = sm.nav.t_s
    ef, es = errors(sm.forward, truth)[:, :3], errors(sm.nav, truth)[:, :3]
    sig = np.sqrt(np.diagonal(sm.nav.att_cov, axis1=1, axis2=2)) / DEG  # about E, N, U
    sig_f = np.sqrt(np.diagonal(sm.forward.att_cov, axis1=1, axis2=2)) / DEG
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for i, (ax, name, s_i) in enumerate(zip(axes, ("heading", "pitch", "roll"), (2, 0, 1), strict=True)):
        ax.plot(t, ef[:, i], lw=0.8, label="forward (ADD2)")
        ax.plot(t, es[:, i], lw=0.8, label="smoothed (RTS)")
        ax.fill_between(t, -sig[:, s_i], sig[:, s_i], color="C1", alpha=0.2, lw=0, label="smoothed 1-sigma (about U / E / N)")
        ax.plot(t, sig_f[:, s_i], "C0:", lw=0.6, label="forward 1-sigma")
        lim = 4.0 * max(float(np.percentile(np.abs(ef[t > 60.0, i]), 99)), 1e-4)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{name} error [deg]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right", ncol=2)
    axes[0].set_title(title, fontsize=9)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def recordings(bags: list[Path]) -> None:
    from dpos_core.config import load_aircraft
    from dpos_ros.io.session import read_session
    from dpos_ros.products.master_reference import accuracy, ifa_references

    print("| recording | reference | segment | " + " | ".join(COLS) + " |")
    print("|---" * (len(COLS) + 3) + "|")
    for b in bags:
        sess = read_session(b)
        ac = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
        refs = {"recorded": sess.master, **{k: v.nav for k, v in ifa_references(sess, ac).items()}}
        segs = sess.imaging_segments() or {"session": (float(sess.master.t_s[0]), float(sess.master.t_s[-1]))}
        for name, nav in refs.items():
            for seg, (a, z) in segs.items():
                acc = accuracy(nav, sess.truth["master"], a, z)
                vals = acc["hpr_deg"] + acc["vel_mps"] + acc["pos_m"]
                print(f"| {sess.session_id} | {name} | {seg} | " + " | ".join(f"{v:.3g}" for v in vals) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper_ifa")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--window", default="100:380", metavar="FROM:TO", help="seconds of the flight (default 100:380)")
    ap.add_argument("--heading-error", type=float, default=30.0, metavar="DEG")
    ap.add_argument("--method", default="add2")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--bags", help="comma-separated dpos-sim recordings: the dpos-process main-POS references instead")
    ap.add_argument("--plot", type=Path, help="PNG of the first seed's attitude errors, forward and smoothed, with the smoothed 1-sigma")
    args = ap.parse_args()
    if args.bags:
        recordings([Path(b) for b in args.bags.split(",")])
        return
    lo, hi = (float(v) for v in args.window.split(":"))
    sc = load_scenario(args.scenario)
    rows: dict[str, dict[int, list[float]]] = {"forward": {}, "smoothed": {}}
    info: dict[int, dict] = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        ss = SimulatedSession(sc, seed)
        imu, gnss = ss.master_imu(), ss.gnss()
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run(imu, gnss, sc.aircraft.gnss_lever_arm_m, filter_config(sc), args.method, initial_state(ss, args.heading_error),
                      record_smoother=True)
        t1 = time.perf_counter()
        sm = smooth(res, imu)
        t2 = time.perf_counter()
        truth = ss.truth("master", sm.nav.t_s)
        w = (sm.nav.t_s >= lo) & (sm.nav.t_s <= hi)
        for name, nav in (("forward", sm.forward), ("smoothed", sm.nav)):
            rows[name][seed] = [float(v) for v in np.sqrt(np.mean(errors(nav, truth)[w] ** 2, axis=0))]
        if args.plot is not None and not info:
            plot(args.plot, sm, truth, f"{args.scenario} seed {seed}, {args.method.upper()}, {args.heading_error:g} deg initial heading error")
        info[seed] = {"aligned_s": res.aligned_t_s, "fine_from_step": sm.segments[-1][0], "forward_s": t1 - t0, "smooth_s": t2 - t1}
    seeds = sorted(rows["forward"])
    print(f"{args.scenario}, {args.method.upper()}, {args.heading_error:g} deg initial heading error, window {lo:g}-{hi:g} s, "
          f"RMSE (heading, pitch, roll deg; velocity E N U m/s; position E N U m)\n")
    print("| seed | solution | " + " | ".join(COLS) + " |")
    print("|---" * (len(COLS) + 2) + "|")
    for seed in seeds:
        for name in ("forward", "smoothed"):
            print(f"| {seed} | {name} | " + " | ".join(f"{v:.4g}" for v in rows[name][seed]) + " |")
    for name in ("forward", "smoothed"):
        tot = np.sqrt(np.mean(np.array([rows[name][s] for s in seeds]) ** 2, axis=0))
        print(f"| RMS {seeds[0]}-{seeds[-1]} | {name} | " + " | ".join(f"{v:.4g}" for v in tot) + " |")
    for seed in seeds:
        i = info[seed]
        print(f"seed {seed}: aligned at {i['aligned_s']} s, forward run {i['forward_s']:.1f} s, smoothing {i['smooth_s']:.2f} s")
    if args.json:
        args.json.write_text(json.dumps({"scenario": args.scenario, "window_s": [lo, hi], "columns": COLS, "rows": rows, "info": info}, indent=1))


if __name__ == "__main__":
    main()
