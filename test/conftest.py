"""Session-wide test setup: a dedicated ROS 2 domain, an rclpy Context and an executor.

The ROS environment is set at import time, before any test imports rclpy, and exported in
os.environ so that node subprocesses inherit it:

- ROS_DOMAIN_ID: one per test session, one per pytest-xdist worker (1..100, from the pid; never 0,
  the default domain), so concurrent sessions on one machine do not see each other's nodes. Set
  DPOS_TEST_ROS_DOMAIN_ID to force a value.
- RMW_IMPLEMENTATION=rmw_fastrtps_cpp (the middleware of the wheels).
- DPOS_WORKERS=1 unless set: ``workers: 0`` (one per core) starts one worker process.
- ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set: discovery stays on this machine.
- DPOS_FIGURES=off unless set: the products are written without their PNG figures (about a second
  of CPU each, two per antenna and run); the tests of the figures ask for them (``--figures on`` or
  the ``figures_on`` fixture).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from xdist_groups import group_module_fixture_tests, heavy_first


def _pick_domain_id() -> int:
    """1..100: from this process's pid, or under pytest-xdist from the controller's pid and the
    worker's index, so that the workers of one run never share a domain."""
    forced = os.environ.get("DPOS_TEST_ROS_DOMAIN_ID")
    if forced:
        return int(forced)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw"):
        n_workers = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
        slots = max(1, 100 // n_workers)
        return (os.getppid() % slots) * n_workers + int(worker[2:]) % n_workers + 1
    return os.getpid() % 100 + 1


ROS_DOMAIN_ID = _pick_domain_id()
# "one worker process per core" means one in the tests (the tests run two at a time on two cores;
# the results do not depend on it): the tests of the pools ask for their workers explicitly
os.environ.setdefault("DPOS_WORKERS", "1")
os.environ["ROS_DOMAIN_ID"] = str(ROS_DOMAIN_ID)
os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("DPOS_FIGURES", "off")


@pytest.fixture
def figures_on(monkeypatch: pytest.MonkeyPatch) -> None:
    """The products of this test with their figures ($DPOS_FIGURES=on, also for the processes it starts)."""
    monkeypatch.setenv("DPOS_FIGURES", "on")


_NODES_DIR = Path(__file__).parent / "nodes"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--cpu-burner", type=int, default=0, metavar="N",
        help="run N CPU-bound processes beside the tests for the whole session (make stress: 1); "
             "they are stopped at the end of the session and exit by themselves if pytest dies",
    )


_BURNERS_KEY = pytest.StashKey[list]()


@pytest.hookimpl(trylast=True)
def pytest_configure(config: pytest.Config) -> None:
    n = config.getoption("--cpu-burner", default=0) or 0
    if n < 0:
        raise pytest.UsageError("--cpu-burner must be >= 0")
    # under pytest-xdist only the controller starts burners (the workers would each start their own)
    if n and not hasattr(config, "workerinput"):
        from cpu_burner import start_burners

        config.stash[_BURNERS_KEY] = start_burners(n)


def pytest_unconfigure(config: pytest.Config) -> None:
    burners = config.stash.get(_BURNERS_KEY, None)
    if burners:
        from cpu_burner import stop_burners

        stop_burners(burners)


def pytest_report_header(config: pytest.Config) -> str | None:
    burners = config.stash.get(_BURNERS_KEY, None)
    if not burners:
        return None
    from cpu_burner import read_loadavg

    return f"cpu burners: {len(burners)} (pids {' '.join(str(p.pid) for p in burners)}); loadavg {read_loadavg()}"


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    if config.stash.get(_BURNERS_KEY, None):
        from cpu_burner import read_loadavg

        terminalreporter.write_line(f"cpu burners: {len(config.stash[_BURNERS_KEY])}; loadavg at the end {read_loadavg()}")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test under test/nodes/ starts nodes or uses DDS: marked ``ros`` even where its module
    does not say so (``make stress`` runs the ``ros`` tests beside a CPU burner; ``-m "not ros"`` leaves them out)."""
    for item in items:
        if _NODES_DIR in item.path.parents:
            item.add_marker(pytest.mark.ros)
    # make test runs ``-n 2 --dist loadgroup``: a module's tests that share a module fixture on one worker
    group_module_fixture_tests(items, Path(__file__).parent)
    heavy_first(items)  # the long tests dealt first: no long test left for the run's tail


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """The ROS_DOMAIN_ID of this test session (also in os.environ)."""
    return ROS_DOMAIN_ID


@pytest.fixture
def ros_context(ros_domain_id: int) -> Iterator[Any]:
    """An initialised rclpy Context on the session's domain, shut down after the test.

    rclpy's signal handlers are not installed, so Ctrl-C still reaches pytest.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(context=context, domain_id=ros_domain_id, signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def ros_executor(ros_context: Any) -> Iterator[Any]:
    """A SingleThreadedExecutor on ``ros_context``; shut down after the test."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=ros_context)
    try:
        yield executor
    finally:
        executor.shutdown(timeout_sec=5.0)


# the node-process fixture of the tests that start nodes as console scripts (test/support/node_process.py)
from node_process import start_node  # noqa: E402,F401
