"""Bounded waits for in-process ROS tests (no fixed sleeps): spin an executor until a condition holds."""

from __future__ import annotations

import time
from collections.abc import Callable
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
