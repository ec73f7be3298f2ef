"""The worker processes of the smoothers (transfer_align_node and :func:`dpos_ros.products.ta.solve`)."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os


def process_pool(n_workers: int) -> cf.ProcessPoolExecutor:
    """``n_workers`` (at least 1) spawned worker processes: "spawn", not "fork", because the
    callers may run threads (rclpy executors, numba) that a forked child would inherit mid-state."""
    return cf.ProcessPoolExecutor(max_workers=max(1, n_workers), mp_context=mp.get_context("spawn"))


def worker_count(workers: int, tasks: int) -> int:
    """How many workers to start for ``tasks`` tasks: ``workers`` (0 = one per core), at most one
    per task, at least 1."""
    return max(1, min(tasks, workers or (os.cpu_count() or 1)))
