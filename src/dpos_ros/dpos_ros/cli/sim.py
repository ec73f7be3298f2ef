"""``dpos-sim``: write a simulated session as a rosbag2 (MCAP) with every topic of design.md.

    dpos-sim --scenario paper_su --seed 1 --out /tmp/paper_su_s1
    dpos-sim --scenario paper_su --aircraft paper_su_pair --duration 50 --out bags/paper_su_pair_50s
    dpos-sim --scenario my_flight.yaml --aircraft my_aircraft.yaml --out /data/sim1
    dpos-sim --scenario paper_wing --duration 14400 --window 60 --no-truth --out /data/long   # a 4 h flight, window by window

``--window S``: simulate and write the session in windows of S seconds, memory holding one window
(for long flights; docs/campaign.md "Long flights").  Its noise samples are drawn by streaming
recursions (dpos_core.sim.chunked): the same seed gives the same bag whatever S, but not the
samples of the whole-session simulation (nor of the ``device: sim`` nodes).

The same scenario and seed give the same samples as the ``device: sim`` nodes publish live.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from dpos_core.config import ConfigError, config_text
from dpos_core.sim.scenario import builtin_scenarios, load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli.options import one_line_errors
from dpos_ros.cli.progress import Progress
from dpos_ros.devices.sim_streams import chunked_session_streams, session_custom_data, session_id, session_streams
from dpos_ros.io.bag import write_stream_batches, write_streams
from dpos_ros.io.outdir import OutputError, OutputTarget
from dpos_ros.runtime.params import datum_problem


@one_line_errors("dpos-sim")
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dpos-sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", required=True, help=f"built-in {builtin_scenarios()} or a scenario YAML file")
    ap.add_argument("--aircraft", help="aircraft configuration (built-in name or YAML) instead of the scenario's")
    ap.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    ap.add_argument("--duration", type=float, help="cut the flight to this many seconds")
    ap.add_argument("--out", type=Path, required=True, help="new rosbag2 directory to write")
    ap.add_argument("--window", type=float, metavar="S",
                    help="simulate and write in windows of S seconds (bounded memory; other noise samples than without)")
    ap.add_argument("--no-truth", action="store_true", help="leave out the /truth/* topics")
    ap.add_argument("--datum", type=float, nargs=3, metavar=("LAT_DEG", "LON_DEG", "H_M"),
                    help="origin of the enu frame (default: the scenario's start point)")
    args = ap.parse_args(argv)
    if args.seed < 0:
        ap.error("--seed must be >= 0")
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        ap.error("--duration must be > 0 (and finite)")
    if args.window is not None and not (args.window > 0 and math.isfinite(args.window)):
        ap.error("--window must be > 0 (and finite)")
    if args.datum is not None and (problem := datum_problem(*args.datum)) is not None:
        ap.error(f"--datum: {problem}")
    if args.out.exists():
        ap.error(f"--out {args.out} exists; rosbag2 writes a new directory")
    try:
        target = OutputTarget(args.out)
    except OutputError as e:
        print(f"dpos-sim: error: --out {e}", file=sys.stderr)
        return 2
    try:
        scenario = load_scenario(args.scenario, aircraft=args.aircraft)
        session = SimulatedSession(scenario, args.seed, args.duration)
    except (ConfigError, ValueError) as e:
        print(f"dpos-sim: {e}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    print(f"dpos-sim: {scenario.name} ({scenario.source}), aircraft {scenario.aircraft.name}, seed {args.seed}, "
          f"{session.duration_s:.0f} s -> {args.out}")
    datum = None if args.datum is None else np.array([np.deg2rad(args.datum[0]), np.deg2rad(args.datum[1]), args.datum[2]])
    if args.window is not None:
        return _windowed(args, session, datum, target, t0)
    streams = session_streams(session, truth=not args.no_truth, datum_llh=datum)
    t_gen = time.perf_counter() - t0
    ac_text = config_text("aircraft", args.aircraft if args.aircraft else _scenario_aircraft(args.scenario))
    try:
        n = write_streams(args.out, streams, progress=Progress("writing"), custom_data=session_custom_data(session, ac_text))
    except OSError as e:  # ENOSPC, EACCES, EROFS, EIO: no bag without its metadata is left behind
        if sys.stderr.isatty():
            print(file=sys.stderr)  # end the progress bar's line
        print(f"dpos-sim: error: {target.fault(e)}", file=sys.stderr)
        return 2
    elapsed = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in args.out.iterdir())
    print(f"session {session_id(session)}: {n} messages on {len(streams)} topics, {size / 1e6:.1f} MB")
    for s in streams:
        print(f"  {s.topic:<28} {s.msgtype:<46} {len(s):>8}")
    print(f"simulated in {t_gen:.1f} s, total {elapsed:.1f} s "
          f"(processing time / data duration = {elapsed / session.duration_s:.4f})")
    return 0


def _windowed(args: argparse.Namespace, session: SimulatedSession, datum, target: OutputTarget, t0: float) -> int:
    """``--window``: the session simulated and written window by window."""
    ac_text = config_text("aircraft", args.aircraft if args.aircraft else _scenario_aircraft(args.scenario))
    bar = Progress("simulating and writing")
    t_start_ns = int(round(session.scenario.start_time_s * 1e9))
    batches = chunked_session_streams(session, args.window, truth=not args.no_truth, datum_llh=datum)
    try:
        n, counts = write_stream_batches(args.out, batches, progress=lambda t_ns: bar(t_ns - t_start_ns, int(session.duration_s * 1e9)),
                                         custom_data=session_custom_data(session, ac_text))
    except OSError as e:  # ENOSPC, EACCES, EROFS, EIO
        if sys.stderr.isatty():
            print(file=sys.stderr)
        print(f"dpos-sim: error: {target.fault(e)}", file=sys.stderr)
        return 2
    elapsed = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in args.out.iterdir())
    print(f"session {session_id(session)}: {n} messages on {len(counts)} topics, {size / 1e6:.1f} MB (windows of {args.window:g} s)")
    for topic, msgtype, c in counts:
        print(f"  {topic:<28} {msgtype:<46} {c:>8}")
    print(f"total {elapsed:.1f} s (processing time / data duration = {elapsed / session.duration_s:.4f})")
    return 0


def _scenario_aircraft(scenario: str) -> str:
    d = yaml.safe_load(config_text("scenarios", scenario))
    ref = str(d.get("aircraft", d.get("name")))
    p = Path(scenario)
    # a user's scenario file may name its aircraft file relative to itself
    if p.suffix in (".yaml", ".yml") and (p.parent / ref).is_file():
        return str(p.parent / ref)
    return ref


if __name__ == "__main__":
    raise SystemExit(main())
