"""The worker processes of the smoothers (transfer_align_node and :func:`dpos_ros.products.ta.solve`)."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing.context as mpc
import os
import signal
import threading
from collections.abc import Callable

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


def worker_count(workers: int, tasks: int) -> int:
    """How many workers to start for ``tasks`` tasks: ``workers`` (0 = one per core), at most one
    per task, at least 1."""
    return max(1, min(tasks, workers or (os.cpu_count() or 1)))


def warm_pool(n_workers: int, warm: Callable[[], object]) -> tuple[cf.ProcessPoolExecutor, list[cf.Future]]:
    """:func:`process_pool` with its ``n_workers`` workers started now, each running ``warm`` (a
    module-level function or a partial of one, pickled by name; e.g.
    :func:`dpos_core.ta.warmup.warm_up`) in the background: a spawned worker otherwise spends
    ~1.5 s of CPU importing the filters and loading their numba kernels before its first sub-IMU.
    One call per worker: each ``submit`` while no worker is idle starts one, and ``warm`` takes
    longer than a worker's start, so each worker takes one.  Returns the pool and the warm-up
    futures (a ``warm`` that fails needs no handling: the real tasks report their own errors)."""
    pool = process_pool(n_workers)
    return pool, [pool.submit(warm) for _ in range(max(1, n_workers))]
