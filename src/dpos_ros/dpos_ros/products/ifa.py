"""``dpos-eval`` for in-flight-alignment scenarios (paper_ifa): argument handling and output of
:mod:`dpos_core.evaluation.ifa`.

    dpos-eval --scenario paper_ifa --methods add2,dd2,aekf --runs 5 --seed 1 --out /tmp/ifa
    dpos-eval --scenario paper_ifa --runs 3 --heading-sweep 10,45,90,135,180 --no-table --out /tmp/sweep
    dpos-eval --scenario paper_ifa --runs 3 --outage 300,30 --noise-jump 240,10 --no-table --out /tmp/robust
    dpos-eval --scenario mems_vehicle --methods add2 --runs 4 --consistency --no-table --out /tmp/mems
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from dpos_core.evaluation import ifa as E
from dpos_core.sim.scenario import Scenario


def _pair(ap: argparse.ArgumentParser, text: str | None, name: str) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        ap.error(f"--{name} takes two numbers 'A,B', got {text!r}")
    return a, b


def main_ifa(ap: argparse.ArgumentParser, args: argparse.Namespace, scenario: Scenario, methods: list[str]) -> int:
    """Run the experiments asked for with ``methods`` (checked against the core's METHODS by the
    caller), write ``metrics.json`` and ``report.md`` to ``args.out``."""
    if args.runs < 1:
        ap.error("--runs must be >= 1")
    outage = _pair(ap, args.outage, "outage")
    jump = _pair(ap, args.noise_jump, "noise-jump")
    if outage and outage[1] <= 0:
        ap.error("--outage duration must be > 0")
    if jump and jump[1] <= 0:
        ap.error("--noise-jump scale must be > 0")
    try:
        sweep = [float(v) for v in args.heading_sweep.split(",")] if args.heading_sweep else None
    except ValueError:
        ap.error(f"--heading-sweep takes numbers 'D1,D2,..', got {args.heading_sweep!r}")
    h0 = args.initial_heading_error if args.initial_heading_error is not None else float(scenario.ifa.get("initial_heading_error_deg", 30.0))
    seeds = [args.seed + r for r in range(args.runs)]
    ev = E.Evaluator(scenario, duration_s=args.duration)
    parts: dict = {}
    if not args.no_table:
        parts["methods"] = E.table(ev, methods, seeds, h0)
        for m, d in parts["methods"].items():
            a = d["mean"]["mean_abs"]
            print(f"{m:>5}: final |error| heading {a['heading_deg']:.4f} pitch {a['pitch_deg']:.5f} roll {a['roll_deg']:.5f} deg "
                  f"({d['timing']['processing_s'] / len(seeds):.2f} s per run)", flush=True)
    if sweep:
        parts["heading_sweep"] = E.sweep(ev, methods, seeds, sweep)
    if outage:
        parts["outage"] = {"t0_s": outage[0], "duration_s": outage[1], "methods": E.outage(ev, methods, seeds, h0, *outage)}
    if jump:
        parts["noise_jump"] = {"t0_s": jump[0], "scale": jump[1], "methods": E.noise_jump(ev, methods, seeds, h0, *jump)}
    if args.consistency:
        outs = [(iv.t_start_s, iv.t_end_s) for iv in scenario.gnss.schedule if iv.outage]
        o = outs[0] if outs else None
        parts["consistency"] = {"outage_s": o, "filters": E.consistency(scenario, seeds, methods[0], args.duration, o)}
    metrics = E.metrics_json(scenario.name, seeds, h0, ev.cfg, parts)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    report = E.report_md(metrics)
    (out / "report.md").write_text(report + "\n")
    print(report)
    print(f"wrote {out / 'metrics.json'} and {out / 'report.md'}")
    return 0
