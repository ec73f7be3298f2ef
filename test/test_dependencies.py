"""Every package declares what it imports.

Each ``src/<pkg>/package.xml`` lists as ``exec_depend`` the rosdep key of every library its Python
sources import (module level and inside functions), the ROS packages and the workspace's other
packages, and nothing else; its ``setup.py`` ``install_requires`` lists the PyPI distributions of
the non-ROS libraries (``setuptools`` besides), ``extras_require`` those of its optional imports.
An import is optional when it sits in a ``try:`` whose handler catches ``ImportError``; it must be
an ``exec_depend`` or in an extra (or, with a reason, in :data:`OPTIONAL_FALLBACK`).

The rosdep keys are those of rosdistro's ``rosdep/python.yaml`` where it has one; the libraries it
lacks take the ``-pip`` key convention, defined in ``tools/rosdep.yaml`` (a rosdep source for a
colcon user). The lock files must cover the runtime: requirements.in (wheel route) and
requirements-noros.in (apt-ROS route) name every distribution of :data:`LIBRARIES`; the dev tools
are in requirements-dev.in only.

Also: dpos-campaign without its optional extra (dask/distributed) fails in one line naming it.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml
from repo_paths import REPO

SRC = REPO / "src"
PACKAGES = ["dpos_core", "dpos_ros", "pos_master_node", "pos_sub_node", "ifa_node", "transfer_align_node", "sar_nav_node"]

#: import name -> (rosdep key, PyPI distribution) of the third-party non-ROS libraries
LIBRARIES: dict[str, tuple[str, str]] = {
    "numpy": ("python3-numpy", "numpy"),
    "scipy": ("python3-scipy", "scipy"),
    "numba": ("python3-numba", "numba"),
    "yaml": ("python3-yaml", "pyyaml"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "ruamel": ("python3-ruamel.yaml", "ruamel.yaml"),
    "tqdm": ("python3-tqdm", "tqdm"),
    # not in rosdistro's python.yaml: pip keys, tools/rosdep.yaml
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "zstandard": ("python3-zstandard-pip", "zstandard"),
    "lz4": ("python3-lz4-pip", "lz4"),
    "distributed": ("python3-distributed-pip", "distributed"),
    "dask": ("python3-dask-pip", "dask"),  # (campaign extra: dask.config for the local cluster)
}
#: ROS packages (rosdep key = package name); from the ros-jazzy wheels or apt, never in install_requires
ROS_PACKAGES = {
    "rclpy", "rcl_interfaces", "rosidl_runtime_py", "builtin_interfaces", "diagnostic_msgs", "geometry_msgs",
    "nav_msgs", "rosgraph_msgs", "sensor_msgs", "std_msgs", "std_srvs",
}
#: optional imports with a fallback in the code, declared nowhere: (package, import) -> reason
OPTIONAL_FALLBACK = {
    ("dpos_ros", "rosidl_runtime_py"): "contract.topics.message_class imports the message module itself without it",
}
#: the dev tools: in requirements-dev.in, not in the runtime locks' inputs
DEV_TOOLS = {"pytest", "pytest-timeout", "pytest-xdist", "ruff", "mypy", "types-pyyaml", "mcap"}  # (mcap: the tests' reference MCAP reader)
#: the optional extras' distributions
EXTRAS = {"campaign": {"dask", "distributed", "cryptography"}, "plot": {"matplotlib"}}


def canonical(name: str) -> str:
    """A distribution name as pip compares them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


@dataclass
class Imports:
    """The top-level names a package's sources import: ``required`` anywhere, ``optional`` only
    inside a ``try`` that catches ImportError; ``where`` one file:line per name."""

    required: set[str] = field(default_factory=set)
    optional: set[str] = field(default_factory=set)
    where: dict[str, str] = field(default_factory=dict)


def _catches_import_error(handler: ast.ExceptHandler) -> bool:
    types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(isinstance(t, ast.Name) and t.id in ("ImportError", "ModuleNotFoundError") for t in types)


def _walk(node: ast.AST, guarded: bool, out: list[tuple[str, int, bool]]) -> None:
    if isinstance(node, ast.Import):
        out += [(a.name.split(".")[0], node.lineno, guarded) for a in node.names]
    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
        out.append((node.module.split(".")[0], node.lineno, guarded))
    if isinstance(node, ast.Try):
        body_guarded = guarded or any(_catches_import_error(h) for h in node.handlers)
        for child in node.body:
            _walk(child, body_guarded, out)
        for child in [*node.handlers, *node.orelse, *node.finalbody]:
            _walk(child, guarded, out)
        return
    for child in ast.iter_child_nodes(node):
        _walk(child, guarded, out)


