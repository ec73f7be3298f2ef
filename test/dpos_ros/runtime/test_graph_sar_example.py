"""The packaged SINS/SAR graph (``dpos-graph --example sim_paper_sar``): sar_nav_node and the simulated
paper_sar main system; it parses, and its node parameters are valid for the nodes' config dataclasses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from dpos_ros.runtime.graph import GraphSpec
from dpos_ros.runtime.params import config_from_values
from pos_master_node.params import PosMasterConfig
from sar_nav_node.params import SarNavConfig

EXE = Path(sys.executable).parent


def test_sim_paper_sar_example(tmp_path: Path) -> None:
    r = subprocess.run([str(EXE / "dpos-graph"), "--example", "sim_paper_sar"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    spec = GraphSpec.from_yaml(tmp_path / "g.yaml", text=r.stdout)
    nodes = {n.executable: n for n in spec.nodes}
    assert sorted(nodes) == ["pos_master_node", "sar_nav_node"]
    assert config_from_values(SarNavConfig, nodes["sar_nav_node"].parameters).method == "ekf"
    master = config_from_values(PosMasterConfig, nodes["pos_master_node"].parameters)
    assert master.scenario == "paper_sar" and master.min_subscribers == 1
