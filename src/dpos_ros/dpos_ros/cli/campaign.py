"""``dpos-campaign``: many recordings (a survey campaign) or many Monte Carlo runs on a Dask
cluster - a local one on this machine by default, or an existing one given its scheduler.

    dpos-campaign process /data/rec01 /data/rec02 ... --out /data/products            # local cluster, one worker per core
    dpos-campaign process /data/rec* --out DIR --method urtss --workers 2 --retries 2
    dpos-campaign process /shared/rec* --out /shared/products --scheduler tcp://head:8786
    dpos-campaign eval --scenario paper_su --methods ups,urtss --runs 100 --seed 1 --out DIR
    dpos-campaign eval --scenario paper_su --runs 100 --runs-per-task 5 --scheduler tcp://head:8786 --out DIR

``process``: one task per recording, each exactly dpos-process (its options, e.g. ``--method``,
``--particles``, ``--master-reference``, ``--overwrite``, are passed on; its own ``--workers`` is
1); the products of recording R go to ``OUT/R/<session id>/``, its log to ``OUT/R/process.log``,
its result record to ``OUT/R/task.json``; a line per recording as it finishes; the summary
``OUT/campaign.json`` lists every recording (ok, partial = some antenna not estimated, failed +
the error).  A failed recording does not stop the others.

``eval``: dpos-eval's Monte Carlo runs of a transfer-alignment scenario (run r: seed S + r), one
task per ``--runs-per-task`` runs, combined exactly as dpos-eval combines them: ``OUT/metrics.json``
and ``OUT/report.md`` are dpos-eval's (same seeds, same figures), ``OUT/campaign.json`` the runs'
records.

Engine: ``--scheduler tcp://HOST:8786`` uses an existing Dask scheduler (its workers must have the
same dpos packages and see the recordings and OUT at the same paths: docs/campaign.md); without it
a LocalCluster of ``--workers`` processes (default one per core), one thread each, on 127.0.0.1:
its scheduler and workers talk TLS with a temporary certificate made for this run (Dask's
``Security.temporary()``, which needs the ``cryptography`` package: without it the cluster runs on
plain TCP and a warning says so), and serve no HTTP route (no dashboard, no ``/metrics``: Dask's
HTTP server still listens on a port of 127.0.0.1 and answers 404 to everything).
A task that fails is retried ``--retries`` times (default 1), then reported, not fatal.

Progress: the line per task on stdout, and a bar of the tasks done (with the time left) on stderr
when it is a terminal, not with ``--quiet`` nor into a file or a pipe.

Exit status: 0 every task ok; 1 some task failed (or a recording is partial); 2 unusable input
(a bad option, a missing recording, an unwritable OUT, an unreachable scheduler or one without
workers, the engine not installed) - nothing has run then.

The Dask engine (dask, distributed) is the optional extra ``dpos_ros[campaign]``
(``pip install 'dpos_ros[campaign]'``; the workspace's requirements-dev.txt has it): it is
imported only when a campaign runs, and without it dpos-campaign says so in one line (exit 2).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dpos_core.config import ConfigError
from dpos_core.evaluation.ifa import is_ifa_scenario
from dpos_core.sim.scenario import load_scenario
from dpos_ros.cli import evaluate as eval_cli
from dpos_ros.cli import process as process_cli
from dpos_ros.cli.campaign_tasks import (
    CampaignError,
    EvalTask,
    eval_tasks,
    failed_record,
    mean_rmse,
    process_tasks,
    result_line,
    run_eval_task,
    run_process_task,
    summary,
    worker_info,
    write_summary,
)
from dpos_ros.cli.options import one_line_errors
from dpos_ros.cli.progress import Stages
from dpos_ros.io.outdir import OutputError, probe_writable
from dpos_ros.runtime.pool import WORKER_ENV, default_workers, numba_stats

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_ERROR = 2
PROG = "dpos-campaign"
#: how to install the Dask engine (src/dpos_ros/setup.py extras_require["campaign"])
CAMPAIGN_EXTRA = "pip install 'dpos_ros[campaign]'"

#: dpos-process's options the campaign does not pass on (its own --out and --workers)
_PROCESS_OWN = {"help", "bag", "out", "workers", "quiet"}
#: dpos-eval's options of a transfer-alignment evaluation (the IFA and mismatch ones are not campaigns yet)
_EVAL_TA = {"scenario", "aircraft", "methods", "runs", "seed", "particles", "duration", "initial_attitude_error", "position_matching"}


def _engine_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("engine (Dask distributed)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://head:8786 (default: a local cluster on this machine)")
    g.add_argument("--workers", type=int, default=0, metavar="N",
                   help="local cluster: worker processes, one thread each (default 0 = one per core)")
    g.add_argument("--retries", type=int, default=1, metavar="N", help="retries of a failed task (default 1)")
    g.add_argument("--connect-timeout", type=float, default=20.0, metavar="S",
                   help="--scheduler: seconds to connect and to wait for a first worker (default 20)")
    p.add_argument("--quiet", action="store_true", help="no progress bar on the terminal (none is shown when stderr is not one)")


def _copy_options(src: argparse.ArgumentParser, dst: argparse.ArgumentParser, keep: Callable[[str], bool]) -> list[argparse.Action]:
    """Add ``src``'s options whose ``dest`` passes ``keep`` to ``dst`` (the same Action objects,
    as argparse's ``parents=`` does); returns them."""
    copied = [a for a in src._actions if keep(a.dest)]
    for a in copied:
        dst._add_action(a)
    return copied


