"""Workspace structure: ament_python packages, console scripts, and a ROS-free dpos_core."""

from __future__ import annotations

import ast
import configparser
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from importlib.metadata import entry_points
from pathlib import Path

import pytest
from repo_paths import REPO

ROOT = REPO
SRC = ROOT / "src"
PACKAGES = ["dpos_core", "dpos_ros", "pos_master_node", "pos_sub_node", "ifa_node", "transfer_align_node", "sar_nav_node"]
NODE_PACKAGES = ["pos_master_node", "pos_sub_node", "ifa_node", "transfer_align_node", "sar_nav_node"]
BIN_DIR = Path(sys.executable).parent


def _is_ros_module(module: str) -> bool:
    parts = module.split(".")
    return parts[0] in ("rclpy", "rosbags") or any(p.endswith(("_msgs", "_srvs")) for p in parts)


@pytest.mark.parametrize("package", PACKAGES)
def test_package_is_ament_python(package):
    pkg_dir = SRC / package
    root = ET.parse(pkg_dir / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == package
    assert root.findtext("export/build_type") == "ament_python"
    assert "python3-pytest" in [e.text for e in root.findall("test_depend")]
    assert (pkg_dir / "setup.py").is_file()
    assert (pkg_dir / "resource" / package).is_file()
    assert (pkg_dir / package / "__init__.py").is_file()
    cfg = configparser.ConfigParser()
    cfg.read(pkg_dir / "setup.cfg")
    assert cfg.get("develop", "script_dir") == f"$base/lib/{package}"
    assert cfg.get("install", "install_scripts") == f"$base/lib/{package}"


@pytest.mark.parametrize("package", NODE_PACKAGES)
def test_node_package_depends_on_glue_and_ships_params(package):
    root = ET.parse(SRC / package / "package.xml").getroot()
    deps = {e.text for e in root.findall("exec_depend")}
    assert {"rclpy", "dpos_ros", "dpos_core"} <= deps
    assert (SRC / package / package / "config" / f"{package}.yaml").is_file()


@pytest.mark.parametrize("script", [*NODE_PACKAGES, "dpos-demo", "dpos-strapdown-demo", "dpos-sim", "dpos-process", "dpos-eval", "dpos-graph", "dpos-play", "dpos-record", "dpos-campaign", "dpos-sar"])
def test_console_script_in_venv_bin(script):
    path = BIN_DIR / script
    assert path.is_file(), f"{path} missing: was the package installed with pip --use-pep517? (see setup.cfg)"


@pytest.mark.parametrize("package", NODE_PACKAGES)
def test_node_entry_point(package):
    (ep,) = entry_points(group="console_scripts", name=package)
    assert ep.value == f"{package}.node:main"


def test_dpos_core_sources_import_no_ros():
    offenders = []
    files = sorted((SRC / "dpos_core").rglob("*.py"))
    assert files
    for path in files:
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            else:
                continue
            offenders += [f"{path.relative_to(ROOT)}:{node.lineno}: {n}" for n in names if _is_ros_module(n)]
    assert not offenders, "dpos_core must not import ROS:\n" + "\n".join(offenders)


def test_dpos_core_modules_load_no_ros():
    code = (
        "import importlib, json, pkgutil, sys\n"
        "import dpos_core\n"
        "mods = [m.name for m in pkgutil.walk_packages(dpos_core.__path__, 'dpos_core.')]\n"
        "for m in mods:\n"
        "    importlib.import_module(m)\n"
        "print(json.dumps({'imported': mods, 'modules': sorted(sys.modules)}))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=240, check=False
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    loaded = [m for m in report["modules"] if _is_ros_module(m)]
    assert not loaded, f"importing {report['imported']} loaded ROS modules: {loaded}"
