"""``dpos-process``: transfer alignment of a recorded session, offline, through the same code as
transfer_align_node; writes the session products (design.md) and metrics when truth is recorded.

    dpos-process /tmp/paper_su_s1 --out /tmp/products                 # UPS (the default)
    dpos-process /tmp/paper_su_s1 --method ups --particles 100 --out /tmp/products
    dpos-process BAG --method ups --aircraft my_aircraft.yaml --out DIR
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.ta.pipeline import METHODS
from dpos_ros.io.session import SessionError, read_session
from dpos_ros.products.ta import evaluate, solve, write


def parser() -> argparse.ArgumentParser:
    """The command line of dpos-process (its ``--method`` choices are the core's METHODS)."""
    ap = argparse.ArgumentParser(prog="dpos-process", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="rosbag2 directory of the session")
    ap.add_argument("--method", choices=METHODS, default="ups",
                    help="default ups ([Gong2018]'s unscented particle smoother); urtss is the Gaussian smoother")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0, help="random seed of the particle methods")
    ap.add_argument("--filter-rate", type=float, default=1.0, metavar="HZ", help="filter update rate (default 1 Hz, [Gong2018])")
    ap.add_argument("--output-rate", type=float, default=0.0, metavar="HZ", help="rate of the antenna poses (default 0 = the sub-IMU rate)")
    ap.add_argument("--aircraft", help="aircraft configuration (default: the one embedded in the recording)")
    ap.add_argument("--initial-attitude-error", type=float, metavar="DEG",
                    help="initial sub-IMU attitude error per axis (default: the recording's transfer_alignment setting, else 0)")
    ap.add_argument("--out", type=Path, required=True, help="output directory (products go to OUT/<session id>/)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if args.particles < 1:
        ap.error("--particles must be >= 1")
    try:
        sess = read_session(args.bag)
        if args.aircraft:
            aircraft = load_aircraft(args.aircraft)
        elif "dpos.aircraft_yaml" in sess.custom:
            aircraft = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
        else:
            raise SessionError(f"{args.bag} carries no aircraft configuration: pass --aircraft")
    except (SessionError, ConfigError) as e:
        print(f"dpos-process: {e}", file=sys.stderr)
        return 2
    ta = json.loads(sess.custom.get("dpos.transfer_alignment", "{}") or "{}")
    err0 = args.initial_attitude_error if args.initial_attitude_error is not None else float(ta.get("initial_attitude_error_deg", 0.0))
    for w in sess.warnings:
        print(f"dpos-process: warning: {w}", file=sys.stderr)
    print(f"dpos-process: session {sess.session_id}: {len(sess.sub_imus)} sub-IMU(s), {sess.master.t_s[-1] - sess.master.t_s[0]:.0f} s, "
          f"method {args.method}, initial attitude error {err0:g} deg")
    if not args.filter_rate > 0 or args.output_rate < 0:
        ap.error("--filter-rate must be > 0 and --output-rate >= 0")
    antennas, timing = solve(sess, aircraft, args.method, args.particles, args.seed, err0,
                             filter_rate_hz=args.filter_rate, output_rate_hz=args.output_rate)
    ev = evaluate(sess, antennas)
    out = write(args.out, sess, antennas, args.method, timing, ev or None)
    for name, a in antennas.items():
        print(f"  {name}: {a.status}")
    print(f"processing {timing['processing_s']:.1f} s for {timing['data_s']:.0f} s of sub-IMU data "
          f"(ratio {timing['processing_s'] / max(timing['data_s'], 1e-9):.4f})")
    print(f"products in {out}")
    if ev:
        print((out / "report.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
