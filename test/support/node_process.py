"""Helpers for tests that run dpos nodes as subprocesses (console scripts of the venv)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

BIN_DIR = Path(sys.executable).parent

#: Hang guards of the tests that run node processes and CLIs [s]: how long a start (to its first log
#: line, or to its exit on a bad parameter), a stop (after SIGINT / SIGTERM) or a short CLI run may
#: take before the test fails. Not performance bounds: a node's start alone costs 4-9 s of CPU
#: (imports, numba kernels loaded; measured: ifa_node 4.2 s, pos_master_node 6.4 s,
#: transfer_align_node 8.6 s), a graph starts several at once, and on a busy machine (``make
#: stress``: a CPU-bound neighbour on the 2 cores) each gets a fraction of a core - 30 s was measured
#: too short there. Every wait ends as soon as its condition holds.
START_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 60.0
CLI_TIMEOUT_S = 120.0


class NodeProcess:
    """A node started from its console script; stdout and stderr are read line by line.

    Every wait is bounded by a deadline; nothing sleeps for a fixed time.
    """

    def __init__(self, script: str, args: Sequence[str] = ()) -> None:
        self.argv = [str(BIN_DIR / script), *args]
        env = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_LOGGING_BUFFERED_STREAM="0")
        self.proc = subprocess.Popen(
            self.argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        self.lines: list[str] = []
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._queue.put(line.rstrip("\n"))
        self._queue.put(None)

    def _drain(self, timeout: float) -> bool:
        """Move one line (waiting up to ``timeout``) into ``lines``; False at end of output."""
        try:
            line = self._queue.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return True
        if line is None:
            self._queue.put(None)
            return False
        self.lines.append(line)
        return True

    def wait_for_line(self, text: str, timeout: float) -> str:
        """The first output line containing ``text``; fails after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        checked = 0
        while True:
            for line in self.lines[checked:]:
                if text in line:
                    return line
            checked = len(self.lines)
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"no line with {text!r} within {timeout} s; output:\n{self.output}")
            if not self._drain(remaining) and checked == len(self.lines):
                raise AssertionError(
                    f"{self.argv[0]} exited ({self.proc.poll()}) without a line with {text!r}; output:\n{self.output}"
                )

    def wait(self, timeout: float) -> int:
        """Exit status, waiting up to ``timeout`` seconds; all output is collected."""
        rc = self.proc.wait(timeout=timeout)
        self._reader.join(timeout=timeout)
        while True:
            try:
                line = self._queue.get_nowait()
            except queue.Empty:
                break
            if line is None:
                self._queue.put(None)
                break
            self.lines.append(line)
        return rc

    def send_signal(self, sig: int = signal.SIGINT) -> None:
        self.proc.send_signal(sig)

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


@pytest.fixture
def start_node() -> Iterator:
    """``start_node(script, *args) -> NodeProcess``; leftover processes are killed after the test."""
    started: list[NodeProcess] = []

    def _start(script: str, *args: str) -> NodeProcess:
        node = NodeProcess(script, args)
        started.append(node)
        return node

    try:
        yield _start
    finally:
        for node in started:
            node.kill()
