"""The warm worker pool of dpos-process and transfer_align_node (dpos_ros.runtime.pool.WarmPool): on
a fresh install (an empty numba cache) the workers that compiled the kernels while warming up are
replaced at the first task by new ones, which load the kernels from the cache just written; with
a warm cache the workers are kept."""

from __future__ import annotations

from pathlib import Path

import pytest

from dpos_core.ifa.warmup import warm_up_mechanization
from dpos_ros.runtime.pool import _warm, numba_stats, warm_pool


def test_workers_that_compiled_are_replaced_by_workers_that_load_from_the_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))  # (read by the spawned workers: a fresh install)
    pool, warming = warm_pool(1, warm_up_mechanization)  # (one worker: the tasks below run in the same one)
    try:
        assert all(f.result(timeout=600)["compiled"] for f in warming)  # the worker compiled into the empty cache
        again = pool.submit(_warm, warm_up_mechanization).result(timeout=600)  # the first task: in a new worker
        assert pool.recycled and not again["compiled"]
        stats = pool.submit(numba_stats).result(timeout=60)
        assert stats["loaded_from_cache"] > 0 and stats["compiled"] == 0
    finally:
        pool.shutdown()
    pool, warming = warm_pool(1, warm_up_mechanization)  # the cache is warm now: the worker is kept
    try:
        assert not warming[0].result(timeout=600)["compiled"]
        assert pool.submit(int).result(timeout=60) == 0 and not pool.recycled
    finally:
        pool.shutdown()


def test_default_workers_is_the_environment_or_the_cores(monkeypatch) -> None:
    """``workers: 0`` means DPOS_WORKERS when set (a shared computer), else this process's CPUs;
    a value that is no positive integer is an error naming the variable."""
    import os

    from dpos_ros.runtime.pool import default_workers, worker_count

    monkeypatch.setenv("DPOS_WORKERS", "3")
    assert default_workers() == 3 and worker_count(0, 10) == 3 and worker_count(0, 2) == 2 and worker_count(5, 10) == 5
    monkeypatch.delenv("DPOS_WORKERS")
    assert default_workers() == len(os.sched_getaffinity(0))
    for bad in ("0", "-2", "two"):
        monkeypatch.setenv("DPOS_WORKERS", bad)
        with pytest.raises(ValueError, match="DPOS_WORKERS"):
            default_workers()
