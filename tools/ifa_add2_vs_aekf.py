"""ADD2 against its baseline AEKF on paper_ifa: the controlled comparison of docs/ifa.md (#31 part 7).

    .venv/bin/python tools/ifa_add2_vs_aekf.py --seeds 11,12,13,14,15,16
    .venv/bin/python tools/ifa_add2_vs_aekf.py --seeds 21,22,23,24,25,26 --variants adaptive

Each variant runs the two filters on the same simulated sessions (paper_ifa, 400 s, 30 deg initial
heading error, ``dpos_core.evaluation.ifa.Evaluator``: the same start, Q, prior, bank of heading
hypotheses and GNSS data), so that the only difference inside a variant is the filter's core:

* ``nominal``: DD2 and the EKF with the nominal R, no adaptation (``IfaFilterConfig(adaptive=False)``);
* ``true``: the same with the receiver's true (reported) sigmas (``use_reported_sigma``): the bound;
* ``adaptive``: ADD2 and AEKF with the default change-point noise estimate (the issue's table);
* ``window``: ADD2 and AEKF with eq. 22's 10-epoch window (``r_estimator: window``);
* ``single``: ADD2 and AEKF as ``adaptive`` but one filter from the 30 deg error (no bank of
  heading hypotheses: the linearization at a large heading error that [Fang2012] sec. 3.4 is about).

Prints per variant the final heading / pitch / roll RMSE over the seeds [deg] of both filters, the
per-seed final heading errors, the paired difference of the two filters' final headings in units of
the filters' final heading 1 sigma, and the ratio of the RMSEs; ``--json`` writes the numbers.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dpos_core.evaluation.ifa import Evaluator
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.sim.scenario import load_scenario

#: variant -> (the DD2-side method, the EKF-side method, configuration changes)
VARIANTS: dict[str, tuple[str, str, dict]] = {
    "nominal": ("dd2", "aekf", {"adaptive": False}),
    "true": ("dd2", "aekf", {"adaptive": False, "use_reported_sigma": True}),
    "adaptive": ("add2", "aekf", {}),
    "window": ("add2", "aekf", {"r_estimator": "window"}),
    "single": ("add2", "aekf", {"heading_hypotheses": 1}),
}


def compare(seeds: list[int], variant: str, heading0_deg: float = 30.0) -> dict:
    """Both filters of ``variant`` over ``seeds``: final errors (seeds, 3) [deg], final heading
    1 sigma (seeds,) [deg], processing time [s]."""
    dd_method, ekf_method, kw = VARIANTS[variant]
    sc = load_scenario("paper_ifa")
    cfg = replace(IfaFilterConfig(window=int(sc.ifa.get("window", 10))), **kw)
    out: dict = {"variant": variant, "seeds": seeds, "config": kw}
    for side, method in (("dd", dd_method), ("ekf", ekf_method)):
        ev = Evaluator(sc, cfg)
        fin, sig, t0 = [], [], time.perf_counter()
        for s in seeds:
            r = ev.run(method, s, heading0_deg)
            fin.append(r.final_deg.tolist())
            sig.append(float(r.heading_sigma_deg_final))
        out[side] = {"method": method, "final_deg": fin, "heading_sigma_deg": sig,
                     "rmse_deg": np.sqrt(np.mean(np.square(fin), axis=0)).tolist(), "processing_s": time.perf_counter() - t0}
    a, b = np.asarray(out["dd"]["final_deg"]), np.asarray(out["ekf"]["final_deg"])
    sig_h = 0.5 * (np.asarray(out["dd"]["heading_sigma_deg"]) + np.asarray(out["ekf"]["heading_sigma_deg"]))
    out["paired_heading_diff_sigma"] = ((a[:, 0] - b[:, 0]) / sig_h).tolist()
    out["rmse_ratio"] = (np.asarray(out["dd"]["rmse_deg"]) / np.asarray(out["ekf"]["rmse_deg"])).tolist()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="11,12,13,14,15,16")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, from {', '.join(VARIANTS)}")
    ap.add_argument("--initial-heading-error", type=float, default=30.0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    res = []
    print("| variant | filter | heading | pitch | roll | final heading per seed | (DD - EKF) / sigma_h per seed |")
    print("|---|---|---|---|---|---|---|")
    for v in args.variants.split(","):
        r = compare(seeds, v, args.initial_heading_error)
        res.append(r)
        for side in ("dd", "ekf"):
            d = r[side]
            heads = " ".join(f"{f[0]:+.4f}" for f in d["final_deg"])
            diff = " ".join(f"{x:+.2f}" for x in r["paired_heading_diff_sigma"]) if side == "dd" else ""
            print(f"| {v} | {d['method'].upper()} | " + " | ".join(f"{x:.5f}" for x in d["rmse_deg"]) + f" | {heads} | {diff} |",
                  flush=True)
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
