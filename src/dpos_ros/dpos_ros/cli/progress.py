"""A minimal progress bar for terminals (silent when stderr is not a TTY)."""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, label: str, stream=None, enabled: bool | None = None) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        frac = min(1.0, done / total)
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        self.stream.write(f"\r{self.label} [{bar}] {100 * frac:5.1f}% {time.perf_counter() - self.t0:6.1f} s")
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()
