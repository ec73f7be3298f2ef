"""The worker processes of the smoothers (transfer_align_node and :func:`dpos_ros.products.solve.solve`)."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing.context as mpc
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

from numba.core.registry import CPUDispatcher

#: the BLAS / OpenMP thread counts of a worker: one (its matrices are small, one worker per core;
#: BLAS threads would contend with the other workers: ~5 % of a paper_wing sub-IMU's CPU)
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

_env_lock = threading.Lock()


class _OneThreadBlasProcess(mpc.SpawnProcess):
    """A spawned process started with :data:`WORKER_ENV` in its environment (read by numpy's
    BLAS when the child imports it); the parent's environment is restored at once."""

    def start(self) -> None:
        with _env_lock:
            saved = {k: os.environ.get(k) for k in WORKER_ENV}
            os.environ.update(WORKER_ENV)
            try:
                super().start()
            finally:
                for k, v in saved.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v


class _SpawnContext(mpc.SpawnContext):
    Process = _OneThreadBlasProcess


def _ignore_sigint() -> None:
    """Worker initializer: SIGINT is the parent's to handle.  A Ctrl-C in a terminal (or a
    ``killpg(SIGINT)``) reaches the whole process group; a worker that died of it would break the
    pool under the parent's orderly shutdown (transfer_align_node finalizes the session it holds,
    and writes its products with the workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def process_pool(n_workers: int) -> cf.ProcessPoolExecutor:
    """``n_workers`` (at least 1) spawned worker processes: "spawn", not "fork", because the
    callers may run threads (rclpy executors, numba) that a forked child would inherit mid-state;
    each with one BLAS thread (:data:`WORKER_ENV`), ignoring SIGINT (:func:`_ignore_sigint`)."""
    return cf.ProcessPoolExecutor(max_workers=max(1, n_workers), mp_context=_SpawnContext(), initializer=_ignore_sigint)


#: environment variable: the worker count that ``workers: 0`` ("one per core") means, e.g. on a
#: computer shared with other work (docs/running.md); unset: the cores this process may run on
WORKERS_ENV = "DPOS_WORKERS"


def max_workers() -> int:
    """The most worker processes a command accepts: 4 per core this process may use (each worker
    is a Python process holding a filter; more only thrash the machine)."""
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # (no affinity on this platform)
        cores = os.cpu_count() or 1
    return 4 * cores


def default_workers() -> int:
    """The worker processes that ``0`` (one per core) means: :data:`WORKERS_ENV` when set to a
    positive integer (anything else is an error naming it), else the CPUs this process may use."""
    text = os.environ.get(WORKERS_ENV, "").strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if not 1 <= n <= max_workers():
            raise ValueError(f"{WORKERS_ENV}={text!r}: expected a number of worker processes in 1..{max_workers()}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # (no affinity on this platform)
        return os.cpu_count() or 1


def worker_count(workers: int, tasks: int) -> int:
    """How many workers to start for ``tasks`` tasks: ``workers`` (0 = :func:`default_workers`), at
    most one per task, at least 1."""
    return max(1, min(tasks, workers or default_workers()))


def numba_stats() -> dict:
    """This process's numba kernels of dpos_core and dpos_ros: where their cache is, whether it can
    be written, how many were loaded from it and how many compiled (cache misses)."""
    hits = misses = 0
    paths: set[str] = set()
    for name, mod in list(sys.modules.items()):
        if not name.startswith(("dpos_core", "dpos_ros")) or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, CPUDispatcher):
                st = obj.stats
                hits += sum(st.cache_hits.values())
                misses += sum(st.cache_misses.values())
                if st.cache_path:
                    paths.add(st.cache_path)
    return {"numba": True, "loaded_from_cache": hits, "compiled": misses, "cache_dirs": sorted(paths),
            "cache_writable": all(os.access(p, os.W_OK) for p in paths) if paths else None}


def _warm(warm: Callable[[], object]) -> dict:
    """A worker's warm-up task: ``{"result": warm(), "compiled": whether this process compiled numba
    kernels into a cache it could write}`` (then the next process loads them from there)."""
    result = warm()
    st = numba_stats()
    return {"result": result, "compiled": bool(st.get("compiled")) and bool(st.get("cache_writable"))}


class WarmPool(cf.Executor):
    """:func:`process_pool` whose workers run a warm-up first (:func:`warm_pool`).  On a fresh install
    (empty numba caches) the warm-up compiles the kernels, and the compiler's memory stays in the
    worker's heap (~80 MB a worker; a 4 h paper_wing flight peaked at 1961 MB instead of 1739 MB):
    then, at the first task, the workers are replaced by new ones, which load the kernels from the
    cache just written (~0.7 s).  With warm caches the workers are kept.  ``make``: the executor of
    ``n_workers`` (:func:`process_pool`; tests give threads)."""

    def __init__(self, n_workers: int, warm: Callable[[], object], make: Callable[[int], cf.Executor] = process_pool) -> None:
        self.n_workers = max(1, n_workers)
        self._make = make
        self._pool = make(self.n_workers)
        self.warm_futures = [self._pool.submit(_warm, warm) for _ in range(self.n_workers)]
        self.recycled = False
        self._checked = False
        self._lock = threading.Lock()

    def _check(self) -> None:
        with self._lock:
            if self._checked:
                return
            self._checked = True
            try:
                compiled = any(f.result()["compiled"] for f in self.warm_futures)
            except Exception:  # (a failed warm-up: the real tasks report their own errors)
                return
            if compiled:
                self._pool.shutdown(wait=True)
                self._pool = self._make(self.n_workers)
                self.recycled = True

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        self._check()
        return self._pool.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._checked = True  # (no recycling after a shutdown)
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)


def warm_pool(n_workers: int, warm: Callable[[], object]) -> tuple[WarmPool, list[cf.Future]]:
    """:class:`WarmPool`: ``n_workers`` (at least 1) worker processes started now, each running
    ``warm`` (a module-level function or a partial of one, pickled by name; e.g.
    :func:`dpos_core.ta.warmup.warm_up`) in the background: a spawned worker otherwise spends
    ~1.5 s of CPU importing the filters and loading their numba kernels before its first sub-IMU.
    One call per worker: each ``submit`` while no worker is idle starts one, and ``warm`` takes
    longer than a worker's start, so each worker takes one.  Returns the pool and the warm-up
    futures (their results: :func:`_warm`'s; a ``warm`` that fails needs no handling: the real
    tasks report their own errors)."""
    pool = WarmPool(n_workers, warm)
    return pool, pool.warm_futures