def parser() -> argparse.ArgumentParser:
    """The command line of dpos-campaign."""
    return _parsers()[0]


def _parsers() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser], list[argparse.Action]]:
    """dpos-campaign's parser, its sub-commands' parsers, and the dpos-process options ``process`` passes on."""
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, metavar="{process,eval}")
    pp = sub.add_parser("process", help="dpos-process on every recording", description="dpos-process on every recording, one task each; "
                        "the other options are dpos-process's (its --workers is 1: the campaign's parallelism is one task per core)")
    pp.add_argument("recordings", type=Path, nargs="+", metavar="RECORDING", help="rosbag2 directories (or transfer_align_node spills)")
    pp.add_argument("--out", type=Path, required=True, help="output directory: OUT/<recording name>/ per recording, OUT/campaign.json")
    _engine_options(pp)
    forwarded = _copy_options(process_cli.parser(), pp, lambda d: d not in _PROCESS_OWN)
    ep = sub.add_parser("eval", help="dpos-eval's Monte Carlo runs, one task per run (or batch)",
                        description="dpos-eval's Monte Carlo runs of a transfer-alignment scenario on the cluster, combined as dpos-eval combines them")
    _copy_options(eval_cli.parser(), ep, lambda d: d in _EVAL_TA)
    ep.add_argument("--runs-per-task", type=int, default=1, metavar="K", help="Monte Carlo runs per task (default 1)")
    ep.add_argument("--out", type=Path, required=True, help="output directory: metrics.json, report.md (dpos-eval's), campaign.json")
    _engine_options(ep)
    return ap, {"process": pp, "eval": ep}, forwarded


def forwarded_argv(args: argparse.Namespace, actions: Sequence[argparse.Action]) -> list[str]:
    """The dpos-process command-line options of ``args`` that differ from dpos-process's defaults
    (an ``--aircraft`` or ``--geoid`` file as an absolute path: the workers do not run in this directory)."""
    argv: list[str] = []
    for a in actions:
        v = getattr(args, a.dest)
        if v == a.default:
            continue
        if a.dest in ("aircraft", "geoid") and Path(v).is_file():
            v = Path(v).resolve()
        if isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
            argv.append(a.option_strings[-1])
        else:
            argv += [a.option_strings[-1], str(v)]
    return argv


def distributed_module() -> Any:
    """The Dask engine: the ``distributed`` package (with ``distributed.comm.addressing``) of the
    optional extra ``dpos_ros[campaign]``, imported here and nowhere else, when a campaign runs.
    Raises :class:`CampaignError` naming the extra when it (or dask) is not installed."""
    try:
        import distributed
        import distributed.comm.addressing
    except ImportError as e:
        raise CampaignError(f"the Dask engine is not installed (no module {e.name or 'distributed'!r}): "
                            f"{CAMPAIGN_EXTRA}") from None
    return distributed


def _check_engine(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.workers < 0:
        ap.error(f"--workers must be >= 0 (0 = one per core), got {args.workers}")
    if args.retries < 0:
        ap.error(f"--retries must be >= 0, got {args.retries}")
    if not args.connect_timeout > 0:
        ap.error(f"--connect-timeout must be > 0 s, got {args.connect_timeout:g}")
    if args.scheduler is not None:
        if args.workers:
            ap.error("--workers is for the local cluster; with --scheduler the cluster's own workers run the tasks")
        addressing = distributed_module().comm.addressing
        try:
            addressing.parse_host_port(addressing.parse_address(args.scheduler)[1])
        except ValueError as e:
            ap.error(f"--scheduler {args.scheduler!r} is not a scheduler address like tcp://HOST:8786 ({e})")


@dataclass
class Engine:
    """A connected Dask client and what to report about it (``info``: JSON-able)."""

    client: Any
    info: dict


#: Dask configuration of the local cluster: no HTTP route on the scheduler and the workers (no
#: dashboard, no /metrics, no JSON API)
NO_HTTP_ROUTES: dict[str, Any] = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []}


