"""``dpos-demo`` (``make demo``): the product on the built-in simulated flight, as a live graph.

Starts, without launch, pos_master_node (main POS mechanized from a heading error, aligned in
flight: ``--alignment ifa``, default; or the simulated reference navigation), ifa_node (ADD2
against the GNSS, which paper_su's receiver reports with its differential-GNSS sigmas), two
pos_sub_node (the wing sub-IMUs sub_r and sub_l) and transfer_align_node on their own
ROS_DOMAIN_ID; the devices publish paper_su (shortened) as fast as the graph keeps up; when
pos_master_node publishes /session/end, transfer_align_node aligns both sub-IMUs in worker
processes from the epoch the main POS is aligned, publishes /antenna/<name>/odom and writes the
session products.  Prints where they are and the accuracy table against the simulation's truth.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from dpos_core.ta.pipeline import METHODS
from dpos_ros.cli.options import one_line_errors
from dpos_ros.contract import topics as T
from dpos_ros.io.outdir import is_products_dir
from dpos_ros.runtime.graph import Graph, GraphError, GraphSpec, NodeSpec


def parser() -> argparse.ArgumentParser:
    """The command line of dpos-demo (its ``--method`` choices are the core's METHODS)."""
    ap = argparse.ArgumentParser(prog="dpos-demo", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=500.0, help="seconds of paper_su to fly (default 500: includes the S-turn and 100 s of segment AB)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--method", default="ups", choices=METHODS, help="transfer-alignment method (default ups)")
    ap.add_argument("--alignment", choices=("ifa", "reference"), default="ifa",
                    help="main POS: ifa (mechanized, aligned in flight by ifa_node against GNSS; default) or reference "
                         "(the simulated reference navigation, truth + the paper's noise)")
    ap.add_argument("--initial-heading-error", type=float, default=30.0, metavar="DEG",
                    help="with --alignment ifa: the main POS starts with this heading error (default 30)")
    ap.add_argument("--out", type=Path, default=Path("out/demo"))
    ap.add_argument("--timeout", type=float, default=400.0, help="give up when no products came after this long [s] (wall clock)")
    ap.add_argument("--verbose", action="store_true", help="stream every node's log")
    return ap


@one_line_errors("dpos-demo")
def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    t_start = time.monotonic()
    domain = int(os.environ.get("DPOS_DEMO_DOMAIN_ID", 100 + os.getpid() % 100))
    sim = {"scenario": "paper_su", "aircraft_config": "paper_su_pair", "seed": args.seed, "duration": args.duration,
           "rate_factor": 0.0, "min_subscribers": 1, "wait_subscribers_s": 10.0}
    out = args.out.resolve()
    spec = GraphSpec(nodes=[
        NodeSpec("transfer_align_node", "transfer_align_node",
                 {"method": args.method, "aircraft_config": "paper_su_pair", "output_dir": str(out), "initial_attitude_error_deg": 1.0},
                 ready_subscribes=(T.MASTER_NAV, "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu")),
        NodeSpec("ifa_node", "ifa_node", {"method": "add2", "aircraft_config": "paper_su_pair", "use_reported_sigma": True}),
        NodeSpec("pos_master_node", "pos_master_node", {**sim, "alignment": args.alignment,
                                                        **({"initial_heading_error_deg": [args.initial_heading_error]} if args.alignment == "ifa" else {})}),
        NodeSpec("sub_r", "pos_sub_node", {**sim, "name": "sub_r"}),
        NodeSpec("sub_l", "pos_sub_node", {**sim, "name": "sub_l"}),
    ], ros_domain_id=domain, ready_timeout_s=60.0, stop_timeout_s=15.0)

    def log(name: str, line: str) -> None:
        if args.verbose or name == "transfer_align_node" and any(k in line for k in ("session", "antenna", "processed", "WARN", "ERROR")):
            print(f"[{name}] {line}", flush=True)

    sid = f"paper_su_seed{args.seed}"
    status = out / sid / "status.json"
    if (out / sid).exists() or (out / sid).is_symlink():  # the node writes a session's products only into a new directory
        if not is_products_dir(out / sid):  # only what dpos wrote is ever removed
            print(f"dpos-demo: error: {out / sid} exists and is not a dpos products directory: not removing it", file=sys.stderr)
            return 2
        print(f"dpos-demo: removing the previous demo products {out / sid}", flush=True)
        shutil.rmtree(out / sid)
    print(f"dpos-demo: paper_su ({args.duration:.0f} s, both wings) through the live graph on ROS_DOMAIN_ID {domain}", flush=True)
    try:
        with Graph(spec, log) as g:
            print("dpos-demo: graph ready: " + ", ".join(n.name for n in spec.nodes), flush=True)
            end = time.monotonic() + args.timeout
            while not status.is_file() and time.monotonic() < end:
                if any(p.popen.poll() is not None for p in g.procs.values()):
                    dead = [n for n, p in g.procs.items() if p.popen.poll() is not None]
                    raise GraphError(f"node(s) {dead} exited early: {g.logs(dead[0])[-10:]}")
                time.sleep(0.5)
            if not status.is_file():
                raise GraphError(f"no session products after {args.timeout:.0f} s; transfer_align_node log: {g.logs('transfer_align_node')[-10:]}")
    except GraphError as e:
        print(f"dpos-demo: {e}", file=sys.stderr)
        return 1
    prod = out / sid
    print(f"\ndpos-demo: session products in {prod}/ ({time.monotonic() - t_start:.0f} s)")
    for f in sorted(prod.iterdir()):
        print(f"  {f.name}")
    rep = prod / "report.md"
    if rep.is_file():
        print("\n" + rep.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
