"""Progress of the long commands on a terminal (dpos-process, dpos-import, dpos-campaign, dpos-sim):
stage lines and bars drawn by tqdm on stderr.

Silent when stderr is not a terminal (a log file, a pipe, a campaign's worker) and with the
commands' ``--quiet``: then nothing at all is written by this module, and the commands' results
(stdout) and warnings (stderr) are the same either way.

    st = Stages("dpos-process", quiet=args.quiet)
    st.stage("reading the recording")                 # "dpos-process: [0.1 s] reading the recording"
    with st.items("sub-IMU", 6) as bar:               # a bar of the 6 sub-IMUs
        bar.done("imu01", "estimated")                # "  sub-IMU imu01: estimated" above the bar, bar + 1
    Progress("writing")(done, total)                   # a bar of done / total (the bag writers' callback)
    with st.solving(6) as progress:                   # the bars of solve's ProductProgress (write: st.writing)
        solve(..., progress=progress)
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import TextIO

from tqdm import tqdm

from dpos_ros.products.progress import ProductProgress


def on_terminal(stream: TextIO, quiet: bool = False) -> bool:
    """Whether progress is shown on ``stream``: not ``quiet`` and ``stream`` is a terminal."""
    if quiet:
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # (no isatty, or a closed stream)
        return False


#: the terminal's columns and rows when it does not tell its own (a pseudo-terminal of 0 x 0, e.g.
#: under ``script``: tqdm would draw bars of no width, hidden below a screen of no rows)
DEFAULT_SIZE = (100, 24)


def screen(stream: TextIO) -> dict[str, int]:
    """tqdm's ``ncols`` and ``nrows`` of the terminal ``stream`` is on (:data:`DEFAULT_SIZE` for a 0 or unknown one)."""
    try:
        cols, rows = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):
        cols = rows = 0
    return {"ncols": cols if cols > 0 else DEFAULT_SIZE[0], "nrows": rows if rows > 0 else DEFAULT_SIZE[1]}


class Progress:
    """A bar of ``done`` / ``total`` (called as the writers' ``progress(done, total)``), made at the
    first call; closed when ``done`` reaches ``total`` (or by :meth:`close`)."""

    def __init__(self, label: str, stream: TextIO | None = None, enabled: bool | None = None) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = on_terminal(self.stream) if enabled is None else enabled
        self._bar: tqdm | None = None

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        if self._bar is None:
            self._bar = tqdm(total=total, desc=self.label, file=self.stream, leave=True, **screen(self.stream),
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]")
        self._bar.total = total
        self._bar.update(min(done, total) - self._bar.n)
        if done >= total:
            self.close()

    def close(self) -> None:
        """End the bar's line (a failure before it completed)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class Items:
    """A bar of ``total`` named items (sub-IMUs, antennas, recordings): :meth:`done` writes a line
    per item above the bar and advances it.  A context manager (closes the bar)."""

    def __init__(self, what: str, total: int, stream: TextIO, enabled: bool) -> None:
        self.what = what
        self.bar = tqdm(total=total, desc=what, unit=what, file=stream, leave=False, disable=not enabled,
                        **(screen(stream) if enabled else {}))

    def done(self, name: str, text: str = "done") -> None:
        """Item ``name`` finished (``text``: its outcome, one line)."""
        if not self.bar.disable:
            self.bar.write(f"  {self.what} {name}: {text}", file=self.bar.fp)
        self.bar.update(1)

    def advance(self) -> None:
        """An item finished, its line written elsewhere (e.g. the command's result line on stdout)."""
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> Items:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


class Stages:
    """The stages of a command (a line each, with the seconds since the command started) and its
    items (:meth:`items`), on ``stream`` (default stderr) when :func:`on_terminal`."""

    def __init__(self, prog: str, *, quiet: bool = False, stream: TextIO | None = None, enabled: bool | None = None) -> None:
        self.prog = prog
        self.stream = stream or sys.stderr
        self.enabled = on_terminal(self.stream, quiet) if enabled is None else enabled
        self.t0 = time.perf_counter()

    def stage(self, text: str) -> None:
        """A stage begins: ``<prog>: [<s> s] <text>``."""
        if self.enabled:
            tqdm.write(f"{self.prog}: [{time.perf_counter() - self.t0:.1f} s] {text}", file=self.stream)

    def items(self, what: str, total: int) -> Items:
        """A bar of ``total`` items called ``what`` (:class:`Items`)."""
        return Items(what, total, self.stream, self.enabled)

    def bar(self, label: str) -> Progress:
        """A bar of done / total (:class:`Progress`), shown as the stages are."""
        return Progress(label, self.stream, self.enabled)

    @contextmanager
    def _items_and_bar(self, what: str, total: int, label: str) -> Iterator[tuple[Items, Progress]]:
        """:meth:`items` of ``total`` ``what`` and a :meth:`bar` called ``label``, both closed on leaving."""
        with self.items(what, total) as items:
            bar = self.bar(label)
            try:
                yield items, bar
            finally:
                bar.close()

    @contextmanager
    def solving(self, n_sub_imus: int) -> Iterator[ProductProgress]:
        """:func:`dpos_ros.products.solve.solve`'s progress: a line and a bar step per sub-IMU (of
        ``n_sub_imus``), a bar of the wing fit's windows."""
        with self._items_and_bar("sub-IMU", n_sub_imus, "wing fit") as (items, fit):
            yield ProductProgress(sub_imu=items.done, fit_window=fit)

    @contextmanager
    def writing(self, n_antennas: int) -> Iterator[ProductProgress]:
        """:func:`dpos_ros.products.write.write`'s progress: a line and a bar step per antenna (of
        ``n_antennas``), a bar of the antenna bag's batches."""
        with self._items_and_bar("antenna", n_antennas, "antenna bag") as (items, bag):
            yield ProductProgress(antenna=items.done, bag=bag)

    def print(self, text: str) -> None:
        """A line on stdout (flushed) while a bar may be drawn on the terminal (the bar is redrawn below it)."""
        if self.enabled:
            tqdm.write(text, file=sys.stdout)
        else:
            print(text)
        sys.stdout.flush()
