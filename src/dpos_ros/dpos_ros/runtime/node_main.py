"""The ``main()`` of every dpos node: init, construct, spin, clean shutdown.

Pattern (Jazzy's ``rclpy.init()`` is not a context manager)::

    install SIGINT/SIGTERM handlers that only set a stop flag
    try:
        rclpy.init(signal_handler_options=NO)
        executor, node = ...
        while not stop and rclpy.ok(): executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException): pass
    finally: node.destroy_node(); rclpy.try_shutdown(); restore the signal handlers

Why not rclpy's own signal handlers: they shut the context down at once, and a signal that
arrives while the node or executor is still being built then makes rclpy raise ``RCLError``
("context is not valid") and print tracebacks from ``__del__``. With a stop flag, a SIGINT or
SIGTERM at any moment ends the process with status 0 and no traceback; the spin loop notices
it within ``POLL_PERIOD_S``.

A :class:`~dpos_ros.runtime.params.ParameterError` while the node is constructed is logged as one
error line naming the parameter and value, and gives exit status 2.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
import rclpy.logging
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from dpos_ros.runtime.params import ParameterError

__all__ = ["run_node", "install_stop_handlers", "restore_handlers", "EXIT_OK", "EXIT_BAD_PARAMETER", "POLL_PERIOD_S"]

EXIT_OK = 0
EXIT_BAD_PARAMETER = 2
#: Longest time between a stop signal and the end of the spin loop.
POLL_PERIOD_S = 0.1

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def install_stop_handlers(on_stop: Callable[[], None]) -> dict:
    """SIGINT and SIGTERM call ``on_stop()`` instead of raising (only in the main thread, where
    Python allows handlers; elsewhere nothing is installed).  Returns the previous handlers, for
    :func:`restore_handlers`."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in _STOP_SIGNALS:
            previous[sig] = signal.signal(sig, lambda _signum, _frame: on_stop())
    return previous


def restore_handlers(previous: dict) -> None:
    """Put back the handlers :func:`install_stop_handlers` replaced."""
    for sig, handler in previous.items():
        signal.signal(sig, handler)


def run_node(
    node_factory: Callable[[], Any],
    node_name: str,
    argv: Sequence[str] | None = None,
    executor_factory: Callable[[], Executor] = SingleThreadedExecutor,
) -> int:
    """Run one node until SIGINT/SIGTERM or context shutdown; return the exit status.

    Args:
        node_factory: builds the node (called after ``rclpy.init``).
        node_name: the logger name used when construction fails.
        argv: command line (``sys.argv`` when None), ``--ros-args ...`` included.
        executor_factory: the executor to spin the node in.
    """
    args = list(sys.argv if argv is None else argv)
    stop = threading.Event()
    previous = install_stop_handlers(stop.set)
    node = None
    executor = None
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        executor = executor_factory()
        try:
            node = node_factory()
        except ParameterError as exc:
            rclpy.logging.get_logger(node_name).error(str(exc))
            return EXIT_BAD_PARAMETER
        executor.add_node(node)
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=POLL_PERIOD_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        restore_handlers(previous)
    return EXIT_OK
