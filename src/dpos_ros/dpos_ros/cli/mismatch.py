"""``dpos-eval --mismatch``: the mismatch suite (docs/mismatch.md).

For each case of :data:`dpos_core.evaluation.mismatch.CASES` and each run, the case's truth is simulated
(:func:`dpos_core.evaluation.mismatch.simulate`) and recorded in memory with the *nominal* aircraft file
in its metadata; the transfer alignment gets the nominal aircraft, the oracle the true one (what
its model can express of the case).  Per case: [Gong2018] Table 1 rows (RMSE of UPS, URTSS,
oracle), each method's ratio to the oracle, the goal (heading <= 0.01 deg, baseline <= 5 mm,
heading and baseline within 2x of the oracle) and the reported sigmas against the errors
(fraction within 2 sigma, ANEES per component with its chi-square bounds for the runs).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dpos_core.config import AircraftConfig, config_text
from dpos_core.config.aircraft import scenario_aircraft_ref
from dpos_core.evaluation import mismatch as MM
from dpos_core.evaluation import ta as from_sim
from dpos_core.sim.scenario import Scenario
from dpos_core.ta import metrics as M
from dpos_core.ta.pipeline import ORACLE, TASettings
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io.session import session_from_streams
from dpos_ros.products.evaluate import evaluate
from dpos_ros.products.report import ROWS, combine_runs, metrics_json
from dpos_ros.products.solve import NO_ORACLE, Oracle, solve

#: the goal for every case (docs/mismatch.md, "The table")
GOAL_HEADING_DEG = 0.01
GOAL_BASELINE_M = 0.005
GOAL_RATIO = 2.0


def recording(case: MM.MismatchCase, scenario: Scenario, seed: int, aircraft_text: str, duration_s: float | None = None):
    """The simulated session of ``case`` (the truth) and its in-memory recording, which carries the
    nominal ``aircraft_text`` as ``dpos.aircraft_yaml`` and the case as ``dpos.mismatch``."""
    ss = MM.simulate(case, scenario, seed, duration_s)
    custom = {**session_custom_data(ss, aircraft_text), "dpos.mismatch": case.name}
    return ss, session_from_streams(session_streams(ss), custom, f"{scenario.name}_{case.name}_seed{seed}")


@dataclass(frozen=True)
class CaseRuns:
    """How each case of the suite is run (:func:`run_case`): one simulated recording per seed of
    ``seeds`` (``duration_s``: the scenario's own when None) carrying the nominal ``aircraft_text``;
    the filters' settings of :meth:`settings`."""

    seeds: list[int]
    aircraft_text: str
    particles: int = 100
    duration_s: float | None = None
    initial_attitude_error_deg: float = 0.0
    filter_rate_hz: float = 1.0

    def settings(self, case: MM.MismatchCase, method: str, seed: int) -> TASettings:
        """The transfer alignment's settings of ``method`` on ``case``'s run ``seed``."""
        return TASettings(method=method, particles=self.particles, seed=seed, filter_rate_hz=self.filter_rate_hz,
                          master_error_tau_s=case.master_error_tau_s, initial_attitude_error_deg=self.initial_attitude_error_deg)


def run_case(case: MM.MismatchCase, scenario: Scenario, methods: list[str], plan: CaseRuns, *, log=print,
             filter_aircraft: AircraftConfig | None = None) -> dict:
    """One case over ``plan.seeds``: metrics.json's entry (module docstring).  ``filter_aircraft``: what
    the filters read instead of the nominal aircraft (a what-if: the configuration that would fix a case)."""
    seeds = plan.seeds
    if filter_aircraft is None and case.filters is not None:
        filter_aircraft = case.filters(scenario.aircraft)
    per_method: dict[str, list[dict]] = {m: [] for m in methods}
    timing = {m: {"processing_s": 0.0, "data_s": 0.0} for m in methods}
    sess = None
    for seed in seeds:
        ss, sess = recording(case, scenario, seed, plan.aircraft_text, plan.duration_s)
        truth = {s.name: from_sim.oracle_truth(ss, s.name) for s in ss.scenario.aircraft.sub_imus} if ORACLE in methods else None
        for m in methods:
            t0 = time.perf_counter()
            # the filters read the nominal aircraft; the oracle the true one (what its model can express)
            ac = _with_installation_states(ss.scenario.aircraft, filter_aircraft) if m == ORACLE else (filter_aircraft or scenario.aircraft)
            ants, tm = solve(sess, ac, plan.settings(case, m, seed), oracle=Oracle(truth=truth) if m == ORACLE else NO_ORACLE)
            ev = evaluate(sess, ants, keep_nsq=True)
            per_method[m].append(ev)
            timing[m]["processing_s"] += tm["processing_s"]
            timing[m]["data_s"] += tm["data_s"]
            mean = M.average([{"rmse": e["rmse"], "std": e["std"]} for e in ev.values()])
            log(f"{case.name} seed {seed} {m:>6}: heading {mean['rmse']['heading_deg']:.2e} deg, "
                f"baseline {mean['rmse'].get('baseline_m', float('nan')):.2e} m ({time.perf_counter() - t0:.1f} s)", flush=True)
    combined = combine_runs(per_method, timing)
    metrics = metrics_json(sess, combined, runs=len(seeds), scenario=scenario.name)
    lo, hi = M.nees_bounds(len(seeds))
    entry: dict = {"description": case.description, "oracle_limits": case.oracle_limits, "seeds": seeds,
                   "methods": metrics["methods"], "segments": metrics["segments"], "nees_bounds": [lo, hi]}
    # the run-averaged normalized squared error per epoch inside its chi^2 bounds (pooled over antennas)
    for m in methods:
        inside = {}
        for i, k in enumerate(M.CONS_KEYS):
            fr = []
            for n in per_method[m][0]:
                series = [run[n]["nsq"][:, i] for run in per_method[m] if "nsq" in run.get(n, {})]
                if len(series) != len(seeds):
                    continue
                L = min(s.size for s in series)
                avg = np.mean([s[:L] for s in series], axis=0)
                fr.append(float(np.mean((avg >= lo) & (avg <= hi))) if L else float("nan"))
            if fr:
                inside[k] = float(np.mean(fr))
        if inside:
            entry["methods"][m].setdefault("consistency", {})["epochs_in_nees_bounds"] = inside
        # each run's ANEES (pooled over antennas) and whether the runs' pooled ANEES is inside the bounds
        runs = [M.average_consistency([a["consistency"] for a in run.values() if a.get("consistency")]) for run in per_method[m]]
        if runs and all(r["n"] for r in runs):
            cons = entry["methods"][m].setdefault("consistency", {})
            cons["nees_per_run"] = {k: [r["nees"][k] for r in runs] for k in M.CONS_KEYS}
            if cons.get("nees"):
                cons["nees_in_bounds"] = M.anees_in_bounds(cons["nees"], len(seeds))
    if ORACLE in methods:
        o = metrics["methods"][ORACLE]["mean"]["rmse"]
        entry["ratio_to_oracle"] = {m: {k: (metrics["methods"][m]["mean"]["rmse"][k] / o[k] if o.get(k) else None)
                                        for k in metrics["methods"][m]["mean"]["rmse"]} for m in methods}
    entry["goal"] = {m: goal(entry, m) for m in methods}
    return entry


def _with_installation_states(truth: AircraftConfig, filters: AircraftConfig | None) -> AircraftConfig:
    """The true aircraft with the filters' installation states (the sub-IMUs' ``lever_arm_sigma_m``,
    ``time_offset_sigma_ms``, ``axis_error_states``): the oracle estimates what they estimate, about
    the truth (its datasheet is the true one)."""
    if filters is None:
        return truth
    subs = []
    for s in truth.sub_imus:
        f = filters.sub_imu(s.name)
        subs.append(replace(s, lever_arm_sigma_m=f.lever_arm_sigma_m, time_offset_sigma_ms=f.time_offset_sigma_ms,
                            axis_error_states=f.axis_error_states))
    return replace(truth, sub_imus=tuple(subs))


def goal(entry: dict, m: str) -> dict:
    """The goal for method ``m`` of a case: heading and baseline RMSE and their ratios to the oracle."""
    r = entry["methods"][m]["mean"]["rmse"]
    ratio = entry.get("ratio_to_oracle", {}).get(m, {})
    ok_h = r["heading_deg"] <= GOAL_HEADING_DEG
    ok_b = r.get("baseline_m", np.inf) <= GOAL_BASELINE_M
    ok_r = all(ratio.get(k) is not None and ratio[k] <= GOAL_RATIO for k in ("heading_deg", "baseline_m")) if ratio else None
    return {"heading": bool(ok_h), "baseline": bool(ok_b), "ratio": ok_r, "met": bool(ok_h and ok_b and ok_r is not False)}


def _f(v) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.3g}"


