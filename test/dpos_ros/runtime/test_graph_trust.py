"""What a graph file may start and set: only the product's executables
unless the file lists others under ``allow_executables``; no loader variables in ``env``; wrong
types, spaces and quotes in names and values end in one line naming the entry (GraphError, which
dpos-graph prints with exit status 2), never a traceback.  Nothing here starts a process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from dpos_core.errors import GraphError
from dpos_ros.runtime.graph import GraphSpec, _param_text

NODE = "{name: a, executable: ifa_node}"

# (case, graph file text, what the one line must say): the cases, then ours
REFUSED = [
    ("bash", "nodes: [{name: a, executable: bash, args: ['-c', 'id']}]", "not one of the product's"),
    ("LD_PRELOAD", f"env: {{LD_PRELOAD: /tmp/x.so}}\nnodes: [{NODE}]", "env 'LD_PRELOAD': refused"),
    ("wrong type: parameters a list", "nodes: [{name: a, executable: ifa_node, parameters: [1, 2]}]", "parameters must be a mapping"),
    ("wrong type: ready a list", "nodes: [{name: a, executable: ifa_node, ready: [x]}]", "ready must be a mapping"),
    ("wrong type: timeout a word", f"ready_timeout_s: abc\nnodes: [{NODE}]", "ready_timeout_s must be a number"),
    ("wrong type: env a list", f"env: [A]\nnodes: [{NODE}]", "env must be a mapping"),
    ("space in a name", "nodes: [{name: 'my node', executable: ifa_node}]", "not a ROS node name"),
    ("quote in a name", "nodes: [{name: \"it's\", executable: ifa_node}]", "not a ROS node name"),
    ("space in a parameter name", "nodes: [{name: a, executable: ifa_node, parameters: {'bad key': 1}}]", "not a ROS parameter name"),
    ("space in a remap", "nodes: [{name: a, executable: ifa_node, remaps: {'/a b': /c}}]", "both must be topic names"),
    ("line break in a value", "nodes: [{name: a, executable: ifa_node, parameters: {x: \"a\\nb\"}}]", "control character"),
    # ours
    ("absolute path to a shell", "nodes: [{name: a, executable: /bin/sh}]", "not one of the product's"),
    ("PYTHONPATH", f"env: {{PYTHONPATH: /tmp/evil}}\nnodes: [{NODE}]", "env 'PYTHONPATH': refused"),
    ("LD_LIBRARY_PATH", f"env: {{LD_LIBRARY_PATH: /tmp}}\nnodes: [{NODE}]", "env 'LD_LIBRARY_PATH': refused"),
    ("PATH", f"env: {{PATH: /tmp/evil}}\nnodes: [{NODE}]", "env 'PATH': refused"),
    ("a dict as a value", "nodes: [{name: a, executable: ifa_node, parameters: {x: {y: 1}}}]", "is not a parameter value"),
    ("a mixed list", "nodes: [{name: a, executable: ifa_node, parameters: {x: [1, a]}}]", "values of one type"),
    ("a number as a name", "nodes: [{name: 5, executable: ifa_node}]", "not a ROS node name"),
    ("domain id a bool", f"ros_domain_id: true\nnodes: [{NODE}]", "ros_domain_id must be an integer"),
    ("negative stop timeout", f"stop_timeout_s: -1\nnodes: [{NODE}]", "stop_timeout_s must be a number"),
    ("allow_executables a string", f"allow_executables: bash\nnodes: [{NODE}]", "allow_executables must be a list"),
    ("binary file", "\x00\x01", "cannot read the graph file"),
]


@pytest.mark.parametrize("case, text, match", REFUSED, ids=[c[0] for c in REFUSED])
def test_graph_file_refused_in_one_line(case: str, text: str, match: str) -> None:
    with pytest.raises(GraphError, match=match) as e:
        GraphSpec.from_yaml("g.yaml", text=text)
    assert "\n" not in str(e.value)


def test_other_executables_only_when_the_file_allows_them() -> None:
    spec = GraphSpec.from_yaml("g.yaml", text="allow_executables: [my_driver]\nnodes: [{name: drv, executable: my_driver}, "
                                              "{name: ifa_node, executable: ifa_node}]")
    assert [n.executable for n in spec.nodes] == ["my_driver", "ifa_node"]
    spec = GraphSpec.from_yaml("g.yaml", text=f"env: {{RMW_IMPLEMENTATION: rmw_fastrtps_cpp, FASTDDS_X: 1}}\nnodes: [{NODE}]")
    assert spec.env == {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp", "FASTDDS_X": "1"}


@pytest.mark.parametrize("value", ["it's", 'say "hi"', "a b", "1.0", "true", "", " lead", "x: y", "#c", "[1]", "plain",
                                   ["a b", "it's"], [], 3, 2.5, True])
def test_parameter_values_reach_the_node_intact(value) -> None:
    """``-p name:=TEXT`` is parsed as YAML by rcl: every string comes back as the same string."""
    assert yaml.safe_load(_param_text(value)) == value


def test_dpos_graph_prints_one_line_and_exits_2(tmp_path: Path) -> None:
    g = tmp_path / "g.yaml"
    g.write_text("env: {LD_PRELOAD: /tmp/x.so}\nnodes: [{name: a, executable: ifa_node}]\n")
    r = subprocess.run([str(Path(sys.executable).parent / "dpos-graph"), str(g)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "refused" in lines[0], r.stderr
