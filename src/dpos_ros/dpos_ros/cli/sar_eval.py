"""``dpos-eval`` on a SINS/SAR scenario (a ``sar:`` block, ``paper_sar``): [Yan2016] Table 2.

    dpos-eval --scenario paper_sar --methods ekf,ukf,oracle,pf,rpf,mcmc_rpf --particles 1000 \\
        --runs 10 --seed 1 --particle-sweep 100,300,1000,3000 --out out/sar

Each run simulates the scenario with seed S + r (dpos_core.evaluation.sar: free SINS, SAR and
barometer measurements) and runs every method on the same data.  Writes ``metrics.json``,
``report.md`` (Table 2's MAE and STD of the attitude and position errors over 100-1000 s per
method, the oracle beside them, the paper's error ranges beside ours), ``ess.csv`` / ``ess.png``
(the particle filters' effective sample size and distinct particles over time, means over the
runs) and, with ``--particle-sweep``, ``particles.csv`` / ``particles.png`` (each particle
filter's accuracy against its particle count, the Gaussian filters' as lines).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dpos_core.evaluation.sar import COMPONENTS, PAPER_RANGES, WINDOW_S, problem, run_methods
from dpos_core.filters.pf import PF_METHODS
from dpos_core.sar.pipeline import METHODS, ORACLE
from dpos_core.sim.scenario import Scenario
from dpos_core.sim.session import SimulatedSession

_UNITS = ("'", "'", "'", "m", "m", "m")


def sar_methods(text: str | None) -> list[str]:
    """The ``--methods`` of a SINS/SAR scenario (default: all and the oracle); ValueError naming
    the unknown ones."""
    known = METHODS + (ORACLE,)
    methods = [m.strip() for m in (text or ",".join(known)).split(",") if m.strip()]
    bad = [m for m in methods if m not in known]
    if bad or not methods:
        raise ValueError(f"unknown SINS/SAR method(s) {bad}; choose from {known}")
    return methods


def _sweep(text: str | None) -> list[int]:
    if not text:
        return []
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--particle-sweep must be a comma list of particle counts, got {text!r}") from None
    if not out or min(out) < 2:
        raise ValueError(f"--particle-sweep counts must be >= 2, got {text!r}")
    return out


def score(stats: dict[str, dict[str, float]]) -> tuple[float, float]:
    """The sweep's two accuracy figures: mean attitude MAE [arcmin] and mean position MAE [m]."""
    return float(np.mean([stats[c]["mae"] for c in COMPONENTS[:3]])), float(np.mean([stats[c]["mae"] for c in COMPONENTS[3:]]))


def main_sar(ap: argparse.ArgumentParser, args: argparse.Namespace, scenario: Scenario) -> int:
    """Run the evaluation (module docstring); usage errors through ``ap.error``."""
    try:
        methods = sar_methods(args.methods)
        sweep = _sweep(getattr(args, "particle_sweep", None))
    except ValueError as e:
        ap.error(str(e))
    if args.particles < 2:
        ap.error(f"--particles must be >= 2 for the particle filters, got {args.particles}")
    bw = float(getattr(args, "bandwidth_scale", 1.0) or 1.0)
    if not (np.isfinite(bw) and bw > 0):
        ap.error(f"--bandwidth-scale must be > 0, got {bw:g}")
    if args.duration is not None and args.duration > scenario.duration_s:
        ap.error(f"--duration {args.duration:g} s exceeds the scenario {scenario.name}'s {scenario.duration_s:g} s")
    if args.duration is not None and args.duration <= WINDOW_S[0]:
        ap.error(f"--duration must exceed the {WINDOW_S[0]:g} s the statistics start at, got {args.duration:g}")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    per_run: list[dict[str, dict]] = []
    sweep_runs: dict[int, list[dict[str, dict]]] = {n: [] for n in sweep}
    t_s = None
    for r in range(args.runs):
        seed = args.seed + r
        prob = problem(SimulatedSession(scenario, seed, args.duration))
        t_s = prob.model.track.t_s
        res = run_methods(prob, methods, args.particles, seed, bw)
        per_run.append(res)
        for m, v in res.items():
            print(f"run {r + 1}/{args.runs} seed {seed} {m:9s} " + " ".join(f"{c} {v['stats'][c]['mae']:.3g}" for c in COMPONENTS)
                  + f"  {v['seconds']:.1f} s", flush=True)
        pfs = [m for m in methods if m in PF_METHODS]
        for n in sweep:
            sweep_runs[n].append(run_methods(prob, pfs, n, seed, bw) if n != args.particles else {m: res[m] for m in pfs})
            print(f"run {r + 1}/{args.runs} sweep N={n}: " + " ".join(
                f"{m} {score(sweep_runs[n][-1][m]['stats'])[1]:.3g} m" for m in pfs), flush=True)
    assert t_s is not None
    metrics = combine(per_run, methods)
    metrics["scenario"], metrics["runs"], metrics["seed"] = scenario.name, args.runs, args.seed
    metrics["particles"], metrics["bandwidth_scale"], metrics["window_s"] = args.particles, bw, list(WINDOW_S)
    if sweep:
        metrics["particle_sweep"] = {str(n): combine(sweep_runs[n], list(sweep_runs[n][0]))["methods"] for n in sweep}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    write_ess(out, t_s, per_run, [m for m in methods if m in PF_METHODS])
    if sweep:
        write_sweep(out, metrics, methods, sweep)
    (out / "report.md").write_text(report_md(metrics, methods, args, sweep))
    print(f"wrote {out / 'metrics.json'} and {out / 'report.md'}")
    return 0


