#!/usr/bin/env python3
"""Integrate every scenario's truth IMU outputs with the dpos strapdown and print the largest
errors against the simulator's truth (markdown table).  The simulator's main self-check
(design.md); test_scenario.py asserts the same with bounds.

    .venv/bin/python tools/sim_check.py [--seed 1]
"""

from __future__ import annotations

import argparse

import numpy as np

from dpos_core import earth
from dpos_core.attitude import attitude_error
from dpos_core.sim.scenario import builtin_scenarios, load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.strapdown import NavState, Strapdown


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print("| scenario | body | duration [s] | IMU [Hz] | max horiz. pos [m] | max height [m] | max vel [m/s] | max att [rad] |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in builtin_scenarios():
        aircraft = "paper_su_pair" if name == "paper_su" else None
        ss = SimulatedSession(load_scenario(name, aircraft=aircraft), args.seed)
        for body in ["master"] + [f"sub_imu/{s.name}" for s in ss.scenario.aircraft.sub_imus]:
            imu = ss.ideal_imu(body)
            tr = ss.truth(body)
            T = np.diff(tr.t_s)[:, None]
            out = Strapdown(NavState(0.0, tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0])).run_increments(imu.t_s, imu.omega_radps * T, imu.f_mps2 * T)
            d = earth.dllh_to_enu(out.llh - tr.llh[1:], tr.llh[1:])
            horiz = np.hypot(d[:, 0], d[:, 1]).max()
            vert = np.abs(d[:, 2]).max()
            vel = np.abs(out.vel_n_mps - tr.vel_n_mps[1:]).max()
            att = np.abs(attitude_error(out.C_nb, tr.C_nb[1:])).max()
            rate = 1.0 / T[0, 0]
            print(f"| {name} | {body} | {ss.duration_s:.0f} | {rate:.0f} | {horiz:.2e} | {vert:.2e} | {vel:.2e} | {att:.2e} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
