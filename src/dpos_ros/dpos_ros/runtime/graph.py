"""Launch-free startup of a node graph: processes from a small YAML file.

    with Graph.from_yaml("graph.yaml") as g:      # starts every node, waits until ready
        g.wait_for_exit("master", timeout=600)    # or anything else
    # leaving the block stops them: SIGINT, then SIGTERM, then SIGKILL, no orphans

Graph file::

    ros_domain_id: 42            # optional; default: inherit the environment's
    ready_timeout_s: 30          # optional
    stop_timeout_s: 10           # optional: SIGINT -> SIGTERM after this, SIGKILL after twice
    env: {RMW_IMPLEMENTATION: rmw_fastrtps_cpp}
    nodes:
      - name: master             # node name (-r __node:=NAME) and log prefix
        executable: pos_master_node      # console script beside this Python, or on PATH
        parameters: {scenario: paper_su, rate_factor: 10.0}
        params_file: my_params.yaml      # optional, relative to the graph file
        remaps: {/gnss/fix: /receiver/fix}
        ready: {publishes: [/master/imu]} # optional; default: the node is in the ROS graph
      - name: sub_r
        executable: pos_sub_node
        parameters: {name: sub_r}
        ready: {subscribes: [/master/nav]}

Readiness is checked through the ROS graph by a private probe node: a node is ready when it is
visible and every topic it should publish (subscribe) has it as a publisher (subscriber).  Each
process runs in its own session (process group), its stdout/stderr are streamed line by line
with a ``[name]`` prefix and kept for inspection.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dpos_core.errors import GraphError


@dataclass(frozen=True)
class NodeSpec:
    name: str
    executable: str
    parameters: dict[str, Any] = field(default_factory=dict)
    params_file: str | None = None
    remaps: dict[str, str] = field(default_factory=dict)
    ready_publishes: tuple[str, ...] = ()
    ready_subscribes: tuple[str, ...] = ()
    args: tuple[str, ...] = ()

    def command(self, base: Path) -> list[str]:
        exe = _resolve(self.executable)
        cmd = [exe, *self.args, "--ros-args", "-r", f"__node:={self.name}"]
        if self.params_file:
            p = Path(self.params_file)
            cmd += ["--params-file", str(p if p.is_absolute() else base / p)]
        for k, v in self.parameters.items():
            cmd += ["-p", f"{k}:={_param_text(v)}"]
        for a, b in self.remaps.items():
            cmd += ["-r", f"{a}:={b}"]
        return cmd


def _resolve(exe: str) -> str:
    local = Path(sys.executable).parent / exe
    if local.is_file():
        return str(local)
    found = shutil.which(exe)
    if found is None:
        raise GraphError(f"executable {exe!r} not found beside {sys.executable} nor on PATH")
    return found


def _is_placeholder(v: Any) -> bool:
    """A value written ``<LIKE THIS>`` in an example graph: the user must replace it."""
    return isinstance(v, str) and len(v) > 2 and v.startswith("<") and v.endswith(">")


def _param_text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_param_text(x) for x in v) + "]"
    if isinstance(v, str) and (v == "" or any(c in v for c in " :,[]{}#")):
        return "'" + v.replace("'", "\\'") + "'"
    return str(v)


@dataclass
class GraphSpec:
    nodes: list[NodeSpec]
    ros_domain_id: int | None = None
    env: dict[str, str] = field(default_factory=dict)
    ready_timeout_s: float = 30.0
    stop_timeout_s: float = 10.0
    base_dir: Path = Path(".")

    @classmethod
    def from_yaml(cls, path: str | Path, text: str | None = None) -> GraphSpec:
        p = Path(path)
        label = str(p)
        try:
            d = yaml.safe_load(text if text is not None else p.read_text())
        except (OSError, yaml.YAMLError) as e:
            raise GraphError(f"{label}: cannot read the graph file: {e}") from None
        if not isinstance(d, dict) or not isinstance(d.get("nodes"), list) or not d["nodes"]:
            raise GraphError(f"{label}: needs a non-empty 'nodes' list")
        unknown = set(d) - {"nodes", "ros_domain_id", "env", "ready_timeout_s", "stop_timeout_s"}
        if unknown:
            raise GraphError(f"{label}: unknown key(s) {sorted(unknown)}")
        nodes = []
        for i, n in enumerate(d["nodes"]):
            if not isinstance(n, dict) or not n.get("name") or not n.get("executable"):
                raise GraphError(f"{label}: nodes[{i}] needs a name and an executable")
            bad = set(n) - {"name", "executable", "parameters", "params_file", "remaps", "ready", "args"}
            if bad:
                raise GraphError(f"{label}: nodes[{i}] ({n['name']}): unknown key(s) {sorted(bad)}")
            ready = n.get("ready") or {}
            nodes.append(NodeSpec(str(n["name"]), str(n["executable"]), dict(n.get("parameters") or {}), n.get("params_file"),
                                  dict(n.get("remaps") or {}), tuple(ready.get("publishes") or ()), tuple(ready.get("subscribes") or ()),
                                  tuple(str(a) for a in n.get("args") or ())))
        unset = [f"{n.name}: {where} {key!r} = {value}" for n in nodes for where, values in (("parameter", n.parameters), ("remap", n.remaps))
                 for key, value in values.items() if _is_placeholder(value)]
        if unset:
            raise GraphError(f"{label}: set what only you know about your installation (values written <LIKE THIS>):\n  "
                             + "\n  ".join(unset))
        names = [n.name for n in nodes]
        if len(set(names)) != len(names):
            raise GraphError(f"{label}: duplicate node names {names}")
        dom = d.get("ros_domain_id")
        if dom is not None and not (isinstance(dom, int) and 0 <= dom <= 232):
            raise GraphError(f"{label}: ros_domain_id must be an integer in 0..232, got {dom!r}")
        return cls(nodes, dom, {str(k): str(v) for k, v in (d.get("env") or {}).items()},
                   float(d.get("ready_timeout_s", 30.0)), float(d.get("stop_timeout_s", 10.0)), p.parent)


class _Proc:
    def __init__(self, spec: NodeSpec, popen: subprocess.Popen, sink: Callable[[str, str], None]) -> None:
        self.spec = spec
        self.popen = popen
        self.lines: deque[str] = deque(maxlen=5000)
        self._sink = sink
        self.thread = threading.Thread(target=self._pump, name=f"log-{spec.name}", daemon=True)
        self.thread.start()

    def _pump(self) -> None:
        assert self.popen.stdout is not None
        for raw in self.popen.stdout:
            line = raw.rstrip("\n")
            self.lines.append(line)
            self._sink(self.spec.name, line)


class Graph:
    """A running set of node processes (see module docstring)."""

    def __init__(self, spec: GraphSpec, log: Callable[[str, str], None] | None = None) -> None:
        self.spec = spec
        self._log = log or (lambda name, line: print(f"[{name}] {line}", flush=True))
        self.procs: dict[str, _Proc] = {}
        self.exit_codes: dict[str, int] = {}

    @classmethod
    def from_yaml(cls, path: str | Path, log: Callable[[str, str], None] | None = None, **overrides: Any) -> Graph:
        spec = GraphSpec.from_yaml(path)
        for k, v in overrides.items():
            setattr(spec, k, v)
        return cls(spec, log)

    # ------------------------------------------------------------------ lifecycle
    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.update(self.spec.env)
        if self.spec.ros_domain_id is not None:
            env["ROS_DOMAIN_ID"] = str(self.spec.ros_domain_id)
        env["PYTHONUNBUFFERED"] = "1"
        env.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "0")
        return env

    def start(self) -> None:
        env = self.env()
        try:
            cmds = [(n, n.command(self.spec.base_dir)) for n in self.spec.nodes]
        except GraphError:
            raise
        for node, cmd in cmds:
            p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                 start_new_session=True, bufsize=1)
            self.procs[node.name] = _Proc(node, p, self._log)

    def wait_ready(self, timeout_s: float | None = None) -> None:
        """Block until every node is ready (module docstring); GraphError naming the laggards."""
        timeout = self.spec.ready_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        pending = {n.name: n for n in self.spec.nodes}
        probe = _Probe(self.spec.ros_domain_id)
        try:
            while pending and time.monotonic() < deadline:
                for name in list(pending):
                    pr = self.procs[name].popen
                    if pr.poll() is not None:
                        raise GraphError(f"node {name} exited with status {pr.returncode} before it was ready; "
                                         f"last output: {list(self.procs[name].lines)[-5:]}")
                    if probe.ready(pending[name]):
                        del pending[name]
                if pending:
                    probe.spin(0.1)
        finally:
            probe.close()
        if pending:
            raise GraphError(f"not ready after {timeout:g} s: {sorted(pending)}")

    def wait_for_exit(self, name: str, timeout: float | None = None) -> int:
        return self.procs[name].popen.wait(timeout=timeout)

    def logs(self, name: str) -> list[str]:
        return list(self.procs[name].lines)

    def stop(self) -> dict[str, int]:
        """SIGINT every running node; SIGTERM after ``stop_timeout_s``; SIGKILL after twice that."""
        t = self.spec.stop_timeout_s
        for sig, wait in ((signal.SIGINT, t), (signal.SIGTERM, t), (signal.SIGKILL, 5.0)):
            alive = [p for p in self.procs.values() if p.popen.poll() is None]
            if not alive:
                break
            for p in alive:
                try:
                    os.killpg(p.popen.pid, sig)
                except ProcessLookupError:
                    pass
            end = time.monotonic() + wait
            for p in alive:
                try:
                    p.popen.wait(timeout=max(0.0, end - time.monotonic()))
                except subprocess.TimeoutExpired:
                    if sig != signal.SIGKILL:
                        self._log(p.spec.name, f"did not stop after {signal.Signals(sig).name} within {wait:g} s")
        for name, p in self.procs.items():
            self.exit_codes[name] = p.popen.wait()
            p.thread.join(timeout=2.0)
        return dict(self.exit_codes)

    def __enter__(self) -> Graph:
        try:
            self.start()
            self.wait_ready()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class _Probe:
    """A private rclpy context + node that reads the ROS graph."""

    def __init__(self, domain_id: int | None) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.ctx = Context()
        kw = {} if domain_id is None else {"domain_id": domain_id}
        rclpy.init(context=self.ctx, **kw)
        self.node = rclpy.create_node(f"dpos_graph_probe_{os.getpid()}", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def spin(self, t: float) -> None:
        self.ex.spin_once(timeout_sec=t)

    def ready(self, n: NodeSpec) -> bool:
        names = {nm for nm, _ns in self.node.get_node_names_and_namespaces()}
        if n.name not in names:
            return False
        for topic in n.ready_publishes:
            if not any(i.node_name == n.name for i in self.node.get_publishers_info_by_topic(topic)):
                return False
        for topic in n.ready_subscribes:
            if not any(i.node_name == n.name for i in self.node.get_subscriptions_info_by_topic(topic)):
                return False
        return True

    def close(self) -> None:
        try:
            self.ex.shutdown()
            self.node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self.ctx)