def dist_config_set(values: dict[str, Any]) -> contextlib.AbstractContextManager[Any]:
    """``dask.config.set(values)`` (a context manager: the configuration is restored after)."""
    try:
        import dask
    except ImportError as e:  # (it comes with distributed; the extra names both)
        raise CampaignError(f"the Dask engine is not installed (no module {e.name or 'dask'!r}): {CAMPAIGN_EXTRA}") from None
    return dask.config.set(values)


def local_security(dist: Any) -> Any:
    """The local cluster's TLS: ``Security.temporary()`` (a certificate made for this run, held
    in memory, encryption required), or None with a warning on stderr when the ``cryptography``
    package it needs is not installed."""
    try:
        return dist.security.Security.temporary()  # (encryption required)
    except ImportError:
        print(f"{PROG}: warning: the local Dask cluster runs without TLS (plain TCP on 127.0.0.1): "
              "install the 'cryptography' package for a temporary certificate", file=sys.stderr)
        return None


@contextlib.contextmanager
def dask_engine(scheduler: str | None, workers: int, connect_timeout_s: float) -> Iterator[Engine]:
    """A Dask client: connected to ``scheduler`` (raises :class:`CampaignError` when it cannot be
    reached or has no worker within ``connect_timeout_s``), else to a new LocalCluster of
    ``workers`` processes (0 = one per core) with one thread and one BLAS thread each, no
    dashboard, on dynamic ports of 127.0.0.1; closed (and the local cluster stopped) on exit."""
    dist = distributed_module()
    Client, LocalCluster = dist.Client, dist.LocalCluster  # noqa: N806 - the classes' own names
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout=connect_timeout_s, set_as_default=False)
            except Exception as e:  # noqa: BLE001 - OSError / TimeoutError / ValueError (bad address): one message
                raise CampaignError(f"cannot connect to the Dask scheduler at {scheduler}: {e}") from None
            stack.callback(client.close)
            try:
                client.wait_for_workers(1, timeout=connect_timeout_s)
            except (TimeoutError, OSError):
                raise CampaignError(f"the Dask scheduler at {scheduler} has no worker after {connect_timeout_s:g} s "
                                    f"(start some: dask worker {scheduler} --nthreads 1)") from None
            info: dict[str, Any] = {"cluster": "remote", "scheduler": scheduler}
        else:
            n = workers or default_workers()
            security = local_security(dist)
            stack.enter_context(dist_config_set(NO_HTTP_ROUTES))  # the scheduler, the nannies and (passed on) the workers
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", scheduler_port=0,
                                   dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False},
                                   silence_logs=logging.CRITICAL, env=dict(WORKER_ENV),
                                   **({} if security is None else {"security": security, "protocol": "tls://"}))
            stack.callback(cluster.close)
            client = Client(cluster, set_as_default=False, **({} if security is None else {"security": security}))
            stack.callback(client.close)
            info = {"cluster": "local", "scheduler": cluster.scheduler_address, "tls": security is not None}
        info["workers"] = len(client.scheduler_info(n_workers=-1)["workers"])
        yield Engine(client, info)


def check_workers(engine: Engine) -> list[str]:
    """Ask every worker for :func:`worker_info`; returns warnings (a worker whose BLAS may use
    several threads).  Raises :class:`CampaignError` when a worker cannot run dpos code."""
    try:
        infos = engine.client.run(worker_info)
    except Exception as e:  # noqa: BLE001 - ModuleNotFoundError on a node without the packages, ...
        raise CampaignError(f"a worker cannot run the dpos packages ({type(e).__name__}: {e}); every worker needs "
                            "the same venv / packages as this machine (docs/campaign.md)") from None
    engine.info["worker_info"] = infos
    warnings = []
    for addr, info in infos.items():
        bad = {k: v for k, v in info["threads_env"].items() if v != "1"}
        if bad:
            warnings.append(f"worker {addr}: {', '.join(f'{k}={v}' for k, v in bad.items())}: BLAS may use several threads "
                            "per worker (start workers with OPENBLAS_NUM_THREADS=OMP_NUM_THREADS=MKL_NUM_THREADS=1)")
    return warnings


