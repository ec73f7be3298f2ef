"""``dpos-eval``: Monte Carlo evaluation in the papers' format.

    dpos-eval --scenario paper_su --methods ups,urtss,oracle --runs 5 --seed 1 --out /tmp/eval

Each run simulates the scenario with seed S + r and processes it through the same reader and
solver as dpos-process (in memory, no bag).  ``oracle_wing`` is the URTSS of a model that knows
the true wing (the simulated deformed lever arm and flexure rotation in its matches, no flexure
states to estimate): how far the transfer alignment is from knowing the wing it does not model.
``oracle`` is the model linearized about the true
state with the true noise statistics (the practical bound; simulations only), ``oracle_filter``
its forward filter alone (the bound of the forward filters ukf, upf, cdkf, cdvf).  Writes
``metrics.json`` (design.md schema, means over runs and antennas) and ``report.md`` ([Gong2018]
Table 1 layout with the paper's columns, and each method's ratio to the oracle).

``--stream``: a run longer than an hour (``auto``, the default; ``on``: every run) is simulated
window by window into a temporary recording beside ``--out`` (dpos-sim ``--window``'s
machinery, deleted after the run) and processed and evaluated as ``dpos-process --stream on``
does (each sub-IMU read from the recording, the rows spilled to files), so a run's memory does not
grow with its duration; a shorter run's simulated session stays in memory and goes through the
same dpos_ros.products.solve.solve and dpos_ros.products.evaluate.evaluate, its sub-IMUs and
truth taken from memory.  A run simulated into a recording takes the recorded main POS and draws
other white-noise samples than the simulation in memory (the same statistics); the oracles need
the simulation in memory (``--stream on`` with one is refused).  metrics.json's
``evaluation.paths`` and a line of report.md say which way each run took.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path

from dpos_core.config import ConfigError, config_text
from dpos_core.evaluation import ta as from_sim
from dpos_core.evaluation.ifa import is_ifa_scenario
from dpos_core.evaluation.mismatch import CASES as MISMATCH_CASES
from dpos_core.evaluation.mismatch import case_names as mismatch_cases
from dpos_core.ifa.pipeline import METHODS as IFA_METHODS
from dpos_core.sim.scenario import Scenario, load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta import metrics as M
from dpos_core.ta.pipeline import METHODS, ORACLE, ORACLE_FILTER, ORACLE_WING, TASettings
from dpos_ros.cli.mismatch import main_mismatch
from dpos_ros.cli.options import MAX_PARTICLES, one_line_errors
from dpos_ros.cli.sar_eval import main_sar
from dpos_ros.devices.sim_streams import chunked_session_streams, session_custom_data, session_streams
from dpos_ros.io.bag import topics_and_duration, write_stream_batches
from dpos_ros.io.session import read_session, session_from_streams
from dpos_ros.products import lsfit_tables
from dpos_ros.products.evaluate import evaluate, series_free
from dpos_ros.products.ifa import main_ifa
from dpos_ros.products.report import combine_runs, metrics_json, report_md
from dpos_ros.products.solve import Oracle, SubImuSource, solve

#: the filter rate of the transfer-alignment runs (TASettings' default, [Gong2018])
TA_FILTER_RATE_HZ = 1.0
#: --stream auto: runs longer than this [s] are simulated into a recording, their rows spilled (dpos-process's threshold)
STREAM_AUTO_S = 3600.0
#: the windows of a streamed run's simulation [s] (dpos-sim --window)
STREAM_SIM_WINDOW_S = 60.0
#: the run paths (metrics.json ``evaluation.paths``)
PATH_MEMORY, PATH_STREAMING = "in memory", "streaming"


def methods_of(text: str | None, *, ifa: bool) -> list[str]:
    """The ``--methods`` list for a transfer-alignment (``ifa=False``) or in-flight alignment
    scenario, checked against the core's METHODS; raises ValueError naming the unknown ones."""
    known = IFA_METHODS if ifa else METHODS + (ORACLE, ORACLE_FILTER, ORACLE_WING)
    if text is None:
        text = ",".join(IFA_METHODS) if ifa else "ups,urtss"
    methods = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in methods if m not in known]
    if bad or not methods:
        kind = "IFA method" if ifa else "transfer-alignment method"
        raise ValueError(f"unknown {kind}(s) {bad}; choose from {known}")
    return methods


