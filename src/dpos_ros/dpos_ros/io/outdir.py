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

Names never become paths unchecked: a session id (from a bag's metadata, a spill, any
``/session/end`` publisher) becomes a directory name only through :func:`safe_name`, and a
directory is made from it only through :func:`child_dir`, which resolves it and checks that it is
directly under its root.  A products directory carries the marker :data:`PRODUCTS_MARKER`
(:func:`mark_products`); ``--overwrite`` replaces only a directory that :func:`is_products_dir`
recognises as dpos's own.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from dpos_core.errors import OutputError

__all__ = ["OutputError", "OutputTarget", "PRODUCTS_MARKER", "atomic_path", "child_dir", "is_products_dir", "mark_products",
           "os_error_text", "probe_writable", "safe_name"]

#: longest name :func:`safe_name` returns [characters]
MAX_NAME_CHARS = 120
#: the file that marks a directory as dpos's products (written first, by :func:`mark_products`)
PRODUCTS_MARKER = ".dpos-products"
_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def safe_name(raw: object, default: str = "session") -> str:
    """``raw`` (a session id from a recording, a spill or a ``/session/end`` message) as one safe
    directory name: every run of characters other than letters, digits and ``. _ + -`` (path
    separators, ``..``, spaces, quotes, control characters) becomes ``_``; leading dots, dashes
    and ``_`` are dropped (no ``.``/``..``, no hidden or option-like name: ``../../x`` is ``x``); at most
    :data:`MAX_NAME_CHARS` characters; ``default`` when nothing is left.  The same name is
    returned for a name that is already safe (``safe_name(safe_name(x)) == safe_name(x)``)."""
    name = _UNSAFE.sub("_", str(raw)).lstrip("._-")[:MAX_NAME_CHARS].rstrip(".")
    return name if name and name.strip("_") else default


def child_dir(root: Path, name: str) -> Path:
    """``root/name`` after checking that it stays directly under ``root``: ``name`` must be a
    :func:`safe_name` and the resolved path (symbolic links followed) must have the resolved
    ``root`` as its parent; :class:`OutputError` otherwise.  Returns ``root / name`` (unresolved)."""
    root = Path(root)
    if name != safe_name(name):
        raise OutputError(f"{name!r} is not a safe directory name (under {root})")
    resolved_root = root.resolve()
    if (root / name).resolve().parent != resolved_root:
        raise OutputError(f"{root / name} resolves outside {resolved_root} (a symbolic link?): not writing there")
    return root / name


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write the whole file into; renamed to ``path`` when the
    block ends without an exception, removed when it raises (a full disk leaves no partial file)::

        with atomic_path(out / "nav.csv") as tmp:
            np.savetxt(tmp, rows)
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if exc.filename is None:  # (a write through a library names no file): name the one meant
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def mark_products(path: Path, what: str = "products") -> None:
    """Write the marker :data:`PRODUCTS_MARKER` into the new directory ``path``."""
    (Path(path) / PRODUCTS_MARKER).write_text(json.dumps({"dpos": what}) + "\n")


def is_products_dir(path: Path) -> bool:
    """True when ``path`` is a real directory (no symbolic link) that dpos wrote: it holds
    :data:`PRODUCTS_MARKER`, or (products of versions before the marker) a ``status.json`` that is a
    JSON object with a ``session_id``."""
    path = Path(path)
    if path.is_symlink() or not path.is_dir():
        return False
    if (path / PRODUCTS_MARKER).is_file():
        return True
    try:
        doc = json.loads((path / "status.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and "session_id" in doc


def os_error_text(exc: OSError, path: Path | str | None = None) -> str:
    """``<file>: <errno text> (<ERRNO>)``: one line for an OSError (the file it names, else ``path``)."""
    where = exc.filename if exc.filename is not None else path
    text = exc.strerror or str(exc) or type(exc).__name__
    code = errno.errorcode.get(exc.errno, "") if exc.errno is not None else ""
    return (f"{where}: " if where is not None else "") + text + (f" ({code})" if code else "")


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