def package_imports(package: str) -> Imports:
    """The third-party, ROS and workspace imports of ``src/<package>/<package>/**.py`` (the
    standard library, ``sys.stdlib_module_names``, and the package itself left out)."""
    found = Imports()
    files = sorted((SRC / package / package).rglob("*.py"))
    assert files, package
    for path in files:
        hits: list[tuple[str, int, bool]] = []
        _walk(ast.parse(path.read_text(), filename=str(path)), False, hits)
        for name, line, guarded in hits:
            if name in sys.stdlib_module_names or name in ("__future__", package):
                continue
            found.where.setdefault(name, f"{path.relative_to(REPO)}:{line}")
            (found.optional if guarded else found.required).add(name)
    found.optional -= found.required
    return found


def exec_depends(package: str) -> list[str]:
    root = ET.parse(SRC / package / "package.xml").getroot()
    return [e.text or "" for e in root.findall("exec_depend")]


def setup_kwargs(package: str) -> dict:
    """The literal ``install_requires`` and ``extras_require`` of the package's ``setup(...)``."""
    tree = ast.parse((SRC / package / "setup.py").read_text())
    (call,) = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "setup"]
    kw = {k.arg: ast.literal_eval(k.value) for k in call.keywords if k.arg in ("install_requires", "extras_require")}
    return {"install_requires": kw.get("install_requires", []), "extras_require": kw.get("extras_require", {})}


def rosdep_key(name: str, package: str) -> str:
    """The rosdep key of imported top-level ``name``; fails on a name nobody mapped."""
    if name in PACKAGES or name in ROS_PACKAGES:
        return name
    assert name in LIBRARIES, (f"{package} imports {name!r} ({package_imports(package).where[name]}), which "
                               "test_dependencies.py does not know: add it to LIBRARIES (rosdep key, PyPI name) "
                               "or ROS_PACKAGES, and declare it")
    return LIBRARIES[name][0]


def requirement_names(path: Path) -> set[str]:
    """The distributions named by a requirements file (its ``-c``/``-r`` lines not followed)."""
    names = set()
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            names.add(canonical(re.split(r"[<>=!~;\[ ]", line, maxsplit=1)[0]))
    return names


def lock_pins(path: Path) -> dict[str, str]:
    return {canonical(n): v for n, _, v in (ln.partition("==") for ln in path.read_text().splitlines()
                                            if ln and not ln.startswith("#"))}


@pytest.mark.parametrize("package", PACKAGES)
def test_package_xml_declares_what_the_package_imports(package):
    imports = package_imports(package)
    declared = exec_depends(package)
    assert len(declared) == len(set(declared)), f"{package}/package.xml: an exec_depend twice: {declared}"
    needed = {rosdep_key(n, package): n for n in imports.required}
    extras = set().union(*map(set, setup_kwargs(package)["extras_require"].values()))
    for name in imports.optional:
        if (package, name) in OPTIONAL_FALLBACK:
            continue
        key = rosdep_key(name, package)
        if key not in declared:
            assert name in LIBRARIES and canonical(LIBRARIES[name][1]) in map(canonical, extras), (
                f"{package}: optional import {name!r} ({imports.where[name]}) is neither an exec_depend nor in an "
                "extras_require of setup.py")
    missing = {k: imports.where[n] for k, n in needed.items() if k not in declared}
    assert not missing, f"src/{package}/package.xml lacks <exec_depend> for: {missing}"
    unused = set(declared) - set(needed) - {rosdep_key(n, package) for n in imports.optional}
    assert not unused, f"src/{package}/package.xml declares exec_depends its sources do not import: {sorted(unused)}"


@pytest.mark.parametrize("package", PACKAGES)
def test_setup_py_requires_the_libraries_the_package_imports(package):
    imports = package_imports(package)
    kw = setup_kwargs(package)
    required = {canonical(LIBRARIES[n][1]) for n in imports.required if n in LIBRARIES}
    assert set(map(canonical, kw["install_requires"])) == required | {"setuptools"}, (
        f"src/{package}/setup.py install_requires must be setuptools + the PyPI names of its imports {sorted(required)}")
    optional = {canonical(LIBRARIES[n][1]) for n in imports.optional if n in LIBRARIES} - required
    extras = set().union(*map(set, kw["extras_require"].values()))
    assert optional <= set(map(canonical, extras)), f"{package}: optional imports {optional} not in extras_require {extras}"
    for extra, dists in kw["extras_require"].items():
        assert set(map(canonical, dists)) == EXTRAS.get(extra, set()), f"{package}[{extra}]: {dists}"


