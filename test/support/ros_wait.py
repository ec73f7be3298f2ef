"""Bounded waits for in-process ROS tests (no fixed sleeps): spin an executor until a condition holds;
and the shutdown order of an executor and its nodes (:func:`stop_and_destroy`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any


def spin_until(executor: Any, condition: Callable[[], bool], timeout: float, what: str | Callable[[], str],
               step_s: float = 0.05) -> None:
    """Spin ``executor`` until ``condition()``; fail after ``timeout`` s, describing ``what`` (a string
    or a callable giving one, evaluated only on failure)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what() if callable(what) else what}")
        executor.spin_once(timeout_sec=step_s)


def stop_executor(executor: Any, timeout_s: float = 10.0) -> None:
    """Shut ``executor`` down once none of its callbacks runs any more; call it when nothing spins the
    executor (a thread that spun it stopped and joined). Then its nodes may be destroyed.

    rclpy 7.1 (Jazzy): a MultiThreadedExecutor's ``spin_once`` hands a callback to its thread pool and
    returns before it ran, and ``Executor.shutdown()`` neither waits for the callbacks in progress nor
    keeps the executor's guard condition for them (it destroys it; a callback triggers it when done):
    a callback still running then fails on a destroyed handle (``InvalidHandle``), and so does one of a
    node destroyed under it - on a busy machine the callbacks run late and this happens. So: wait for
    the pool's callbacks (every one handed over runs: a cancelled one would leave a never-awaited
    coroutine), then shut the executor down and wait for its work in progress. A callback that never
    ends is a hang the test's timeout ends.
    """
    pool = getattr(executor, "_executor", None)  # MultiThreadedExecutor's ThreadPoolExecutor
    if isinstance(pool, ThreadPoolExecutor):
        pool.shutdown(wait=True)
    executor.shutdown(timeout_sec=timeout_s)
    tracker = getattr(executor, "_work_tracker", None)
    if tracker is not None and not tracker.wait(timeout_s):
        raise AssertionError(f"callbacks of the executor still running {timeout_s} s after its shutdown")


def stop_and_destroy(executor: Any, nodes: Iterable[Any], timeout_s: float = 10.0) -> None:
    """The shutdown order of an in-process test, once nothing spins ``executor`` any more: stop the
    nodes' own threads (a simulated device's ``device.stop()``), wait for the executor's callbacks and
    shut it down (:func:`stop_executor`), then destroy ``nodes``. Destroying a node first, while a
    callback of it runs in an executor thread, raises ``InvalidHandle`` there."""
    nodes = list(nodes)
    try:
        for n in nodes:
            if getattr(n, "device", None) is not None:
                n.device.stop()
        stop_executor(executor, timeout_s)
    finally:
        for n in nodes:
            n.destroy_node()
