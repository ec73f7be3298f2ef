#!/usr/bin/env python3
"""How far the CDVF's variational state update is from the CDKF's, update by update (docs/cdvf.md).

Runs the ``cdvf`` method ([Ye2024] Algorithm 2, ``dpos_core.filters.variational``) over one
simulated session of a scenario (default ``paper_cdvf``, its first sub-IMU) from a few initial
attitude errors and prints, from the conjugate gradient's record (``TAResult.cg``), the costs of
the first updates (at the prediction ``J0``, at the CDKF's update ``J_cdkf``, at the CDVF's ``J``),
the iterations, and the distance between the two updates in posterior sigmas,
``sqrt(2 (J_cdkf - J))`` (exact for a quadratic cost: ``J_cdkf - J* = 1/2 d^T Gamma d`` with
``Gamma`` the posterior information in the whitened coordinates).

    .venv/bin/python tools/cdvf_update_gap.py [--scenario paper_cdvf] [--seed 1] [--errors 1,10,40]
"""

from __future__ import annotations

import argparse

import numpy as np

from dpos_core.evaluation import ta as from_sim
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import pipeline
from dpos_core.ta.model import TAConfig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper_cdvf")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--errors", default="1,10,40", help="initial attitude errors [deg] on heading, pitch, roll (comma list)")
    args = ap.parse_args(argv)
    try:
        errors = [float(e) for e in args.errors.split(",")]
    except ValueError:
        ap.error(f"--errors must be a comma list of degrees, got {args.errors!r}")
    if not errors or not all(np.isfinite(e) and e >= 0 for e in errors):
        ap.error(f"--errors must be finite degrees >= 0, got {args.errors!r}")
    sc = load_scenario(args.scenario)
    if not sc.aircraft.sub_imus:
        ap.error(f"scenario {sc.name} has no sub-IMU")
    sub = sc.aircraft.sub_imus[0].name
    ss = SimulatedSession(sc, args.seed)
    imu, master, ins = from_sim.sub_imu(ss, sub), from_sim.master_nav(ss), from_sim.installation(ss, sub)
    print(f"{sc.name} seed {args.seed}, sub-IMU {sub}, method cdvf")
    for err in errors:
        r = pipeline.run_segments(imu, master, ins, pipeline.TASettings(method="cdvf", initial_attitude_error_deg=err),
                                  cfg=TAConfig(attitude_sigma_deg=max(err, 1.0)))
        cg = r.cg
        assert cg is not None
        u = np.flatnonzero(cg.updated)
        gap = np.sqrt(2.0 * np.maximum(cg.cost_cdkf[u] - cg.cost[u], 0.0))
        first = "; ".join(f"{cg.cost_prior[k]:.4g} / {cg.cost_cdkf[k]:.4g} / {cg.cost[k]:.4g} ({cg.iterations[k]} it)" for k in u[:3])
        later = gap[10:]
        print(f"{err:g} deg: {u.size} updates; first three J0 / J_cdkf / J: {first}")
        print(f"    CDKF update -> CDVF update [posterior sigma]: first {gap[0]:.3g}, updates 2-10 max {gap[1:10].max():.3g}, "
              f"after: median {np.median(later):.2g}, 99 % {np.quantile(later, 0.99):.2g}, max {later.max():.2g}; "
              f"iterations mean {cg.iterations[u].mean():.2f}, max {cg.iterations[u].max()}; "
              f"stopped by the gradient rule {np.mean(cg.stop[u] == 'gradient'):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