def combine(per_run: list[dict[str, dict]], methods: list[str]) -> dict:
    """Means over the runs of each method's MAE and STD per component, the extreme min / max,
    the processing seconds and, for the particle filters, the mean ESS, distinct particles and
    MH acceptance."""
    out: dict = {"methods": {}}
    for m in methods:
        st = [r[m]["stats"] for r in per_run]
        d: dict = {c: {"mae": float(np.mean([s[c]["mae"] for s in st])), "std": float(np.mean([s[c]["std"] for s in st])),
                       "min": float(np.min([s[c]["min"] for s in st])), "max": float(np.max([s[c]["max"] for s in st]))}
                   for c in COMPONENTS}
        d["seconds"] = float(np.mean([r[m]["seconds"] for r in per_run]))
        for k in ("ess", "distinct", "accept"):
            if k in per_run[0][m]:
                vals = np.concatenate([np.asarray(r[m][k], dtype=float) for r in per_run])
                d[f"mean_{k}"] = float(np.nanmean(vals)) if np.isfinite(vals).any() else None
        out["methods"][m] = d
    return out


def write_ess(out: Path, t_s: np.ndarray, per_run: list[dict[str, dict]], pfs: list[str]) -> None:
    """``ess.csv`` (t_s, per filter the mean ESS and distinct particles over the runs) and ``ess.png``."""
    if not pfs:
        return
    cols = {}
    for m in pfs:
        cols[f"{m}_ess"] = np.mean([r[m]["ess"] for r in per_run], axis=0)
        cols[f"{m}_distinct"] = np.mean([r[m]["distinct"] for r in per_run], axis=0)
    head = "t_s," + ",".join(cols)
    np.savetxt(out / "ess.csv", np.column_stack([t_s, *cols.values()]), delimiter=",", header=head, comments="", fmt="%.6g")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for m in pfs:
        ax[0].plot(t_s, cols[f"{m}_ess"], label=m, lw=0.8)
        ax[1].plot(t_s, cols[f"{m}_distinct"], label=m, lw=0.8)
    ax[0].set_ylabel("ESS after the update")
    ax[1].set_ylabel("distinct particles carried on")
    ax[1].set_xlabel("t [s]")
    ax[0].legend()
    ax[0].set_title("paper_sar: effective sample size and distinct particles (mean over runs)")
    fig.tight_layout()
    fig.savefig(out / "ess.png", dpi=110)
    plt.close(fig)