def test_dependency_check_fails_on_an_undeclared_import(tmp_path, monkeypatch):
    """The checks above see an import that package.xml lacks, inside a function too, and one
    that nobody mapped."""
    pkg = tmp_path / "src" / "dpos_core"
    (pkg / "dpos_core").mkdir(parents=True)
    (pkg / "dpos_core" / "a.py").write_text("import numpy\n\ndef f():\n    import scipy.linalg\n    return scipy\n")
    (pkg / "package.xml").write_text('<package format="3"><name>dpos_core</name>'
                                     "<exec_depend>python3-numpy</exec_depend></package>")
    (pkg / "setup.py").write_text("setup(install_requires=['setuptools', 'numpy'])\n")
    monkeypatch.setattr(sys.modules[__name__], "SRC", tmp_path / "src")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    assert package_imports("dpos_core").required == {"numpy", "scipy"}
    with pytest.raises(AssertionError, match="lacks <exec_depend> for.*python3-scipy"):
        test_package_xml_declares_what_the_package_imports("dpos_core")
    with pytest.raises(AssertionError, match="install_requires"):
        test_setup_py_requires_the_libraries_the_package_imports("dpos_core")
    (pkg / "dpos_core" / "b.py").write_text("try:\n    import shiny_new_lib\nexcept ImportError:\n    pass\n")
    assert "shiny_new_lib" in package_imports("dpos_core").optional
    with pytest.raises(AssertionError, match="does not know"):
        rosdep_key("shiny_new_lib", "dpos_core")


def test_workspace_dependencies_point_down():
    """The workspace packages' exec_depends on each other: dpos_ros on dpos_core only, the node
    packages on those two, never on each other (no cycle, no upward arrow)."""
    for package in PACKAGES:
        own = [d for d in exec_depends(package) if d in PACKAGES]
        allowed = {"dpos_core": [], "dpos_ros": ["dpos_core"]}.get(package, ["dpos_core", "dpos_ros"])
        assert own == allowed, f"{package} depends on {own}, expected {allowed}"


def test_pip_only_rosdep_keys_are_defined():
    """The ``-pip`` keys the packages use are defined in tools/rosdep.yaml, each a pip package."""
    used = {k for p in PACKAGES for k in exec_depends(p) if k.endswith("-pip")}
    rules = yaml.safe_load((REPO / "tools" / "rosdep.yaml").read_text())
    assert used <= set(rules), f"tools/rosdep.yaml lacks {used - set(rules)}"
    pip_names = {canonical(dist) for key, dist in LIBRARIES.values() if key.endswith("-pip")}
    for key, rule in rules.items():
        assert key.endswith("-pip")
        for os_rule in rule.values():
            assert [canonical(p) for p in os_rule["pip"]["packages"]][0] in pip_names, key


def test_requirement_files_cover_the_runtime_and_keep_the_dev_tools_apart():
    runtime = {canonical(d) for d in (dist for _, dist in LIBRARIES.values())} - EXTRAS["campaign"]
    wheel_route = requirement_names(REPO / "requirements.in")
    apt_route = requirement_names(REPO / "requirements-noros.in") | requirement_names(REPO / "requirements-dev.in")
    dev = requirement_names(REPO / "requirements-dev.in")
    assert runtime <= wheel_route, f"requirements.in lacks {runtime - wheel_route}"
    assert not (DEV_TOOLS | EXTRAS["campaign"]) & wheel_route, "the runtime requirements name dev tools or the campaign extra"
    assert DEV_TOOLS | EXTRAS["campaign"] <= dev, f"requirements-dev.in lacks {(DEV_TOOLS | EXTRAS['campaign']) - dev}"
    # the apt-ROS route: the wheel route's runtime without the ROS wheels, the dev tools and the extra
    assert {n for n in wheel_route if not n.startswith("ros-")} | dev <= apt_route
    assert "-r requirements-dev.in" in (REPO / "requirements-noros.in").read_text()
    assert not any(n.startswith("ros-") for n in apt_route)
    # the locks pin every input, with the same versions in all three
    lock, dev_lock, noros_lock = (lock_pins(REPO / f) for f in ("requirements.txt", "requirements-dev.txt", "requirements-noros.txt"))
    assert wheel_route <= set(lock) and dev <= set(dev_lock) and apt_route <= set(noros_lock)
    assert not set(lock) & set(dev_lock), "requirements-dev.txt repeats pins of requirements.txt"
    both = {**lock, **dev_lock}
    assert {n: v for n, v in noros_lock.items() if both.get(n) != v} == {}


BLOCK_ENGINE = """
import sys

class _NoEngine:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('dask', 'distributed'):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, _NoEngine())
from dpos_ros.cli import campaign
sys.exit(campaign.main(sys.argv[1:]))
"""


def test_campaign_without_its_extra_names_it_in_one_line(tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", BLOCK_ENGINE, "eval", "--scenario", "paper_su", "--runs", "1", "--out", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines() == [
        "dpos-campaign: error: the Dask engine is not installed (no module 'distributed'): pip install 'dpos_ros[campaign]'"]
    assert result.stdout == "" and not out.exists()
    # --help needs no engine
    result = subprocess.run(cmd[:3] + ["--help"], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0 and "process" in result.stdout, result.stderr


def test_campaign_engine_is_installed_in_the_dev_environment():
    from dpos_ros.cli import campaign

    assert campaign.distributed_module().Client is not None
