"""One streaming worker task's peak memory and wall time (memory flat with the flight).

Runs :func:`dpos_ros.products.solve.align_to_store` for one sub-IMU of a recording, as
``dpos-process --stream on`` gives it to a worker (the rows spilled to files) (the worker reads its topic and the main POS
itself), in a fresh spawned process warmed up as the pool's workers are
(:func:`dpos_core.ta.warmup.warm_up`), and prints its peak RSS (``getrusage(RUSAGE_SELF).ru_maxrss``), its wall and CPU time
with the largest RSS seen in each stage (``/proc/self/status`` every 20 ms; a stage is the
innermost of the functions wrapped below that is running)::

    .venv/bin/python bench/worker_memory.py BAG [--sub imu01] [--method ups] [--particles 100] [--json OUT]

Memory figures belong here and in bench/run_bench.py, not in the unit tests.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import resource
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

#: (module, function, stage) wrapped in the worker; a missing one is skipped (the names of several versions)
STAGES = (
    ("dpos_ros.products.solve", "read_session", "read"),
    ("dpos_core.ta.pipeline", "run_segments", "align (rest)"),
    ("dpos_core.ta.pipeline", "TransferAlignmentModel", "model setup"),
    ("dpos_core.ta.pipeline", "run_upf", "forward filter"),
    ("dpos_core.ta.pipeline", "run_sigma_point_filter", "forward filter"),
    ("dpos_core.ta.pipeline", "rb_smooth", "backward pass"),
    ("dpos_core.ta.pipeline", "smooth_gaussian", "backward pass"),
    ("dpos_core.ta.pipeline", "epoch_qc", "epoch qc"),
    ("dpos_core.ta.pipeline", "_to_sink", "output rows"),
)


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _task(task, method: str) -> dict:
    """In the spawned worker: warm up, wrap the stages, run the task; the figures."""
    import importlib

    from dpos_core.ta.warmup import warm_up
    from dpos_ros.products import rows, solve

    warm_up(method)
    rows.release_memory()
    stack = ["task (rest)"]
    peaks: dict[str, float] = {}
    times: dict[str, float] = {}
    ends: dict[str, float] = {}
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.02):
            s = stack[-1]
            peaks[s] = max(peaks.get(s, 0.0), _rss_mb())

    def wrap(fn, stage: str):
        def inner(*a, **k):
            stack.append(stage)
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                times[stage] = times.get(stage, 0.0) + time.perf_counter() - t0
                ends[stage] = _rss_mb()
                peaks[stage] = max(peaks.get(stage, 0.0), ends[stage])
                stack.pop()
        return inner

    for mod, name, stage in STAGES:
        m = importlib.import_module(mod)
        if hasattr(m, name):
            setattr(m, name, wrap(getattr(m, name), stage))
    start_mb = _rss_mb()
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    t0 = time.perf_counter()
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    r = solve.align_to_store(task)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    done.set()
    th.join()
    ok = "stores" in r
    if ok:
        n_rows = r["own"].n
        for s in (*r["stores"].values(), r["own"]):
            s.remove()
    return {"status": "ok" if ok else str(r), "wall_s": wall, "cpu_s": cpu, "start_rss_mb": start_mb, "after_rss_mb": _rss_mb(),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "stage_peak_rss_mb": {k: round(v, 1) for k, v in peaks.items()}, "stage_end_rss_mb": {k: round(v, 1) for k, v in ends.items()},
            "stage_s": {k: round(v, 2) for k, v in times.items()},
            "rows": n_rows if ok else 0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag", type=Path)
    ap.add_argument("--sub", default="imu01")
    ap.add_argument("--method", default="ups")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)

    import numpy as np

    from dpos_core.config import load_aircraft
    from dpos_core.ta.model import Installation
    from dpos_core.ta.pipeline import TASettings
    from dpos_ros.io.session import read_session
    from dpos_ros.products.master_reference import AUTO_TAU, master_error_tau
    from dpos_ros.products.rows import RowStore
    from dpos_ros.products.solve import SubImuSource, SubImuTask

    sess = read_session(a.bag, keep=lambda t: False)  # the main POS only (in this process, as dpos-process)
    aircraft = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
    tau, _ = master_error_tau(AUTO_TAU, sess.master_mechanized, "recorded")
    ta = json.loads(sess.custom.get("dpos.transfer_alignment", "{}") or "{}")
    e = float(ta.get("initial_attitude_error_deg", 0.0))
    settings = TASettings(method=a.method, particles=a.particles, master_error_tau_s=tau, initial_attitude_error_deg=e)
    duration = float(sess.master.t_s[-1] - sess.master.t_s[0])
    del sess
    with tempfile.TemporaryDirectory(prefix="dpos_wmem_") as tmp:
        task = SubImuTask(SubImuSource(bag=str(a.bag)), a.sub, None, Installation.from_aircraft(aircraft, a.sub), settings,
                          tuple((x.name, np.asarray(x.lever_arm_m, dtype=float)) for x in aircraft.antennas if x.sub_imu == a.sub),
                          RowStore(Path(tmp)))
        with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
            out = pool.submit(_task, task, a.method).result()
    out.update(bag=str(a.bag), sub=a.sub, method=a.method, particles=a.particles, flight_s=round(duration, 1), master_error_tau_s=tau)
    print(json.dumps(out, indent=1))
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