def run_tasks(engine: Engine, fn: Callable[[Any], Any], tasks: Sequence[Any], keys: Sequence[str], retries: int,
              on_done: Callable[[int, Any, BaseException | None], None]) -> list[tuple[Any, BaseException | None]]:
    """Submit ``fn(task)`` for every task (Dask retries a task that raises ``retries`` times) and
    call ``on_done(index, result, error)`` as each finishes; returns (result, error) per task in
    the order given.  A task that fails every attempt is an ``error``, not an exception here."""
    as_completed = distributed_module().as_completed
    futs = [engine.client.submit(fn, t, key=k, retries=retries, pure=False) for t, k in zip(tasks, keys, strict=True)]
    index = {f.key: i for i, f in enumerate(futs)}
    out: list[tuple[Any, BaseException | None]] = [(None, None)] * len(futs)
    try:
        for fut in as_completed(futs, loop=engine.client.loop):
            i = index[fut.key]
            if fut.status == "finished":
                out[i] = (fut.result(), None)
            elif fut.status == "cancelled":
                out[i] = (None, RuntimeError("the task was cancelled (the scheduler lost it)"))
            else:
                out[i] = (None, fut.exception())
            on_done(i, *out[i])
    finally:
        for f in futs:
            f.release()
    return out


class _Counter:
    """done / failed counts of the progress lines."""

    def __init__(self, total: int) -> None:
        self.total, self.done, self.failed = total, 0, 0

    def tick(self, failed: bool) -> tuple[int, int]:
        self.done += 1
        self.failed += int(failed)
        return self.done, self.failed


def _numba_line(engine: Engine) -> str:
    stats = engine.client.run(numba_stats)
    engine.info["numba"] = stats
    parts = [f"{addr}: {s['loaded_from_cache']} loaded from the cache, {s['compiled']} compiled" for addr, s in stats.items() if s.get("numba")]
    return "numba kernels per worker: " + "; ".join(parts)


