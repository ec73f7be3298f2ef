"""What every command line of dpos shares: validated option types and the top-level handler that
turns an expected failure into one line and a non-zero exit status.

Option types (for ``add_argument(type=...)``): argparse reports a bad value as
``prog: error: argument --x: <why>`` with exit status 2, before anything runs::

    ap.add_argument("--start", type=finite_float)                     # no nan, no inf
    ap.add_argument("--filter-rate", type=float_in(0.0, 1000.0, lo_open=True))
    ap.add_argument("--particles", type=int_in(1, MAX_PARTICLES))     # bounds the allocation

Top-level handler: :func:`one_line_errors` wraps a ``main`` so that the errors the product raises
on purpose (:class:`dpos_core.errors.DposError`), an ``OSError`` (a full disk: ENOSPC, EACCES,
EROFS, EIO, ...) and a ``MemoryError`` (an allocation the machine cannot make) end with
``prog: error: <one line>`` and exit status 2.  Anything else is a bug and keeps its traceback
(no bare ``except Exception``).
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from collections.abc import Callable
from typing import Any, TypeVar

from dpos_core.errors import DposError
from dpos_ros.io.outdir import os_error_text

__all__ = ["EXIT_ERROR", "MAX_PARTICLES", "MAX_RATE_HZ", "finite_float", "float_in", "int_in", "one_line", "one_line_errors"]

EXIT_ERROR = 2
#: the most particles a command accepts: a particle filter's arrays grow with them
MAX_PARTICLES = 100_000
#: the highest filter / output rate [Hz] a command accepts: no IMU of the product is faster, and the
#: epochs allocated grow with the rate times the flight's length
MAX_RATE_HZ = 1000.0
F = TypeVar("F", bound=Callable[..., Any])


def finite_float(text: str) -> float:
    """A finite float (argparse type): ``nan``, ``inf`` and non-numbers are refused."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return v


def float_in(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
             unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite float in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``; a ``None``
    bound is no bound), ``unit`` (e.g. ``" Hz"``) in its message."""

    def parse(text: str) -> float:
        v = finite_float(text)
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise argparse.ArgumentTypeError(f"must be {'>' if lo_open else '>='} {lo:g}{unit}, got {text}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be <= {hi:g}{unit}, got {text}")
        return v

    parse.__name__ = "number"  # argparse names the type in "invalid <name> value"
    return parse


def int_in(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer in ``[lo, hi]`` (a ``None`` bound is no bound); the upper bound
    keeps an allocation sized by the option within what the machine can hold."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if lo is not None and v < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be <= {hi}, got {v}")
        return v

    parse.__name__ = "integer"
    return parse


def one_line(exc: BaseException) -> str:
    """The message of an expected failure as one line (an OSError as ``file: reason (ERRNO)``)."""
    if isinstance(exc, OSError):
        text = os_error_text(exc)
    elif isinstance(exc, MemoryError):
        text = f"out of memory ({exc or 'an allocation the machine cannot make'}): use smaller settings"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def one_line_errors(prog: str) -> Callable[[F], F]:
    """Decorator of a command's ``main``: a :class:`DposError`, an ``OSError`` or a ``MemoryError``
    escaping it is printed as ``prog: error: <one line>`` on stderr and ``main`` returns
    :data:`EXIT_ERROR` (module docstring).  Other exceptions propagate (bugs keep their traceback)."""

    def deco(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            try:
                return fn(*args, **kwargs)
            except (DposError, OSError, MemoryError) as exc:
                print(f"{prog}: error: {one_line(exc)}", file=sys.stderr, flush=True)
                return EXIT_ERROR

        return wrapper  # type: ignore[return-value]

    return deco