def parser() -> argparse.ArgumentParser:
    """The command line of dpos-eval."""
    ap = argparse.ArgumentParser(prog="dpos-eval", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", required=True)
    ap.add_argument("--aircraft")
    ap.add_argument("--methods", help=f"comma list of {METHODS + (ORACLE, ORACLE_FILTER, ORACLE_WING)} (default ups,urtss; "
                    "oracle_filter: the oracle's forward filter, the bound of the forward filters; oracle_wing: the "
                    "URTSS that knows the true wing); IFA scenarios: "
                    f"{IFA_METHODS} (default all)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--duration", type=float)
    ap.add_argument("--initial-attitude-error", type=float, metavar="DEG")
    ap.add_argument("--no-position-matching", dest="position_matching", action="store_false",
                    help="transfer alignment by attitude and velocity matching only, [Gong2018]'s setting (docs/ups.md)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--stream", choices=("auto", "on", "off"), default="auto",
                    help="long runs: on = each run simulated into a temporary recording beside --out window by window and "
                         "processed and evaluated by dpos-process --stream on's path (bounded memory; the wing fit in 5 min "
                         f"windows, other noise samples); auto (default) = on for runs over {STREAM_AUTO_S / 3600:g} h without "
                         "an oracle method")
    ap.add_argument("--mismatch", metavar="CASE[,CASE..]|all",
                    help="the mismatch suite (docs/mismatch.md): simulate each case's truth while the filter keeps the "
                         f"nominal configuration; oracle added to --methods (default ups,urtss). Cases: {', '.join(MISMATCH_CASES)}")
    sar = ap.add_argument_group("SINS/SAR scenarios (paper_sar: dpos_ros.cli.sar_eval, docs/sar.md)")
    sar.add_argument("--particle-sweep", metavar="N,N,..", help="also run the particle filters with these particle counts")
    sar.add_argument("--bandwidth-scale", type=float, default=1.0,
                     help="regularization bandwidth as a multiple of h_opt (default 1; 0.5 for multimodal densities)")
    ifa = ap.add_argument_group("in-flight alignment scenarios (paper_ifa)")
    ifa.add_argument("--initial-heading-error", type=float, metavar="DEG", help="default: the scenario's ifa block")
    ifa.add_argument("--heading-sweep", metavar="DEG,DEG,..", help="also run these initial heading errors, both signs")
    ifa.add_argument("--outage", metavar="T0,DUR", help="also run with a GNSS outage [T0, T0+DUR) s")
    ifa.add_argument("--noise-jump", metavar="T0,SCALE", help="also run with the GNSS noise x SCALE from T0 s on")
    ifa.add_argument("--no-table", action="store_true", help="skip the Table-3 runs (only the experiments asked for)")
    ifa.add_argument("--consistency", action="store_true",
                     help="start from the data as on a real recording; NEES / NIS of the datasheet filter and the oracle")
    return ap


def check_numbers(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The numeric options, before anything runs: ``ap.error`` (exit 2, usage) names the first bad one."""
    if args.runs < 1:
        ap.error(f"--runs must be >= 1, got {args.runs}")
    if args.particles < 1:
        ap.error(f"--particles must be >= 1, got {args.particles}")
    if args.particles > MAX_PARTICLES:
        ap.error(f"--particles must be <= {MAX_PARTICLES} (the filter's arrays grow with it), got {args.particles}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        ap.error(f"--duration must be > 0 seconds, got {args.duration:g}")
    for name in ("initial_attitude_error", "initial_heading_error"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            ap.error(f"--{name.replace('_', '-')} must be a finite number of degrees, got {v:g}")


@one_line_errors("dpos-eval")
def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    check_numbers(ap, args)
    try:
        scenario = load_scenario(args.scenario, aircraft=args.aircraft)
    except ConfigError as e:
        print(f"dpos-eval: {e}", file=sys.stderr)
        return 2
    if scenario.sar is not None:  # SINS/SAR ([Yan2016]): its own methods and report

        return main_sar(ap, args, scenario)
    methods = scenario_methods(ap, args, scenario)
    if args.mismatch is not None:
        if is_ifa_scenario(scenario):
            ap.error("--mismatch is for transfer-alignment scenarios")
        if not args.position_matching:
            ap.error("--no-position-matching is not supported with --mismatch (the suite runs the default matching)")
        try:
            cases = mismatch_cases(args.mismatch)
        except ValueError as e:
            ap.error(str(e))
        if args.duration is not None and args.duration < 1.0 / TA_FILTER_RATE_HZ:
            ap.error(f"--duration must be >= {1.0 / TA_FILTER_RATE_HZ:g} s for transfer alignment, got {args.duration:g}")

        return main_mismatch(args, scenario, methods, cases)
    if is_ifa_scenario(scenario):
        return main_ifa(ap, args, scenario, methods)
    plan = ta_plan(ap, args, scenario, methods)
    runs = [ta_run(plan, args.seed + r, label=f"run {r + 1}/{args.runs}", scratch=args.out) for r in range(args.runs)]
    ta_write(args.out, plan, runs)
    return 0


@dataclass(frozen=True)
class TAPlan:
    """A transfer-alignment Monte Carlo evaluation, checked: what each run needs (picklable, so
    that a run can go to another process: ``dpos-campaign eval``)."""

    scenario: Scenario
    methods: tuple[str, ...]
    particles: int
    duration_s: float | None
    initial_attitude_error_deg: float
    aircraft_text: str | None
    use_position: bool
    stream: bool = False

    def settings(self, method: str, seed: int) -> TASettings:
        """The transfer alignment's settings of one run of ``method`` with ``seed``."""
        return TASettings(method=method, particles=self.particles, seed=seed, filter_rate_hz=TA_FILTER_RATE_HZ,
                          use_position=self.use_position, initial_attitude_error_deg=self.initial_attitude_error_deg)


@dataclass
class TARun:
    """One run of a :class:`TAPlan`: per method the :func:`evaluate` result without its error
    series (per antenna ``rmse``, ``std`` and ``consistency``: what :func:`combine_runs` reads),
    the method's timing (processing and data seconds) and the session's imaging segments."""

    seed: int
    evaluations: dict[str, dict[str, dict]]
    timing: dict[str, dict[str, float]]
    segments: list[str]
    lines: list[str] = field(default_factory=list)
    path: str = PATH_MEMORY



def scenario_methods(ap: argparse.ArgumentParser, args: argparse.Namespace, scenario: Scenario) -> list[str]:
    """``--methods`` checked against the scenario (transfer or in-flight alignment), and
    ``--duration`` against its length: ``ap.error`` (exit 2) names what is wrong."""
    if args.duration is not None and args.duration > scenario.duration_s:
        ap.error(f"--duration {args.duration:g} s exceeds the scenario {scenario.name}'s {scenario.duration_s:g} s")
    try:
        return methods_of(args.methods, ifa=is_ifa_scenario(scenario))
    except ValueError as e:
        ap.error(str(e))


def ta_plan(ap: argparse.ArgumentParser, args: argparse.Namespace, scenario: Scenario, methods: list[str]) -> TAPlan:
    """The runs' settings from dpos-eval's checked arguments for a transfer-alignment scenario
    (``initial_attitude_error`` defaults to the scenario's ``transfer_alignment`` block); a
    ``--duration`` shorter than one filter epoch is ``ap.error`` (exit 2)."""
    if args.duration is not None and args.duration < 1.0 / TA_FILTER_RATE_HZ:
        ap.error(f"--duration must be >= {1.0 / TA_FILTER_RATE_HZ:g} s for transfer alignment "
                 f"(one epoch of the {TA_FILTER_RATE_HZ:g} Hz filter), got {args.duration:g}")
    err0 = args.initial_attitude_error if args.initial_attitude_error is not None else float(scenario.transfer_alignment.get("initial_attitude_error_deg", 0.0))
    oracles = [m for m in methods if m in (ORACLE, ORACLE_FILTER, ORACLE_WING)]
    stream = getattr(args, "stream", "off")
    if stream == "on" and oracles:
        ap.error(f"--stream on: the oracle methods {oracles} need the simulation in memory; use --stream off or auto")
    duration = args.duration if args.duration is not None else scenario.duration_s
    streamed = stream == "on" or (stream == "auto" and duration > STREAM_AUTO_S and not oracles)
    return TAPlan(scenario, tuple(methods), args.particles, args.duration, err0,
                  config_text("aircraft", args.aircraft) if args.aircraft else None, args.position_matching, streamed)


def ta_run(plan: TAPlan, seed: int, label: str = "run", echo: bool = True, scratch: Path | None = None) -> TARun:
    """Simulate the scenario with ``seed`` and run every method of ``plan`` on it; one line per
    method (printed when ``echo``, kept in ``TARun.lines`` either way).  ``plan.stream``: by
    :func:`ta_run_streamed`, its temporary recording under ``scratch`` (default: the system's
    temporary directory)."""
    if plan.stream:
        return ta_run_streamed(plan, seed, label, echo, scratch)
    scenario, methods = plan.scenario, plan.methods
    ss = SimulatedSession(scenario, seed, plan.duration_s)
    custom = session_custom_data(ss, plan.aircraft_text or "")
    sess = session_from_streams(session_streams(ss), custom, f"{scenario.name}_seed{seed}")
    truth = ({s.name: from_sim.oracle_truth(ss, s.name) for s in scenario.aircraft.sub_imus}
             if ORACLE in methods or ORACLE_FILTER in methods else None)
    wing = {s.name: from_sim.known_wing(ss, s.name) for s in scenario.aircraft.sub_imus} if ORACLE_WING in methods else None
    run = TARun(seed, {}, {}, list(sess.imaging_segments().keys()) or ["session"])
    for m in methods:
        t0 = time.perf_counter()
        oracle = Oracle(truth=truth if m in (ORACLE, ORACLE_FILTER) else None, known_wing=wing if m == ORACLE_WING else None)
        ants, tm = solve(sess, scenario.aircraft, plan.settings(m, seed), oracle=oracle)
        ev = evaluate(sess, ants)
        _record(run, m, ev, tm, label, seed, t0, echo)
    return run


def _record(run: TARun, m: str, ev: dict[str, dict], tm: dict[str, float], label: str, seed: int, t0: float, echo: bool) -> None:
    """Method ``m``'s evaluation ``ev`` and timing ``tm`` into ``run`` (without the per-row series), and its line."""
    run.evaluations[m] = series_free(ev)
    run.timing[m] = {"processing_s": tm["processing_s"], "data_s": tm["data_s"]}
    mean = M.average([{"rmse": e["rmse"], "std": e["std"]} for e in ev.values()]) if ev else {"rmse": {}}
    nan = float("nan")
    line = (f"{label} seed {seed} {m:>6}: heading {mean['rmse'].get('heading_deg', nan):.2e} deg, "
            f"vel_n {mean['rmse'].get('vel_n_mps', nan):.2e} m/s, lat {mean['rmse'].get('lat_m', nan):.2e} m "
            f"({time.perf_counter() - t0:.1f} s{', streamed' if run.path == PATH_STREAMING else ''})")
    run.lines.append(line)
    if echo:
        print(line, flush=True)


def ta_run_streamed(plan: TAPlan, seed: int, label: str = "run", echo: bool = True, scratch: Path | None = None) -> TARun:
    """:func:`ta_run` with memory that does not grow with the run's duration (module docstring): the
    session simulated window by window (:data:`STREAM_SIM_WINDOW_S`) into a recording in a new
    temporary directory under ``scratch``, each method run on it by ``dpos-process --stream on``'s
    path (:func:`dpos_ros.products.solve.solve` reading the recording, its rows spilled to files,
    serially in this process) and evaluated by :func:`dpos_ros.products.evaluate.evaluate`; the directory is deleted
    afterwards, whatever happens.  The oracle methods are not available (they read the simulation)."""
    scenario, methods = plan.scenario, plan.methods
    oracles = [m for m in methods if m in (ORACLE, ORACLE_FILTER, ORACLE_WING)]
    if oracles:
        raise ValueError(f"the streamed run cannot run the oracle methods {oracles}")
    ss = SimulatedSession(scenario, seed, plan.duration_s)
    custom = session_custom_data(ss, plan.aircraft_text or "")
    parent = Path(scratch) if scratch is not None else Path(tempfile.gettempdir())
    parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".dpos_eval_seed{seed}_", dir=parent) as tmp:
        rec = Path(tmp) / "recording"
        write_stream_batches(rec, chunked_session_streams(ss, STREAM_SIM_WINDOW_S, truth=True), custom_data=custom)
        del ss
        meta = topics_and_duration(rec)
        assert meta is not None  # (written just now)
        topics = meta[0]
        subs = sorted(t.split("/")[2] for t in topics if t.startswith("/sub_imu/") and t.endswith("/imu") and t.count("/") == 3)
        base = read_session(rec, keep=lambda t: False)  # the main POS only
        run = TARun(seed, {}, {}, list(base.imaging_segments().keys()) or ["session"], path=PATH_STREAMING)
        for m in methods:
            t0 = time.perf_counter()
            sess = dc_replace(base, warnings=list(base.warnings))
            store = Path(tmp) / f"rows_{m}"
            ants, tm = solve(sess, scenario.aircraft, plan.settings(m, seed), source=SubImuSource(bag=str(rec)), store_dir=store,
                             sub_imus=subs)
            ev = evaluate(sess, ants, topics)
            shutil.rmtree(store, ignore_errors=True)
            _record(run, m, ev, tm, label, seed, t0, echo)
    return run


def ta_write(out: Path, plan: TAPlan, runs: list[TARun]) -> dict:
    """Combine ``runs`` (in this order) as dpos-eval does (:func:`combine_runs`: the mean over the
    runs per antenna and method), write ``out/metrics.json`` and ``out/report.md``, print the
    report; returns the metrics."""
    scenario, methods = plan.scenario, plan.methods
    per_method: dict[str, list[dict]] = {m: [run.evaluations[m] for run in runs] for m in methods}
    timing = {m: {"processing_s": 0.0, "data_s": 0.0} for m in methods}
    for run in runs:
        for m in methods:
            timing[m]["processing_s"] += run.timing[m]["processing_s"]
            timing[m]["data_s"] += run.timing[m]["data_s"]
    # mean over runs, per antenna and overall
    combined = combine_runs(per_method, timing)
    metrics = metrics_json(None, combined, runs=len(runs), scenario=scenario.name)
    metrics["segments"] = runs[-1].segments
    metrics["evaluation"] = {"paths": [run.path for run in runs], "seeds": [run.seed for run in runs]}
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    report = report_md(metrics, f"Monte Carlo evaluation: {scenario.name} ({scenario.source})")
    streamed = [run.seed for run in runs if run.path == PATH_STREAMING]
    if streamed:
        report += (f"\nRuns of seed {', '.join(map(str, streamed))} took the streaming path (simulated window by window into a "
                   f"temporary recording, {STREAM_SIM_WINDOW_S:g} s windows, and processed as dpos-process --stream on: the "
                   "recorded main POS, the wing fit over 5-minute windows); "
                   f"{len(runs) - len(streamed)} run(s) in memory.\n")
    for bound, what in ((ORACLE, "the oracle (1.0 = the practical bound)"),
                        (ORACLE_FILTER, "the oracle's forward filter (1.0 = the forward filters' practical bound)"),
                        (ORACLE_WING, "the oracle that knows the true wing (1.0 = the bound with the wing known)")):
        if bound not in methods:
            continue
        o = metrics["methods"][bound]["mean"]["rmse"]
        report += f"\nRatio of RMSE to {what}:\n\n| method | " + " | ".join(M.KEYS) + " |\n|---|" + "---|" * len(M.KEYS) + "\n"
        for m in methods:
            r_ = metrics["methods"][m]["mean"]["rmse"]
            report += f"| {m} | " + " | ".join(f"{r_[k] / o[k]:.2f}" if o.get(k) else "—" for k in M.KEYS) + " |\n"
    if any(lsfit_tables.antenna_number(a.name) is not None for a in scenario.aircraft.antennas):  # an array like [LSFit]'s
        carried = [a.name for a in scenario.aircraft.antennas if a.sub_imu is not None]
        fitted = [a.name for a in scenario.aircraft.antennas if a.sub_imu is None]
        for m in methods:
            rmse = {n: a["rmse"] for n, a in metrics["methods"][m]["antennas"].items()}
            report += "\n" + lsfit_tables.report_md(rmse, carried, fitted, f"{m}, {scenario.name}, {len(runs)} run(s)")
    (out / "report.md").write_text(report)
    print(report)
    print(f"wrote {out / 'metrics.json'} and {out / 'report.md'}")
    return metrics


if __name__ == "__main__":
    raise SystemExit(main())
