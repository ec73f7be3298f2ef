"""CPU-bound neighbours for the ``--cpu-burner N`` pytest option (``make stress``).

A burner is ``python3 -c`` of a busy loop that also watches its parent: it exits by itself when
the pytest process that started it is gone (even after a SIGKILL of pytest), so no burner outlives
the run. :func:`stop_burners` terminates them at the end of the session in any case.
"""

from __future__ import annotations

import os
import subprocess
import sys

#: a busy loop that checks every few million iterations whether its parent still lives
_BURN = (
    "import os, sys\n"
    "parent = int(sys.argv[1])\n"
    "while os.getppid() == parent:\n"
    "    for _ in range(2_000_000):\n"
    "        pass\n"
)


def start_burners(n: int) -> list[subprocess.Popen[bytes]]:
    """Start ``n`` CPU-bound processes beside this one (each takes one core while it runs)."""
    return [
        subprocess.Popen([sys.executable, "-c", _BURN, str(os.getpid())], stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(n)
    ]


def stop_burners(burners: list[subprocess.Popen[bytes]]) -> None:
    """Terminate the burners (kill those that do not stop within 5 s) and reap them."""
    for p in burners:
        if p.poll() is None:
            p.terminate()
    for p in burners:
        try:
            p.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=5.0)


def read_loadavg() -> str:
    """The first three fields of /proc/loadavg (1, 5, 15 min), or '?' where it cannot be read."""
    try:
        with open("/proc/loadavg", encoding="ascii") as fh:
            return " ".join(fh.read().split()[:3])
    except OSError:
        return "?"