def main_process(ap: argparse.ArgumentParser, args: argparse.Namespace, forwarded: Sequence[argparse.Action]) -> int:
    process_cli._check_numbers(ap, args)  # dpos-process's checks (its --workers is the campaign's: also >= 0, 0 = per core)
    options = forwarded_argv(args, forwarded)
    campaign_id = uuid.uuid4().hex[:12]
    try:
        tasks = process_tasks(args.recordings, args.out, options, campaign_id)
        probe_writable(args.out)
    except (CampaignError, OutputError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    t0 = time.perf_counter()
    try:
        with dask_engine(args.scheduler, args.workers, args.connect_timeout) as engine:
            for w in check_workers(engine):
                print(f"{PROG}: warning: {w}", file=sys.stderr)
            print(f"{PROG}: {len(tasks)} recording(s) on a {engine.info['cluster']} Dask cluster ({engine.info['scheduler']}, "
                  f"{engine.info['workers']} worker(s)), retries {args.retries}; dpos-process {' '.join(options) or '(defaults)'}",
                  flush=True)
            count = _Counter(len(tasks))
            records: list[dict] = [{} for _ in tasks]
            width = max(len(t.name) for t in tasks)

            st = Stages(PROG, quiet=args.quiet)

            def done(i: int, rec: dict | None, err: BaseException | None) -> None:
                records[i] = rec if err is None and rec is not None else failed_record(tasks[i], err or RuntimeError("no result"), args.retries)
                n, failed = count.tick(records[i]["status"] == "failed")
                st.print(result_line(n, len(tasks), records[i], width) + (f"   [{failed} failed]" if failed else ""))
                bar.advance()

            with st.items("recording", len(tasks)) as bar:
                run_tasks(engine, run_process_task, tasks, [f"process-{t.name}-{campaign_id}" for t in tasks], args.retries, done)
            print(_numba_line(engine))
            info = engine.info
    except CampaignError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    wall = time.perf_counter() - t0
    data = summary("process", records, engine=info, wall_s=wall, options=options)
    path = write_summary(args.out, data)
    print(f"{len(records)} recording(s): {data['ok']} ok, {data['partial']} partial, {data['failed']} failed; "
          f"{wall:.1f} s wall; summary {path}")
    return EXIT_OK if data["ok"] == len(records) else EXIT_FAILED


def _eval_record(task: EvalTask, result: dict | None, err: BaseException | None, retries: int) -> dict:
    rec: dict = {"name": "seeds " + ",".join(str(s) for s in task.seeds), "seeds": list(task.seeds)}
    if err is not None or result is None:
        return {**rec, "status": "failed", "attempt": retries + 1, "error": f"{type(err).__name__}: {err}"}
    runs = result["runs"]
    return {**rec, "status": "ok", "time_s": result["time_s"], "worker": result["worker"], "lines": [ln for r in runs for ln in r.lines],
            "rmse": {r.seed: {m: mean_rmse(ev) for m, ev in r.evaluations.items()} for r in runs}}


def main_eval(ap: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    if args.runs_per_task < 1:
        ap.error(f"--runs-per-task must be >= 1, got {args.runs_per_task}")
    args.initial_heading_error = None  # (an IFA option of dpos-eval's checks)
    eval_cli.check_numbers(ap, args)
    try:
        scenario = load_scenario(args.scenario, aircraft=args.aircraft)
    except ConfigError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    if is_ifa_scenario(scenario):
        ap.error(f"scenario {scenario.name} is an in-flight alignment evaluation: run it with dpos-eval "
                 "(dpos-campaign eval runs transfer-alignment scenarios)")
    methods = eval_cli.scenario_methods(ap, args, scenario)
    plan = eval_cli.ta_plan(ap, args, scenario, methods)
    try:
        tasks = eval_tasks(plan, args.runs, args.seed, args.runs_per_task)
        probe_writable(args.out)
    except (CampaignError, OutputError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    campaign_id = uuid.uuid4().hex[:12]
    t0 = time.perf_counter()
    results: list[tuple[Any, BaseException | None]] = []
    try:
        with dask_engine(args.scheduler, args.workers, args.connect_timeout) as engine:
            for w in check_workers(engine):
                print(f"{PROG}: warning: {w}", file=sys.stderr)
            print(f"{PROG}: {args.runs} run(s) of {scenario.name} (seeds {args.seed}..{args.seed + args.runs - 1}, methods "
                  f"{','.join(methods)}) in {len(tasks)} task(s) on a {engine.info['cluster']} Dask cluster "
                  f"({engine.info['scheduler']}, {engine.info['workers']} worker(s)), retries {args.retries}", flush=True)
            count = _Counter(len(tasks))
            records: list[dict] = [{} for _ in tasks]

            st = Stages(PROG, quiet=args.quiet)

            def done(i: int, res: dict | None, err: BaseException | None) -> None:
                records[i] = _eval_record(tasks[i], res, err, args.retries)
                n, failed = count.tick(records[i]["status"] == "failed")
                head = f"[{n:>{len(str(len(tasks)))}}/{len(tasks)}] {records[i]['status']:<7} {records[i]['name']}"
                if err is not None:
                    st.print(f"{head}  {records[i]['error']}   [{failed} failed]")
                else:
                    st.print(f"{head}  {records[i]['time_s']:.1f} s" + "".join(f"\n    {ln}" for ln in records[i]["lines"]))
                bar.advance()

            with st.items("task", len(tasks)) as bar:
                results = run_tasks(engine, run_eval_task, tasks, [f"eval-{t.seeds[0]}-{campaign_id}" for t in tasks], args.retries, done)
            print(_numba_line(engine))
            info = engine.info
    except CampaignError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    runs = [run for res, err in results if err is None for run in res["runs"]]  # the tasks are in seed order
    failed_seeds = [s for t, (_, err) in zip(tasks, results, strict=True) if err is not None for s in t.seeds]
    if runs:
        eval_cli.ta_write(args.out, plan, runs)
    wall = time.perf_counter() - t0
    data = summary("eval", records, engine=info, wall_s=wall)
    data.update(scenario=scenario.name, methods=list(methods), seeds=[args.seed + r for r in range(args.runs)],
                combined_runs=len(runs), failed_seeds=failed_seeds)
    path = write_summary(args.out, data)
    print(f"{args.runs} run(s): {len(runs)} combined" + (f", failed seeds {failed_seeds}" if failed_seeds else "")
          + f"; {wall:.1f} s wall; summary {path}")
    if not runs:
        print(f"{PROG}: no run succeeded: no metrics.json", file=sys.stderr)
    return EXIT_OK if not failed_seeds else EXIT_FAILED


@one_line_errors(PROG)
def main(argv: list[str] | None = None) -> int:
    ap, subs, forwarded = _parsers()
    args = ap.parse_args(argv)
    try:
        distributed_module()
    except CampaignError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    sub = subs[args.command]
    _check_engine(sub, args)
    try:
        if args.command == "process":
            return main_process(sub, args, forwarded)
        return main_eval(sub, args)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted: the cluster's tasks were cancelled; no campaign.json written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