def write_sweep(out: Path, metrics: dict, methods: list[str], sweep: list[int]) -> None:
    """``particles.csv`` / ``particles.png``: each PF's mean attitude and position MAE against N."""
    pfs = [m for m in methods if m in PF_METHODS]
    rows = []
    for n in sweep:
        for m in pfs:
            a, p = score(metrics["particle_sweep"][str(n)][m])
            rows.append((n, m, a, p))
    with open(out / "particles.csv", "w") as f:
        f.write("particles,method,attitude_mae_arcmin,position_mae_m\n")
        for n, m, a, p in rows:
            f.write(f"{n},{m},{a:.6g},{p:.6g}\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for m in pfs:
        ax[0].loglog(sweep, [r[2] for r in rows if r[1] == m], "o-", label=m)
        ax[1].loglog(sweep, [r[3] for r in rows if r[1] == m], "o-", label=m)
    for m in methods:
        if m not in PF_METHODS:
            a, p = score(metrics["methods"][m])
            ax[0].axhline(a, ls="--", lw=0.8, color="k" if m == ORACLE else None, label=m)
            ax[1].axhline(p, ls="--", lw=0.8, color="k" if m == ORACLE else None, label=m)
    ax[0].set_ylabel("mean attitude MAE [arcmin]")
    ax[1].set_ylabel("mean position MAE [m]")
    for a_ in ax:
        a_.set_xlabel("particles N")
        a_.legend(fontsize=7)
    fig.suptitle("paper_sar: particles vs accuracy, 100-1000 s (mean over runs)")
    fig.tight_layout()
    fig.savefig(out / "particles.png", dpi=110)
    plt.close(fig)


def report_md(metrics: dict, methods: list[str], args: argparse.Namespace, sweep: list[int]) -> str:
    """[Yan2016] Table 2's layout with the oracle, the paper's error ranges beside ours."""
    ms = metrics["methods"]
    head = " | ".join(f"{c} MAE / STD [{u}]" for c, u in zip(COMPONENTS, _UNITS, strict=True))
    lines = [f"# {metrics['scenario']}: [Yan2016] Table 2 layout", "",
             f"{args.runs} runs from seed {args.seed}, {args.particles} particles, bandwidth {metrics['bandwidth_scale']:g} h_opt; "
             f"errors of the corrected SINS over {WINDOW_S[0]:g}-{WINDOW_S[1]:g} s (attitude in arcmin, position in m); "
             "MAE and STD are means over the runs.", "",
             f"| method | {head} | s/run |", "|---" * (len(COMPONENTS) + 2) + "|"]
    for m in methods:
        d = ms[m]
        lines.append(f"| {m} | " + " | ".join(f"{d[c]['mae']:.3g} / {d[c]['std']:.3g}" for c in COMPONENTS) + f" | {d['seconds']:.1f} |")
    lines += ["", "Error ranges (min, max over all runs) beside [Yan2016]'s (its sec. 5 text; the Table 2 values were lost "
              "in the extraction of the paper):", "", "| method | source | " + " | ".join(COMPONENTS) + " |",
              "|---" * (len(COMPONENTS) + 2) + "|"]
    for m in methods:
        d = ms[m]
        lines.append(f"| {m} | ours | " + " | ".join(f"({d[c]['min']:.3g}, {d[c]['max']:.3g})" for c in COMPONENTS) + " |")
        if m in PAPER_RANGES:
            lines.append(f"| {m} | [Yan2016] | " + " | ".join(f"({a:g}, {b:g})" for a, b in PAPER_RANGES[m]) + " |")
    pf = [m for m in methods if m in PF_METHODS]
    if pf:
        lines += ["", "| particle filter | mean ESS | mean distinct particles carried on | MH acceptance |", "|---|---|---|---|"]
        for m in pf:
            d = ms[m]
            acc = d.get("mean_accept")
            lines.append(f"| {m} | {d['mean_ess']:.1f} | {d['mean_distinct']:.1f} | {'-' if acc is None else f'{acc:.3f}'} |")
    if sweep:
        lines += ["", "Particles vs accuracy (mean attitude MAE [arcmin] / mean position MAE [m]):", "",
                  "| N | " + " | ".join(pf) + " |", "|---" * (len(pf) + 1) + "|"]
        for n in sweep:
            lines.append(f"| {n} | " + " | ".join("{:.3g} / {:.3g}".format(*score(metrics['particle_sweep'][str(n)][m])) for m in pf) + " |")
        g = [m for m in methods if m not in PF_METHODS]
        lines += ["", "Gaussian filters: " + ", ".join("{} {:.3g} / {:.3g}".format(m, *score(ms[m])) for m in g)]
    return "\n".join(lines) + "\n"
