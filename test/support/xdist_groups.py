"""Module groups for pytest-xdist's ``--dist loadgroup`` (make test: ``-n 2 --dist loadgroup``).

Under xdist's per-test distribution a module's tests are dealt to both workers, and each worker
builds the module's fixtures (a simulated flight, a dpos-process run) once more. A test that uses a
module-, class- or package-scoped fixture is put in its module's group, so that the module's tests
run on one worker and its fixtures are built once; the other tests are dealt one by one.
"""

from __future__ import annotations

from pathlib import Path

import pytest

#: fixture scopes that make a module's tests one group
GROUPED_SCOPES = ("module", "package", "class")


def group_module_fixture_tests(items: list[pytest.Item], root: Path) -> int:
    """Mark each item that uses a fixture of :data:`GROUPED_SCOPES` with ``xdist_group(<its module's
    path under root>)``; returns the number of items marked."""
    n = 0
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs.values() if info is not None else ()
        if any(d[-1].scope in GROUPED_SCOPES for d in defs if d):
            item.add_marker(pytest.mark.xdist_group(item.path.relative_to(root).as_posix()))
            n += 1
    return n


#: markers of a test that takes long (``slow``: more than about 10 s; ``ros``: nodes, DDS, real time)
HEAVY_MARKERS = ("xdist_group", "slow", "ros")


def heavy_first(items: list[pytest.Item]) -> None:
    """Sort ``items`` in place (stably) so that the grouped, ``slow`` and ``ros`` tests come first.

    xdist deals the work units in collection order as the workers free up: a long test dealt last
    keeps one worker busy while the other has nothing left (the run's tail). Dealt first, the long
    tests are balanced by the many short ones that follow (longest-processing-time-first)."""
    items.sort(key=lambda item: 0 if any(item.get_closest_marker(m) for m in HEAVY_MARKERS) else 1)
