"""The SINS/SAR particle filters on paper_sar runs, one line per method (docs/sar.md):
mean MAE over the runs of pitch, roll, yaw ['] and lon, lat, alt [m] over 100 s - end, their
(min, max) over all runs, mean ESS, mean distinct particles carried on, MH acceptance, NEES and
CPU seconds per run.

NEES: ``e^T P^-1 e`` of the 15 free error states (the attitude quaternion's vector part, velocity,
position, biases) of each method's reported covariance against the true error state, averaged over
the epochs of the window and the runs (15 for a consistent filter); ``nees9`` the same over the
attitude, velocity and position (9).

    .venv/bin/python bench/sar_pf_table.py --runs 10 --duration 1000 --particles 1000 \\
        --methods ekf,ukf,oracle,pf,rpf,rpf@0.5,mcmc_rpf,mcmc_rpf_literal

(``method@s``: that method at the bandwidth ``s h_opt``; the method's index in the list seeds its
generator as dpos-eval's does.)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dpos_core.evaluation.sar import COMPONENTS, errors, problem, table_stats
from dpos_core.sar.pipeline import ORACLE, run
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession


def nees(x: np.ndarray, P: np.ndarray, xt: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``e^T P^-1 e`` (K,) on the components idx of estimates x (K, n), covariances P (K, n, n)."""
    e = (x - xt)[:, idx]
    S = P[:, idx][:, :, idx]
    S = S + 1e-30 * np.eye(idx.size)
    try:
        return np.einsum("ki,ki->k", e, np.linalg.solve(S, e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        return np.full(e.shape[0], np.inf)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=1000.0)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--methods", default="ekf,pf,rpf,mcmc_rpf")
    ap.add_argument("--bandwidth-scale", type=float, default=1.0)
    ap.add_argument("--window-start", type=float, default=100.0)
    ap.add_argument("--json", type=Path, help="also write the per-run figures here")
    ap.add_argument("--merge", type=Path, nargs="+", help="print the table of these --json files (runs concatenated)")
    a = ap.parse_args()
    if a.merge:
        parts = [json.loads(p.read_text()) for p in a.merge]
        methods = parts[0]["methods"]
        acc = {m: {k: sum((p["acc"][m][k] for p in parts), []) for k in parts[0]["acc"][m]} for m in methods}
        _table(acc, methods, sum(p["runs"] for p in parts), parts[0]["duration"], parts[0]["particles"])
        return
    methods = a.methods.split(",")
    acc: dict[str, dict[str, list]] = {m: {"stats": [], "ess": [], "distinct": [], "accept": [], "nees": [], "nees9": [],
                                           "cpu": []} for m in methods}
    free, nine = np.arange(1, 16), np.arange(1, 10)
    for r in range(a.runs):
        prob = problem(SimulatedSession(load_scenario("paper_sar"), a.seed + r, duration_s=a.duration))
        t = prob.model.track.t_s
        sel = t >= a.window_start
        for i, m in enumerate(methods):
            t0 = time.process_time()
            name, _, bw = m.partition("@")  # rpf@0.5: that method at bandwidth 0.5 h_opt
            est = run(name, prob.model, prob.x0, prob.P0, n_particles=a.particles,
                      rng=np.random.default_rng([a.seed + r, i, a.particles]),
                      truth_x=prob.truth_x if name == ORACLE else None,
                      bandwidth_scale=float(bw) if bw else a.bandwidth_scale)
            d = acc[m]
            d["cpu"].append(time.process_time() - t0)
            d["stats"].append(table_stats(t, errors(prob, est.x), (a.window_start, a.duration)))
            d["nees"].append(float(np.mean(nees(est.x, est.P, prob.truth_x, free)[sel])))
            d["nees9"].append(float(np.mean(nees(est.x, est.P, prob.truth_x, nine)[sel])))
            for key in ("ess", "distinct", "accept"):
                v = est.extra.get(key)
                if v is not None and np.isfinite(v).any():
                    d[key].append(float(np.nanmean(v if key != "distinct" else v[est.extra["resampled"] > 0])
                                        if key != "distinct" or np.any(est.extra["resampled"] > 0) else np.nan))
            print(f"run {r + 1}/{a.runs} {m}: " + " ".join(f"{c} {d['stats'][-1][c]['mae']:.3g}" for c in COMPONENTS)
                  + f" nees {d['nees'][-1]:.3g} cpu {d['cpu'][-1]:.1f}s", flush=True)
    if a.json:
        a.json.write_text(json.dumps({"methods": methods, "runs": a.runs, "duration": a.duration, "particles": a.particles,
                                      "acc": acc}))
    _table(acc, methods, a.runs, a.duration, a.particles)


def _table(acc: dict[str, dict[str, list]], methods: list[str], runs: int, duration: float, particles: int) -> None:
    print(f"\n{runs} runs, {duration:.0f} s, N = {particles}, MAE mean over runs (min, max over all runs)")
    print("| method | " + " | ".join(COMPONENTS) + " | mean ESS | distinct | MH acc | NEES (15) | NEES (9) | CPU s |")
    print("| --- " * (len(COMPONENTS) + 7) + "|")
    for m in methods:
        d = acc[m]
        cells = []
        for c in COMPONENTS:
            mae = np.mean([s[c]["mae"] for s in d["stats"]])
            lo, hi = min(s[c]["min"] for s in d["stats"]), max(s[c]["max"] for s in d["stats"])
            cells.append(f"{mae:.3g} ({lo:.3g}, {hi:.3g})")
        f = lambda k: f"{np.nanmean(d[k]):.3g}" if d[k] else "-"  # noqa: E731
        print(f"| {m} | " + " | ".join(cells) + f" | {f('ess')} | {f('distinct')} | {f('accept')} | {f('nees')} | "
              f"{f('nees9')} | {f('cpu')} |")

if __name__ == "__main__":
    main()
