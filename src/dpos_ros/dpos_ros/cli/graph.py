"""``dpos-graph``: start a node graph from a YAML file without launch, stream its logs, stop it
cleanly on Ctrl-C (or when a node exits / after a duration).

    dpos-graph graph.yaml
    dpos-graph graph.yaml --domain-id 42 --until-exit master --timeout 600
    dpos-graph --example sim_paper_su      # print a packaged example graph file
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from importlib import resources
from pathlib import Path

from dpos_ros.cli.options import float_in, int_in, one_line_errors
from dpos_ros.runtime.graph import Graph, GraphError, GraphSpec
from dpos_ros.runtime.node_main import install_stop_handlers


@one_line_errors("dpos-graph")
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dpos-graph", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("graph", nargs="?", type=Path, help="graph YAML file")
    ap.add_argument("--domain-id", type=int_in(0, 232), help="ROS_DOMAIN_ID for every node (overrides the file)")
    ap.add_argument("--until-exit", metavar="NODE", help="stop the graph when this node exits")
    ap.add_argument("--timeout", type=float_in(0.0, lo_open=True, unit=" s"), help="stop the graph after this many seconds")
    ap.add_argument("--example", metavar="NAME", help="print a packaged example graph and exit")
    args = ap.parse_args(argv)
    if args.example:
        if not args.example.replace("_", "").isalnum():
            ap.error(f"--example {args.example!r}: an example's name (letters, digits, '_')")
        res = resources.files("dpos_ros").joinpath("graphs", f"{args.example}.yaml")
        if not res.is_file():
            known = sorted(f.name[:-5] for f in resources.files("dpos_ros").joinpath("graphs").iterdir() if f.name.endswith(".yaml"))
            print(f"dpos-graph: no example {args.example!r}; examples: {known}", file=sys.stderr)
            return 2
        print(res.read_text(), end="")
        return 0
    if args.graph is None:
        ap.error("a graph file is required")
    try:
        spec = GraphSpec.from_yaml(args.graph)
    except GraphError as e:
        print(f"dpos-graph: {e}", file=sys.stderr)
        return 2
    if args.domain_id is not None:
        spec.ros_domain_id = args.domain_id
    if args.until_exit and args.until_exit not in {n.name for n in spec.nodes}:
        print(f"dpos-graph: --until-exit {args.until_exit!r} is not a node of the graph", file=sys.stderr)
        return 2
    stop = threading.Event()
    install_stop_handlers(stop.set)
    g = Graph(spec)
    try:
        g.start()
        g.wait_ready()
    except GraphError as e:
        print(f"dpos-graph: {e}", file=sys.stderr)
        g.stop()
        return 1
    print(f"dpos-graph: {len(spec.nodes)} node(s) ready: {', '.join(n.name for n in spec.nodes)}", flush=True)
    end = None if args.timeout is None else time.monotonic() + args.timeout
    while not stop.is_set():
        if end is not None and time.monotonic() > end:
            break
        if args.until_exit and g.procs[args.until_exit].popen.poll() is not None:
            break
        if all(p.popen.poll() is not None for p in g.procs.values()):
            break
        stop.wait(0.2)
    codes = g.stop()
    print("dpos-graph: stopped; exit codes " + ", ".join(f"{k}={v}" for k, v in codes.items()), flush=True)
    return 0 if all(c == 0 for c in codes.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
