"""Import direction: who may import whom (docs/design.md "Workspace layout").

- ``dpos_core`` imports no ROS (test_workspace.py) and its simulator ``dpos_core.sim`` is imported
  only by the simulator itself and its callers (the evaluation room ``dpos_core.evaluation``,
  simulated devices, the sim CLIs): estimation, configuration and real devices never depend on it.
- The estimation packages (``dpos_core.ta``, ``.ifa``, ``.sar``, ``.filters``) import neither the
  evaluation room nor each other's warm-ups; the simulator imports no estimation package.
- ``dpos_ros`` is built in rooms, each importing only the rooms below it:
  contract < runtime < io < devices, products < cli.
- Node packages import ``dpos_ros`` and ``dpos_core``, never each other; the shared library
  (``dpos_core``, ``dpos_ros``) imports no node package.

Imports are read from the sources (module level and inside functions), relative ones resolved.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from repo_paths import REPO

SRC = REPO / "src"
NODE_PACKAGES = ("pos_master_node", "pos_sub_node", "ifa_node", "transfer_align_node", "sar_nav_node")


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC).with_suffix("")
    parts = rel.parts[1:]  # src/<package>/<package>/...
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """module -> the dpos / node-package modules it imports (absolute names)."""
    graph: dict[str, set[str]] = {}
    for path in sorted(SRC.glob("*/*/**/*.py")):
        if "build" in path.parts:
            continue
        mod = _module_name(path)
        pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        out: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                out |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
                out.add(base)
                out |= {f"{base}.{a.name}" for a in node.names}  # `from pkg import module`
        graph[mod] = {m for m in out if m.split(".")[0] in ("dpos_core", "dpos_ros", *NODE_PACKAGES)}
    return graph


GRAPH = import_graph()


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _importers(prefix: str) -> set[str]:
    return {m for m, deps in GRAPH.items() if any(_within(d, prefix) for d in deps)}


def test_graph_is_read() -> None:
    assert {"dpos_core.sim.session", "dpos_ros.contract.topics", "pos_master_node.node"} <= set(GRAPH)
    assert "dpos_core.config" in GRAPH["dpos_core.sim.scenario"] or "dpos_core.config.aircraft" in GRAPH["dpos_core.sim.scenario"]


# The simulator's callers: the evaluation room (Monte Carlo on simulated sessions, every module of
# dpos_core.evaluation), the simulated devices and the commands that simulate.  Nothing else.
EVALUATION = "dpos_core.evaluation"
SIM_CALLERS = {
    "dpos_ros.devices.sim_device",
    "dpos_ros.devices.sim_streams",
    "dpos_ros.products.ifa",
    "dpos_ros.cli.sim",
    "dpos_ros.cli.evaluate",
    "dpos_ros.cli.campaign",
    "dpos_ros.cli.mismatch",
    "dpos_ros.cli.sar_eval",
    "dpos_ros.cli.plot_scenario",
}


def test_simulator_is_imported_only_by_its_callers() -> None:
    importers = {m for m in _importers("dpos_core.sim") if not _within(m, "dpos_core.sim") and not _within(m, EVALUATION)}
    assert {m for m in _importers("dpos_core.sim") if _within(m, EVALUATION)}, "the evaluation room simulates"
    assert importers <= SIM_CALLERS, f"modules that must not depend on the simulator: {sorted(importers - SIM_CALLERS)}"


@pytest.mark.parametrize("module", ["dpos_core.ta.model", "dpos_core.ta.pipeline", "dpos_core.ifa.model", "dpos_core.ifa.pipeline",
                                    "dpos_core.ifa.mechanization", "dpos_core.config", "dpos_core.filters.runners",
                                    "dpos_core.sar.model", "dpos_core.sar.pipeline", "dpos_core.filters.pf"])
def test_estimation_and_configuration_do_not_see_the_simulator(module: str) -> None:
    seen, todo = set(), [module]
    while todo:  # transitive closure over dpos_core
        m = todo.pop()
        if m in seen or m not in GRAPH:
            continue
        seen.add(m)
        todo += [d for d in GRAPH[m] if d.startswith("dpos_core")]
    assert not {m for m in seen if m.startswith("dpos_core.sim")}, f"{module} reaches the simulator through {sorted(seen)}"


ROOMS = ("contract", "runtime", "io", "devices", "products", "cli")
# room -> the rooms it may import (besides itself)
ALLOWED = {
    "contract": set(),
    "runtime": {"contract"},
    "io": {"contract", "runtime"},
    "devices": {"contract", "runtime", "io"},
    "products": {"contract", "runtime", "io"},
    "cli": {"contract", "runtime", "io", "devices", "products"},
}


def _room(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "dpos_ros" and len(parts) > 1 and parts[1] in ROOMS else None


def test_dpos_ros_rooms_import_downwards() -> None:
    bad = []
    for mod, deps in GRAPH.items():
        room = _room(mod)
        if room is None:
            continue
        for d in deps:
            other = _room(d)
            if other is not None and other != room and other not in ALLOWED[room]:
                bad.append(f"{mod} imports {d} ({room} -> {other})")
    assert not bad, "\n".join(bad)


def test_every_dpos_ros_module_is_in_a_room() -> None:
    loose = [m for m in GRAPH if m.startswith("dpos_ros.") and _room(m) is None and m != "dpos_ros"]
    assert not loose, f"modules outside contract/runtime/io/devices/products/cli: {loose}"


def test_node_packages_do_not_import_each_other() -> None:
    bad = [f"{m} imports {d}" for m, deps in GRAPH.items() for d in deps
           if m.split(".")[0] in NODE_PACKAGES and d.split(".")[0] in NODE_PACKAGES and d.split(".")[0] != m.split(".")[0]]
    assert not bad, bad


def test_core_imports_no_dpos_ros_or_node() -> None:
    bad = [f"{m} imports {d}" for m, deps in GRAPH.items() if m.startswith("dpos_core") for d in deps if not d.startswith("dpos_core")]
    assert not bad, bad


def test_shared_library_imports_no_node_package() -> None:
    """dpos_core and dpos_ros sit below the node packages: a shared module that needs a node's
    configuration is given it by the node package (e.g. ``dpos-ifa``: ifa_node.offline)."""
    bad = [f"{m} imports {d}" for m, deps in GRAPH.items() if m.split(".")[0] in ("dpos_core", "dpos_ros")
           for d in deps if d.split(".")[0] in NODE_PACKAGES]
    assert not bad, bad


# ----------------------------------------------------------------------------- the evaluation room

ESTIMATION = ("dpos_core.ta", "dpos_core.ifa", "dpos_core.sar", "dpos_core.filters")


def test_estimation_packages_import_no_evaluation_and_no_other_warm_up() -> None:
    bad = []
    for m, deps in GRAPH.items():
        own = next((p for p in ESTIMATION if _within(m, p)), None)
        if own is None:
            continue
        for d in deps:
            if _within(d, EVALUATION) or _within(d, "dpos_core.sim"):
                bad.append(f"{m} imports {d} (evaluation / simulator)")
            other = next((p for p in ESTIMATION if _within(d, p)), None)
            if other is not None and other != own and _within(d, other + ".warmup"):
                bad.append(f"{m} imports {d} (another estimation package's warm-up)")
    assert not bad, "\n".join(bad)


def test_simulator_imports_no_estimation_and_no_evaluation() -> None:
    bad = [f"{m} imports {d}" for m, deps in GRAPH.items() if _within(m, "dpos_core.sim")
           for d in deps if any(_within(d, p) for p in (*ESTIMATION, EVALUATION))]
    assert not bad, bad
