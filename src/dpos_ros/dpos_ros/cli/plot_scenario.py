"""``dpos-plot-scenario``: PNG figures of a simulated scenario (ground track, wing flexure).

    dpos-plot-scenario --scenario paper_su --seed 1 --out docs/img
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from dpos_core import earth
from dpos_core.attitude import attitude_error, mount_dcm
from dpos_core.config import ConfigError
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli.options import one_line_errors


@one_line_errors("dpos-plot-scenario")
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dpos-plot-scenario", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", required=True)
    ap.add_argument("--aircraft")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True, help="directory for the PNG files")
    args = ap.parse_args(argv)
    try:
        ss = SimulatedSession(load_scenario(args.scenario, aircraft=args.aircraft), args.seed)
    except (ConfigError, ValueError) as e:
        print(f"dpos-plot-scenario: {e}", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args.out.mkdir(parents=True, exist_ok=True)
    sc = ss.scenario
    t = np.arange(0.0, sc.duration_s + 1e-9, 1.0)
    tr = ss.truth("master", t)
    enu = earth.geodetic_to_enu(tr.llh[:, 0], tr.llh[:, 1], tr.llh[:, 2], ss.datum_llh) / 1e3
    fig, ax = plt.subplots(figsize=(6.5, 6), constrained_layout=True)
    ax.plot(enu[:, 0], enu[:, 1], color="0.4", lw=1.2, label="flight")
    fl = ss.flight
    for name in sc.imaging_segments:
        a, b = fl.segment_bounds(name)
        m = (t >= a) & (t <= b)
        ax.plot(enu[m, 0], enu[m, 1], lw=3, label=f"imaging {name}")
        ax.annotate(name, tuple(enu[m][len(enu[m]) // 2, :2]), textcoords="offset points", xytext=(6, 6))
    ax.plot(*enu[0, :2], "k^", label="start")
    ax.set(xlabel="East [km]", ylabel="North [km]", aspect="equal",
           title=f"{sc.name}: ground track ({sc.duration_s:.0f} s, {sc.start.speed_mps:.0f} m/s)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    track = args.out / f"{sc.name}_track.png"
    fig.savefig(track, dpi=90)
    plt.close(fig)
    written = [track]
    if sc.aircraft.sub_imus:
        s = sc.aircraft.sub_imus[0]
        tf = np.arange(0.0, sc.duration_s + 1e-9, 1.0 / sc.rates.sub_imu_hz)
        C_m = ss.truth("master", tf).C_nb
        C_s = ss.truth(f"sub_imu/{s.name}", tf).C_nb
        # flexure = sub-IMU attitude relative to master * mount * rho, in sub-IMU axes
        C0 = mount_dcm(s.mount_rpy_deg, s.rho_deg)
        rel = attitude_error(C_m @ C0, C_s)  # world-frame rotation taking the rigid mount to the flexed one
        theta = np.einsum("nji,nj->ni", C_s, rel)
        fig, axs = plt.subplots(3, 1, figsize=(8, 6.5), sharex=True, constrained_layout=True)
        var = sc.aircraft.flexure.variance_deg2
        for i, lab in enumerate("xyz"):
            axs[i].plot(tf, np.rad2deg(theta[:, i]), lw=0.6)
            sig = np.sqrt(var[i]) * sc.aircraft.flexure.span_scale(s.span_m)
            for k in (-1, 1):
                axs[i].axhline(k * sig, color="r", lw=0.8, ls="--")
            axs[i].set(ylabel=f"theta_{lab} [deg]")
            axs[i].grid(alpha=0.3)
        axs[0].set_title(f"{sc.name}: wing flexure at {s.name} (span {s.span_m:g} m, FLU axes; dashed: configured 1 sigma)")
        axs[-1].set(xlabel="t [s]")
        flex = args.out / f"{sc.name}_flexure.png"
        fig.savefig(flex, dpi=90)
        plt.close(fig)
        written.append(flex)
    for p in written:
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
