"""An unknown node parameter through a real process: every node refuses it with one
error naming it and the closest known parameter, and exits with status 2 (not 0, not a traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from node_process import START_TIMEOUT_S  # test/support/node_process.py

pytestmark = pytest.mark.ros

BIN_DIR = Path(sys.executable).parent


@pytest.mark.parametrize(("node", "typo", "hint"), [
    ("pos_master_node", "rate_factr", "did you mean 'rate_factor'?"),
    ("pos_sub_node", "rate_factr", "did you mean 'rate_factor'?"),
    ("ifa_node", "windw", "did you mean 'window'?"),
    ("transfer_align_node", "particels", "did you mean 'particles'?"),
    ("sar_nav_node", "bandwith_scale", "did you mean 'bandwidth_scale'?"),
    # another node's parameter: nothing alike here, so the nearest name and the node's whole list
    ("transfer_align_node", "rate_factr", "the closest known is '"),
    ("ifa_node", "rate_factr", "the closest known is '"),
])
def test_unknown_parameter_exits_2_naming_the_closest(node: str, typo: str, hint: str, tmp_path: Path) -> None:
    r = subprocess.run([str(BIN_DIR / node), "--ros-args", "-p", f"{typo}:=10.0"], capture_output=True, text=True,
                       timeout=START_TIMEOUT_S, cwd=tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 2, out
    assert "Traceback" not in out, out
    errors = [ln for ln in out.splitlines() if f"invalid parameter '{typo}' = 10.0: unknown parameter of this node" in ln]
    assert len(errors) == 1 and hint in errors[0], out
    if "closest known" in hint:
        assert "Config has: " in errors[0], errors[0]
