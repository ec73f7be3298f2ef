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


def stop_executor(executor: Any, thread: Any = None, timeout_s: float = 10.0) -> None:
    """Stop ``executor`` and wait until none of its callbacks runs any more (then its nodes may be destroyed).

    ``executor.shutdown()`` alone does not do this in rclpy 7.1 (Jazzy): it returns without waiting for
    the callbacks in progress, and a MultiThreadedExecutor's ``spin_once`` hands a callback to its thread
    pool and returns before it ran - so a node destroyed right after may still have a callback running
    in a pool thread, which then fails on a destroyed handle (``InvalidHandle``; on a busy machine the
    callbacks run late and this happens). Here: shutdown (spin() returns), join the thread that spun it
    (``thread``), then wait for the pool's callbacks (those handed over and not started yet run too: a
    cancelled one leaves a never-awaited coroutine) and for the executor's work in progress. A callback still running after that is a hang the test's timeout ends.
    """
    executor.shutdown(timeout_sec=timeout_s)
    if thread is not None:
        thread.join(timeout_s)
        if thread.is_alive():
            raise AssertionError(f"the executor's spin thread did not end within {timeout_s} s of its shutdown")
    pool = getattr(executor, "_executor", None)  # MultiThreadedExecutor's ThreadPoolExecutor
    if isinstance(pool, ThreadPoolExecutor):
        pool.shutdown(wait=True)
    tracker = getattr(executor, "_work_tracker", None)
    if tracker is not None and not tracker.wait(timeout_s):
        raise AssertionError(f"callbacks of the executor still running {timeout_s} s after its shutdown")


def stop_and_destroy(executor: Any, nodes: Iterable[Any], thread: Any = None, timeout_s: float = 10.0) -> None:
    """The shutdown order of an in-process test: stop the nodes' own threads (a simulated device's
    ``device.stop()``), stop ``executor`` and wait for its callbacks (:func:`stop_executor`), then
    destroy ``nodes``. Destroying a node first, while a callback of it runs in an executor thread,
    raises ``InvalidHandle`` there."""
    nodes = list(nodes)
    try:
        for n in nodes:
            if getattr(n, "device", None) is not None:
                n.device.stop()
        stop_executor(executor, thread, timeout_s)
    finally:
        for n in nodes:
            n.destroy_node()
