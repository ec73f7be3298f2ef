"""Output directories of the command-line tools: writability checked up front, disk faults
reported in one line, and only what the tool itself created removed after a fault.

    target = OutputTarget(args.out)      # before any work: raises OutputError when it cannot be written
    try:
        write_everything(args.out)
    except OSError as exc:
        print(f"prog: error: {target.fault(exc)}", file=sys.stderr)   # removes what this run created
        return 2

:class:`OutputTarget` remembers which of the directory's ancestors did not exist, so that after a
fault it removes the output directory when this run created it and those ancestors when they are
empty - never anything that existed before.
"""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from dpos_core.errors import OutputError

__all__ = ["OutputError", "OutputTarget", "os_error_text", "probe_writable"]


def os_error_text(exc: OSError, path: Path | str | None = None) -> str:
    """``<file>: <errno text> (<ERRNO>)``: one line for an OSError (the file it names, else ``path``)."""
    where = exc.filename if exc.filename is not None else path
    text = exc.strerror or str(exc) or type(exc).__name__
    code = errno.errorcode.get(exc.errno, "") if exc.errno is not None else ""
    return f"{where}: {text}" + (f" ({code})" if code else "")


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def probe_writable(path: Path) -> None:
    """Raise :class:`OutputError` unless ``path`` (a directory that may not exist yet) can be written:
    its nearest existing ancestor must be a directory in which a file can be created. A real file
    is created and removed (``os.access`` is not enough: root, read-only mounts, ACLs)."""
    path = Path(path)
    base = _existing_ancestor(path)
    if not base.is_dir():
        raise OutputError(f"{path}: {base} is not a directory")
    probe = base / f".dpos-write-probe-{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write in {base}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(probe)


class OutputTarget:
    """The output directory ``path`` of one run (module docstring); checked at construction."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        probe_writable(self.path)
        self.existed = self.path.exists()
        missing = []
        p = self.path.absolute().parent
        while not p.exists() and p != p.parent:
            missing.append(p)
            p = p.parent
        #: ancestors this run would create, deepest first
        self.missing_ancestors = missing

    def cleanup(self) -> list[Path]:
        """Remove what this run created: the directory (when it did not exist before) and the
        ancestors it created that are empty. Returns what was removed."""
        removed = []
        if not self.existed and self.path.exists():
            shutil.rmtree(self.path, ignore_errors=True)
            if not self.path.exists():
                removed.append(self.path)
        for p in self.missing_ancestors:
            try:
                p.rmdir()  # only when empty
            except OSError:
                break
            removed.append(p)
        return removed

    def fault(self, exc: OSError) -> str:
        """Clean up (:meth:`cleanup`) and return the one-line message of a write fault."""
        removed = self.cleanup()
        text = f"writing {self.path} failed: {os_error_text(exc, self.path)}"
        if removed:
            text += f"; removed the partial output {removed[0]}"
        return text
