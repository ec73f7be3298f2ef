"""The engine-independent part of ``dpos-campaign``: the task lists, what one task does in a
worker, its result record, the result lines and the campaign summary.

Nothing here imports Dask: :mod:`dpos_ros.cli.campaign` submits these functions to a cluster,
and a test (or a plain loop) can call them directly.

A *process* task runs exactly what ``dpos-process`` does on one recording, through the one
narrow function :func:`run_dpos_process`; an *eval* task runs one batch of ``dpos-eval``'s Monte
Carlo runs (:func:`dpos_ros.cli.evaluate.ta_run`), combined afterwards by
:func:`dpos_ros.cli.evaluate.ta_write` as dpos-eval combines them.

Records are plain JSON-able dicts:

    {"name": "rec03", "recording": "/data/rec03", "status": "ok" | "partial" | "failed",
     "exit_status": 0 | 1 | 2 | null, "time_s": 14.2, "attempt": 1, "worker": "host:pid",
     "products": "OUT/rec03/paper_su_seed3", "figures": {...}, "error": "..."}

``ok``: dpos-process exit status 0 (every antenna estimated); ``partial``: exit status 1 (the
products are written, some antenna is not estimated: ``figures.not_estimated`` names them);
``failed``: exit status 2 (unusable recording or output: ``error`` is dpos-process's message)
or an exception, after the retries.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import dpos_core  # (this function itself comes from dpos_ros: a worker without the packages fails to run it)
from dpos_core.errors import CampaignError, TaskFailed
from dpos_core.ta import metrics as M
from dpos_ros.cli import process as process_cli
from dpos_ros.cli.evaluate import TAPlan, TARun, ta_run

#: the per-recording file a process task writes at the end of each attempt (its result record)
TASK_FILE = "task.json"
#: dpos-process's log (its stdout and stderr) in OUT/<recording name>/
LOG_FILE = "process.log"
#: the campaign summary in OUT/
SUMMARY_FILE = "campaign.json"


@dataclass(frozen=True)
class ProcessTask:
    """One recording of a ``dpos-campaign process`` run: dpos-process ``options`` (without
    ``--out`` / ``--workers``) on ``recording``, its output in ``out`` (= OUT/``name``)."""

    name: str
    recording: Path
    out: Path
    options: tuple[str, ...]
    campaign_id: str


@dataclass(frozen=True)
class EvalTask:
    """A batch of Monte Carlo runs (their ``seeds``) of one ``dpos-campaign eval`` run;
    ``first_run`` is the 0-based index of the first of them (for the run labels)."""

    plan: TAPlan
    seeds: tuple[int, ...]
    first_run: int
    total_runs: int


def recording_name(recording: Path) -> str:
    """The name of a recording in the campaign: its directory's (or file's) name."""
    return Path(recording).resolve().name


def process_tasks(recordings: Sequence[Path], out: Path, options: Sequence[str], campaign_id: str) -> list[ProcessTask]:
    """One task per recording, in the order given.  Raises :class:`CampaignError` for a
    recording that does not exist, one given twice, or two with the same name (their products
    would go to the same OUT/<name>/)."""
    if not recordings:
        raise CampaignError("no recording given")
    missing = [str(r) for r in recordings if not Path(r).exists()]
    if missing:
        raise CampaignError(f"recording(s) not found: {', '.join(missing)}")
    by_name: dict[str, list[str]] = {}
    for r in recordings:
        by_name.setdefault(recording_name(r), []).append(str(r))
    clash = {n: rs for n, rs in by_name.items() if len(rs) > 1}
    if clash:
        raise CampaignError("recordings with the same name (their products would share OUT/<name>/): "
                            + "; ".join(f"{n}: {', '.join(rs)}" for n, rs in clash.items()))
    return [ProcessTask(recording_name(r), Path(r).resolve(), (Path(out) / recording_name(r)).resolve(), tuple(options), campaign_id)
            for r in recordings]


def eval_tasks(plan: TAPlan, runs: int, seed: int, runs_per_task: int) -> list[EvalTask]:
    """dpos-eval's runs (seeds ``seed`` .. ``seed + runs - 1``) in batches of ``runs_per_task``."""
    if runs < 1 or runs_per_task < 1:
        raise CampaignError(f"runs and runs per task must be >= 1, got {runs} and {runs_per_task}")
    return [EvalTask(plan, tuple(range(seed + i, seed + min(i + runs_per_task, runs))), i, runs)
            for i in range(0, runs, runs_per_task)]


def worker_id() -> str:
    """``host:pid`` of the process running a task."""
    return f"{socket.gethostname()}:{os.getpid()}"