def report_md(doc: dict) -> str:
    """The mismatch table (every case and method: heading, baseline, ratios, consistency), then
    per case the [Gong2018] Table 1 rows of every method and the per-component consistency."""
    lo, hi = next(iter(doc["cases"].values()))["nees_bounds"] if doc["cases"] else (float("nan"), float("nan"))
    lines = [f"# Mismatch suite: {doc['scenario']}", "",
             f"{doc['runs']} run(s) per case (seeds {doc['seeds']}); RMSE over the imaging segments, mean over runs and "
             f"antennas. Goal: heading <= {GOAL_HEADING_DEG} deg, baseline <= {GOAL_BASELINE_M * 1e3:g} mm, both within "
             f"{GOAL_RATIO:g}x of the oracle. Consistency of the reported 1-sigma: fraction of errors within 2 sigma "
             "(0.95 when honest), worst component; ANEES = mean e^2/sigma^2 per component, worst (largest) one, "
             f"with * where it is outside the chi^2 bounds for {doc['runs']} run(s), [{lo:.2f}, {hi:.2f}] (per epoch, and "
             "for the ANEES whatever the errors' correlation in time: metrics.anees_in_bounds). The attitude errors "
             "stay nearly constant over a flight: a few runs' fractions and ANEES scatter widely (docs/mismatch.md).", "",
             "| case | method | heading (deg) | baseline (mm) | heading / oracle | baseline / oracle | worst ratio (row) "
             "| within 2σ (worst) | ANEES (worst) | goal |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, c in doc["cases"].items():
        for m, mm in c["methods"].items():
            r = mm["mean"]["rmse"]
            ratio = c.get("ratio_to_oracle", {}).get(m, {})
            worst = max(((v, k) for k, v in ratio.items() if v is not None), default=(None, ""))
            cons = mm.get("consistency", {})
            w2 = cons.get("within_2sigma", {})
            ne = cons.get("nees", {})
            w2s = f"{min(w2.values()):.2f} ({min(w2, key=w2.get)})" if w2 else "—"
            ib = cons.get("nees_in_bounds", {})
            kw = max(ne, key=ne.get) if ne else ""
            nes = f"{ne[kw]:.3g} ({kw}){'' if ib.get(kw, True) else ' *'}" if ne else "—"
            g = c["goal"][m]
            miss = [w for w, ok in (("heading", g["heading"]), ("baseline", g["baseline"]), ("ratio", g["ratio"])) if ok is False]
            lines.append(f"| {name} | {m} | {_f(r['heading_deg'])} | {_f(r.get('baseline_m', np.nan) * 1e3)} | "
                         f"{_f(ratio.get('heading_deg'))} | {_f(ratio.get('baseline_m'))} | "
                         f"{_f(worst[0])} ({worst[1]}) | {w2s} | {nes} | {'met' if g['met'] else 'missed: ' + ', '.join(miss)} |")
    for name, c in doc["cases"].items():
        methods = list(c["methods"])
        lines += ["", f"## {name}", "", f"{c['description']}." + (f" Oracle: {c['oracle_limits']}." if c["oracle_limits"] else ""), "",
                  "| Parameter | | " + " | ".join(f"{m.upper()} RMSE" for m in methods) + " | "
                  + " | ".join(f"{m.upper()} / oracle" for m in methods if m != ORACLE) + " |",
                  "|---|---|" + "---|" * (2 * len(methods) - (ORACLE in methods))]
        for group, label, key in ROWS:
            row = [group, label] + [_f(c["methods"][m]["mean"]["rmse"].get(key)) for m in methods]
            row += [_f(c.get("ratio_to_oracle", {}).get(m, {}).get(key)) for m in methods if m != ORACLE]
            lines.append("| " + " | ".join(row) + " |")
        lines += ["", "within 2 sigma / ANEES / epochs whose run-averaged NEES is inside the bounds:", "",
                  "| method | " + " | ".join(M.CONS_KEYS) + " |", "|---|" + "---|" * len(M.CONS_KEYS)]
        for m in methods:
            cons = c["methods"][m].get("consistency", {})
            if not cons.get("n"):
                continue
            ib = cons.get("epochs_in_nees_bounds", {})
            lines.append(f"| {m} | " + " | ".join(f"{cons['within_2sigma'][k]:.2f} / {cons['nees'][k]:.3g} / {_f(ib.get(k))}"
                                                 for k in M.CONS_KEYS) + " |")
    return "\n".join(lines) + "\n"


def main_mismatch(args: argparse.Namespace, scenario: Scenario, methods: list[str], cases: list[str]) -> int:
    """dpos-eval --mismatch: every case over ``args.runs`` seeds; metrics.json and report.md in ``args.out``."""
    methods = list(dict.fromkeys(methods + [ORACLE]))
    seeds = [args.seed + r for r in range(args.runs)]
    text = config_text("aircraft", args.aircraft or scenario_aircraft_ref(args.scenario))  # the nominal file the filter reads
    err0 = args.initial_attitude_error if args.initial_attitude_error is not None else float(
        scenario.transfer_alignment.get("initial_attitude_error_deg", 0.0))
    doc: dict = {"scenario": scenario.name, "runs": len(seeds), "seeds": seeds, "methods": methods,
                 "goal": {"heading_deg": GOAL_HEADING_DEG, "baseline_m": GOAL_BASELINE_M, "ratio_to_oracle": GOAL_RATIO},
                 "cases": {}}
    args.out.mkdir(parents=True, exist_ok=True)
    for name in cases:
        doc["cases"][name] = run_case(MM.CASES[name], scenario, methods, CaseRuns(seeds, text, args.particles, args.duration, err0))
        _write(args.out, doc)  # after every case: a long suite keeps what it has
    print(report_md(doc))
    print(f"wrote {args.out / 'metrics.json'} and {args.out / 'report.md'}")
    return 0


def _write(out: Path, doc: dict) -> None:
    (out / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
    (out / "report.md").write_text(report_md(doc))
