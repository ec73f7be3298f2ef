"""The UPS with and without resample-move (``run_upf(move=True)``, docs/sar.md "Resample-move in the UPS").

    .venv/bin/python tools/ups_resample_move.py --runs 2 --seed 1 --out out/ups_move

Runs ``dpos-eval --scenario paper_su --methods ups`` twice on the same seeds: as shipped, and with
the transfer alignment's UPF calling ``run_upf(..., move=True)``; writes both evaluations under
``--out`` (``without/``, ``with/``) and prints each antenna's RMSE side by side.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="ups_resample_move", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--scenario", default="paper_su")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    from dpos_core.filters import runners
    from dpos_core.ta import pipeline
    from dpos_ros.cli.evaluate import main as dpos_eval

    base = ["--scenario", args.scenario, "--methods", "ups", "--runs", str(args.runs), "--seed", str(args.seed),
            "--particles", str(args.particles)]
    shipped = pipeline.run_upf
    rc = dpos_eval(base + ["--out", str(args.out / "without")])
    pipeline.run_upf = functools.partial(runners.run_upf, move=True)
    try:
        rc |= dpos_eval(base + ["--out", str(args.out / "with")])
    finally:
        pipeline.run_upf = shipped
    res = {k: json.loads((args.out / k / "metrics.json").read_text()) for k in ("without", "with")}
    print(json.dumps({k: v.get("antennas", v) for k, v in res.items()}, indent=1)[:4000])
    return rc


if __name__ == "__main__":
    sys.exit(main())