def run_dpos_process(recording: Path, out: Path, options: Sequence[str], log: TextIO) -> int:
    """dpos-process on ``recording`` with products in ``out/<session id>/``: the one place the
    campaign calls it.  Its ``--workers`` is 1 (the campaign's parallelism is one task per core;
    a Dask worker is a daemon process, which may not start processes); its output goes to
    ``log``.  Returns its exit status (0, 1 or 2)."""
    argv = [str(recording), *options, "--out", str(out), "--workers", "1"]
    with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        try:
            return process_cli.main(argv)
        except SystemExit as e:  # argparse (the options are checked before the campaign starts)
            return e.code if isinstance(e.code, int) else 2


def _last_error(log_text: str) -> str:
    """dpos-process's error line from its log (the last ``error:`` line), else its last line."""
    lines = [ln.strip() for ln in log_text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "error:" in ln]
    return (errors or lines or ["dpos-process failed without a message"])[-1]


def _attempt(task_file: Path, campaign_id: str) -> int:
    """The number of this attempt: 1 + the earlier attempts of the same campaign recorded in
    ``task_file`` (a retry may run on another worker; OUT is shared)."""
    try:
        prev = json.loads(task_file.read_text())
    except (OSError, ValueError):
        return 1
    return int(prev.get("attempt", 0)) + 1 if prev.get("campaign_id") == campaign_id else 1


def _products_dir(out: Path) -> Path | None:
    """dpos-process's ``out/<session id>/``: the directory in ``out`` with the newest status.json
    (an earlier campaign may have left another session's products there)."""
    found = [d for d in out.iterdir() if (d / "status.json").is_file()]
    return max(found, key=lambda d: (d / "status.json").stat().st_mtime_ns) if found else None


def figures(products: Path) -> dict:
    """The key figures of one recording's products: from ``status.json`` the antennas and their
    quality-control verdicts, the warnings and the timing; from ``metrics.json`` (recordings with
    truth) the mean RMSE over the antennas."""
    status = json.loads((products / "status.json").read_text())
    ants: dict[str, str] = status.get("antennas", {})
    qc = status.get("qc", {}).get("antennas", {})
    fig: dict = {
        "session_id": status.get("session_id"),
        "method": status.get("method"),
        "antennas": len(ants),
        "estimated": sum(1 for s in ants.values() if s.startswith("estimated")),
        "not_estimated": {n: s for n, s in ants.items() if not s.startswith("estimated")},
        "qc_verdicts": {n: q.get("verdict") for n, q in qc.items()},
        "warnings": len(status.get("warnings", [])),
        "processing_s": status.get("timing", {}).get("processing_s"),
        "data_s": status.get("timing", {}).get("data_s"),
    }
    metrics = products / "metrics.json"
    if metrics.is_file():
        m = json.loads(metrics.read_text())
        fig["rmse"] = m["methods"][status.get("method")]["mean"]["rmse"]
    return fig


def _write_record(task: ProcessTask, record: dict) -> None:
    tmp = task.out / (TASK_FILE + ".tmp")
    tmp.write_text(json.dumps(record, indent=2) + "\n")
    tmp.replace(task.out / TASK_FILE)


def run_process_task(task: ProcessTask) -> dict:
    """One recording, in a worker: dpos-process into ``task.out`` (its log in
    ``task.out/process.log``), the result record also written to ``task.out/task.json``.
    Returns the record of an ``ok`` or ``partial`` recording; raises :class:`TaskFailed`
    (dpos-process's error line) when dpos-process exits 2, so that the engine retries it."""
    t0 = time.perf_counter()
    task.out.mkdir(parents=True, exist_ok=True)
    attempt = _attempt(task.out / TASK_FILE, task.campaign_id)
    record: dict = {"name": task.name, "recording": str(task.recording), "campaign_id": task.campaign_id,
                    "attempt": attempt, "worker": worker_id()}
    error = ""
    with (task.out / LOG_FILE).open("w") as log:
        try:
            code = run_dpos_process(task.recording, task.out, task.options, log)
        except Exception as e:  # noqa: BLE001 - a bug or fault in dpos-process: the record names it, the engine retries
            log.write(f"dpos-campaign: dpos-process raised {type(e).__name__}: {e}\n")
            code = None
            error = f"dpos-process raised {type(e).__name__}: {e}"
    text = (task.out / LOG_FILE).read_text()
    record["time_s"] = time.perf_counter() - t0
    record["exit_status"] = code
    if code in (0, 1):
        products = _products_dir(task.out)
        record["status"] = "ok" if code == 0 else "partial"
        record["products"] = str(products) if products else None
        if products is not None:
            record["figures"] = figures(products)
        if code == 1:
            record["error"] = _last_error(text)
        _write_record(task, record)
        return record
    if code is not None:
        error = _last_error(text)
    record.update(status="failed", error=error)
    _write_record(task, record)
    raise TaskFailed(error, attempt)


