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
- No import cycle between modules.
- Imports are at the top of the module: inside a function only the heavy or optional packages of
  :data:`LAZY_IMPORTS`, each with its reason.

Imports are read from the sources (module level and inside functions), relative ones resolved.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
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
# dpos_core.evaluation), the simulated devices' sessions and streams and the commands that simulate.
# Nothing else: not the stream publisher (dpos_ros.devices.sim_device), which transfer_align_node uses
# for its antenna poses and which would load the simulator (scipy.interpolate, ~0.7 s of CPU) into it.
EVALUATION = "dpos_core.evaluation"
SIM_CALLERS = {
    "dpos_ros.devices.sim_session",
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


# ----------------------------------------------------------------------------- cycles

def import_cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    edges = {m: sorted(d for d in deps if d in graph and d != m) for m, deps in graph.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[set[str]] = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = len(index)
                stack.append(v)
                on_stack.add(v)
            if i < len(edges[v]):
                work.append((v, i + 1))
                w = edges[v][i]
                if w not in index:
                    work.append((w, 0))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(comp)
            for u, _ in work[-1:]:
                low[u] = min(low[u], low[v])
    return out


def test_cycle_finder_finds_a_cycle() -> None:
    cycles = import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d"}})
    assert cycles == [{"a", "b", "c"}]
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycles() -> None:
    cycles = [sorted(c) for c in import_cycles(GRAPH)]
    assert not cycles, f"import cycles: {cycles}"


# ----------------------------------------------------------------------------- imports at the top

#: the packages a function may import (top-level name -> why it is not imported at the top);
#: ROS message packages (``*_msgs``) count as ``rclpy``
LAZY_IMPORTS = {
    "matplotlib": "only the plots use it, and it takes seconds to import",
    "dask": "optional extra dpos_ros[campaign], needed by dpos-campaign only",
    "distributed": "optional extra dpos_ros[campaign], needed by dpos-campaign only",
    "rclpy": "the offline path (dpos-process, its workers, dpos-import, dpos-sar) shares these modules "
             "with the nodes and runs without loading the ROS client library (test_offline_path_loads_no_ros)",
    "rcl_interfaces": "as rclpy",
    "rosidl_runtime_py": "optional: topics.message_class falls back to importing the message module",
}


def _lazy_allowed(module: str) -> bool:
    top = module.split(".")[0]
    return top in LAZY_IMPORTS or top.endswith("_msgs")


@functools.cache
def imports_in_functions() -> dict[str, list[str]]:
    """file (relative to src/) -> ``line: module`` of each import inside a function (absolute module
    names, relative ones resolved)."""
    out: dict[str, list[str]] = {}
    for path in sorted(SRC.glob("*/*/**/*.py")):
        if "build" in path.parts:
            continue
        mod = _module_name(path)
        pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        found: list[str] = []
        stack: list[tuple[ast.AST, bool]] = [(ast.parse(path.read_text(), filename=str(path)), False)]
        while stack:  # each node once; `inside`: the node is in a function's body
            node, inside = stack.pop()
            names: list[str] = []
            if inside and isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif inside and isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
                names = [base]
            found += [f"{node.lineno}: {n}" for n in names if f"{node.lineno}: {n}" not in found]  # type: ignore[attr-defined]
            inner = inside or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
            stack += [(child, inner) for child in ast.iter_child_nodes(node)]
        if found:
            out[str(path.relative_to(SRC))] = sorted(found, key=lambda x: int(x.split(":")[0]))
    return out


def test_in_function_import_scan_sees_them() -> None:
    found = imports_in_functions()
    assert any("matplotlib" in x for x in found.get("dpos_core/dpos_core/demo.py", [])), found.keys()


def test_imports_are_at_the_top() -> None:
    bad = {f: [x for x in lines if not _lazy_allowed(x.split(": ")[1])] for f, lines in imports_in_functions().items()}
    bad = {f: lines for f, lines in bad.items() if lines}
    assert not bad, f"imports inside functions (move them to the top, or add the package to LAZY_IMPORTS with its reason): {bad}"


def test_offline_path_loads_no_ros() -> None:
    """What LAZY_IMPORTS says of rclpy: the offline commands import no ROS client library or message package."""
    code = ("import sys\nimport dpos_ros.cli.process, dpos_ros.cli.import_, dpos_ros.cli.sar\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces') or m.split('.')[0].endswith('_msgs')))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240, check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "[]"
