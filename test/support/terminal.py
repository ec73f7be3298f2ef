"""Run a command with its stderr on a pseudo-terminal: what a user at a terminal sees of its
progress (dpos_ros.cli.progress draws only on a terminal)."""

from __future__ import annotations

import fcntl
import os
import pty
import struct
import subprocess
import termios
import threading


def on_pty(argv: list[str], timeout: float = 600.0, size: tuple[int, int] | None = (120, 40)) -> tuple[int, str, str]:
    """Run ``argv`` with its stderr on a pseudo-terminal of ``size`` (columns, rows; None: the 0 x 0
    a terminal-less ``script`` gives), stdout on a pipe; returns (exit status, stdout, what the
    terminal received)."""
    master, slave = pty.openpty()
    if size is not None:
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", size[1], size[0], 0, 0))
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    chunks: list[bytes] = []

    def pump() -> None:
        while True:
            try:
                b = os.read(master, 4096)
            except OSError:  # (EIO: the child closed the terminal)
                return
            if not b:
                return
            chunks.append(b)

    th = threading.Thread(target=pump, daemon=True)
    th.start()
    try:
        out, _ = p.communicate(timeout=timeout)
    finally:
        p.kill()
        th.join(timeout=10)
        os.close(master)
    return p.returncode, out.decode(), b"".join(chunks).decode(errors="replace")