def run_eval_task(task: EvalTask) -> dict:
    """One batch of Monte Carlo runs, in a worker: ``{"runs": [TARun, ..] (their lines in
    TARun.lines), "time_s": wall seconds, "worker": host:pid}``."""
    t0 = time.perf_counter()
    runs: list[TARun] = [ta_run(task.plan, seed, label=f"run {task.first_run + i + 1}/{task.total_runs}", echo=False)
                         for i, seed in enumerate(task.seeds)]
    return {"runs": runs, "time_s": time.perf_counter() - t0, "worker": worker_id()}


def mean_rmse(evaluation: dict[str, dict]) -> dict[str, float]:
    """The RMSE of one run and method averaged over its antennas (as dpos-eval's run lines)."""
    return M.average([{"rmse": e["rmse"], "std": e["std"]} for e in evaluation.values()])["rmse"]


def failed_record(task: ProcessTask, error: BaseException, retries: int) -> dict:
    """The record of a task that failed every attempt (``error``: what the engine reported:
    a :class:`TaskFailed`, another exception, or a worker that died)."""
    if isinstance(error, TaskFailed):
        msg, attempt = error.message, error.attempt
    else:
        msg, attempt = f"{type(error).__name__}: {error}", retries + 1
    rec: dict = {"name": task.name, "recording": str(task.recording), "campaign_id": task.campaign_id, "status": "failed",
                 "attempt": attempt, "error": msg}
    try:  # the worker's record, when it got that far (time, exit status, worker)
        prev = json.loads((task.out / TASK_FILE).read_text())
        if prev.get("campaign_id") == task.campaign_id:
            rec = {**prev, **rec, "attempt": max(attempt, int(prev.get("attempt", 0)))}
    except (OSError, ValueError):
        pass
    return rec


def _mm(v: float) -> str:
    return f"{1000.0 * v:.1f} mm"


def result_line(done: int, total: int, rec: dict, name_width: int = 0) -> str:
    """One line per finished recording: ``[done/total] status name  time  key figures``."""
    head = f"[{done:>{len(str(total))}}/{total}] {rec['status']:<7} {rec['name']:<{name_width}}"
    t = f"{rec['time_s']:6.1f} s" if rec.get("time_s") is not None else "      -"
    retry = f" (attempt {rec['attempt']})" if rec.get("attempt", 1) > 1 else ""
    if rec["status"] == "failed":
        return f"{head}  {t}{retry}  {rec.get('error', '')}"
    f = rec.get("figures", {})
    parts = [f"{f.get('session_id')}", f"antennas {f.get('estimated')}/{f.get('antennas')}"]
    verdicts = f.get("qc_verdicts", {})
    if verdicts:
        parts.append("qc " + ",".join(str(v) for v in verdicts.values()))
    parts.append(f"{f.get('warnings')} warning(s)")
    r = f.get("rmse")
    if r:
        parts.append(f"RMSE heading {r['heading_deg']:.3f} deg, vel_n {_mm(r['vel_n_mps'])}/s, "
                     f"lat {_mm(r['lat_m'])}, baseline {_mm(r['baseline_m'])}")
    line = f"{head}  {t}{retry}  " + ", ".join(parts)
    if rec["status"] == "partial":
        line += f"  ({rec.get('error', '')})"
    return line


def summary(kind: str, records: list[dict], *, engine: dict, wall_s: float, options: Sequence[str] = ()) -> dict:
    """The campaign summary (``OUT/campaign.json``): every task's record in the order given, the
    counts per status, the engine and the wall time."""
    counts = {s: sum(1 for r in records if r["status"] == s) for s in ("ok", "partial", "failed")}
    return {"kind": kind, "tasks": len(records), **counts, "wall_s": wall_s, "engine": engine,
            "options": list(options), "records": records}


def write_summary(out: Path, data: dict) -> Path:
    """Write ``out/campaign.json`` (replaced whole: written beside it, then renamed)."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / SUMMARY_FILE
    tmp = out / (SUMMARY_FILE + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)
    return path


def worker_info() -> dict:
    """What a worker needs to run the tasks well: its BLAS / OpenMP thread settings (1 each:
    one task per core) and whether the dpos packages import (from where)."""
    info: dict = {"worker": worker_id(), "python": sys.executable,
                  "threads_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}}

    info["dpos_core"] = str(Path(dpos_core.__file__).parent)
    return info
