"""A command's ``main(argv)`` run in the test's own process: its exit status and what it wrote on
stdout and stderr, as ``subprocess.run(..., capture_output=True, text=True)`` gives them.

For the usage errors of a command, which are decided by its argument parsing and checks before
any work: the same code as the console script runs (the script is ``sys.exit(main())``), without
a Python process of its own (~2 s of CPU each to import numpy, scipy, numba and dpos). Each command
keeps at least one test that runs its console script, so the entry point itself stays tested.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class MainResult:
    """What ``subprocess.CompletedProcess`` has of a run: exit status, stdout, stderr."""

    returncode: int
    stdout: str
    stderr: str


def run_main(main: Callable[[list[str]], int | None], argv: Sequence[str]) -> MainResult:
    """``main(list(argv))`` with stdout and stderr captured; a ``SystemExit`` (argparse's usage
    errors) gives its code as the exit status and a message on stderr, as the interpreter would."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(list(argv))
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if isinstance(exc.code, str):  # the interpreter prints such a message on stderr
                print(exc.code, file=err)
    return MainResult(0 if rc is None else int(rc), out.getvalue(), err.getvalue())
