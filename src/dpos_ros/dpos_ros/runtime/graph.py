"""Launch-free startup of a node graph: processes from a small YAML file.

    with Graph.from_yaml("graph.yaml") as g:      # starts every node, waits until ready
        g.wait_for_exit("master", timeout=600)    # or anything else
    # leaving the block stops them: SIGINT, then SIGTERM, then SIGKILL, no orphans

Graph file::

    ros_domain_id: 42            # optional; default: inherit the environment's
    ready_timeout_s: 30          # optional
    stop_timeout_s: 10           # optional: SIGINT -> SIGTERM after this, SIGKILL after twice
    env: {RMW_IMPLEMENTATION: rmw_fastrtps_cpp}   # loader variables (LD_*, PYTHONPATH, ...) are refused
    allow_executables: [my_driver]   # optional: executables other than the product's that this file may start
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

What a graph file may start is checked before anything runs (:meth:`GraphSpec.from_yaml`): an
``executable`` is one of the product's (:data:`PRODUCT_EXECUTABLES`) unless the file lists it under
``allow_executables``; ``env`` cannot set a variable that changes what a process loads
(:func:`env_problem`: ``LD_PRELOAD``, ``PYTHONPATH``, ...); names, parameters, remaps and the
numbers have the types and the characters ROS accepts (one line naming the entry otherwise).
"""

from __future__ import annotations

import math
import os
import re
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

#: the executables of the product a graph file may start without listing them in ``allow_executables``
PRODUCT_EXECUTABLES = frozenset({"pos_master_node", "ifa_node", "pos_sub_node", "transfer_align_node", "sar_nav_node",
                                 "dpos-record", "dpos-play"})
#: environment variables that change what a process loads or runs before its own code: never from a graph file
LOADER_ENV = frozenset({"PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "PYTHONUSERBASE", "PYTHONEXECUTABLE",
                        "PYTHONINSPECT", "PYTHONSAFEPATH", "PYTHONPLATLIBDIR", "BASH_ENV", "ENV", "PATH",
                        "AMENT_PREFIX_PATH", "RMW_IMPLEMENTATION_WRAPPER", "GCONV_PATH", "HOSTALIASES", "NLSPATH"})
_LOADER_PREFIXES = ("LD_", "DYLD_", "MALLOC_", "GLIBC_")
_ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")  # rcl's node name rule
_PARAM_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*\Z")
_TOPIC = re.compile(r"~?/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*\Z")
_EXE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*\Z")


def env_problem(name: str) -> str | None:
    """Why a graph file may not set the environment variable ``name`` (None: it may)."""
    if not _ENV_NAME.match(name):
        return "not a variable name"
    if name.upper().startswith(_LOADER_PREFIXES) or name.upper() in LOADER_ENV:
        return "it changes what a process loads (set it outside dpos-graph if you must)"
    return None


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
    if Path(exe).name != exe:  # a path: only from allow_executables (GraphSpec.from_yaml), run as written
        if not (Path(exe).is_file() and os.access(exe, os.X_OK)):
            raise GraphError(f"executable {exe!r} is not an executable file")
        return exe
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
    if isinstance(v, str) and _needs_quotes(v):  # a YAML single-quoted string: ' doubled
        return "'" + v.replace("'", "''") + "'"
    return str(v)


def _needs_quotes(v: str) -> bool:
    if v == "" or v != v.strip() or any(c in v for c in ":,[]{}#'\"&*!|>%@`?"):
        return True
    try:
        return yaml.safe_load(v) != v
    except yaml.YAMLError:
        return True


def _is_scalar(v: Any) -> bool:
    return isinstance(v, (bool, int, str)) or isinstance(v, float) and math.isfinite(v)


def _param_problem(v: Any) -> str | None:
    """Why ``v`` cannot be a ROS parameter value from a graph file (None: it can)."""
    if isinstance(v, (list, tuple)):  # (an empty list: a parameter's "unset", e.g. datum: [])
        if not all(_is_scalar(x) and not isinstance(x, (list, tuple)) for x in v):
            return "a list must hold numbers, booleans or strings"
        kinds = {bool if isinstance(x, bool) else (float if isinstance(x, (int, float)) else str) for x in v}
        if len(kinds) > 1:
            return "a list must hold values of one type"
        v = list(v)
    elif not _is_scalar(v):
        return f"a {type(v).__name__} is not a parameter value (a number, a boolean, a string or a list of one of them)"
    for x in v if isinstance(v, list) else [v]:
        if isinstance(x, str) and any(ord(c) < 32 for c in x):
            return "a control character (a line break?) in a string"
    return None


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
        """The graph of the YAML file ``path`` (or of ``text``); :class:`GraphError` naming the entry
        that is wrong (module docstring: what a graph file may start and set)."""
        p = Path(path)
        label = str(p)
        try:
            d = yaml.safe_load(text if text is not None else p.read_text())
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
            raise GraphError(f"{label}: cannot read the graph file: {' '.join(str(e).split())}") from None
        if not isinstance(d, dict) or not isinstance(d.get("nodes"), list) or not d["nodes"]:
            raise GraphError(f"{label}: needs a non-empty 'nodes' list")
        unknown = set(d) - {"nodes", "ros_domain_id", "env", "ready_timeout_s", "stop_timeout_s", "allow_executables"}
        if unknown:
            raise GraphError(f"{label}: unknown key(s) {sorted(map(str, unknown))}")
        allowed = d.get("allow_executables") or []
        if not (isinstance(allowed, list) and all(isinstance(x, str) and x for x in allowed)):
            raise GraphError(f"{label}: allow_executables must be a list of executable names or paths, got {allowed!r}")
        nodes = [_node_spec(label, i, n, frozenset(allowed)) for i, n in enumerate(d["nodes"])]
        unset = [f"{n.name}: {where} {key!r} = {value}" for n in nodes for where, values in (("parameter", n.parameters), ("remap", n.remaps))
                 for key, value in values.items() if _is_placeholder(value)]
        if unset:
            raise GraphError(f"{label}: set what only you know about your installation (values written <LIKE THIS>):\n  "
                             + "\n  ".join(unset))
        names = [n.name for n in nodes]
        if len(set(names)) != len(names):
            raise GraphError(f"{label}: duplicate node names {names}")
        dom = d.get("ros_domain_id")
        if dom is not None and not (isinstance(dom, int) and not isinstance(dom, bool) and 0 <= dom <= 232):
            raise GraphError(f"{label}: ros_domain_id must be an integer in 0..232, got {dom!r}")
        env = d.get("env") or {}
        if not isinstance(env, dict):
            raise GraphError(f"{label}: env must be a mapping of variable names to values, got {env!r}")
        for k, v in env.items():
            why = env_problem(str(k)) or (None if _is_scalar(v) and "\0" not in str(v) else "its value must be a string or a number")
            if why:
                raise GraphError(f"{label}: env {k!r}: refused: {why}")
        times = {}
        for key, default in (("ready_timeout_s", 30.0), ("stop_timeout_s", 10.0)):
            t = d.get(key, default)
            if isinstance(t, bool) or not isinstance(t, (int, float)) or not (math.isfinite(t) and 0 < t <= 86400):
                raise GraphError(f"{label}: {key} must be a number of seconds in (0, 86400], got {t!r}")
            times[key] = float(t)
        return cls(nodes, dom, {str(k): str(v) for k, v in env.items()}, times["ready_timeout_s"], times["stop_timeout_s"], p.parent)


def _node_spec(label: str, i: int, n: Any, allowed: frozenset[str]) -> NodeSpec:
    """The ``i``-th entry ``n`` of a graph file's ``nodes``, checked (:meth:`GraphSpec.from_yaml`)."""
    if not isinstance(n, dict) or not n.get("name") or not n.get("executable"):
        raise GraphError(f"{label}: nodes[{i}] needs a name and an executable")
    name = n["name"]
    if not isinstance(name, str) or not _NODE_NAME.match(name):
        raise GraphError(f"{label}: nodes[{i}]: name {name!r} is not a ROS node name (letters, digits, '_'; not a digit first)")
    where = f"{label}: nodes[{i}] ({name})"
    bad = set(n) - {"name", "executable", "parameters", "params_file", "remaps", "ready", "args"}
    if bad:
        raise GraphError(f"{where}: unknown key(s) {sorted(map(str, bad))}")
    exe = n["executable"]
    if not isinstance(exe, str):
        raise GraphError(f"{where}: executable must be a name, got {exe!r}")
    if exe not in allowed and (exe not in PRODUCT_EXECUTABLES or not _EXE_NAME.match(exe)):
        raise GraphError(f"{where}: executable {exe!r} is not one of the product's {sorted(PRODUCT_EXECUTABLES)}; "
                         "a graph file that means to start it lists it under allow_executables")
    params = n.get("parameters") or {}
    if not isinstance(params, dict):
        raise GraphError(f"{where}: parameters must be a mapping, got {params!r}")
    for k, v in params.items():
        if not isinstance(k, str) or not _PARAM_NAME.match(k):
            raise GraphError(f"{where}: parameter name {k!r} is not a ROS parameter name")
        if (why := _param_problem(v)) is not None:
            raise GraphError(f"{where}: parameter {k!r} = {v!r}: {why}")
    remaps = n.get("remaps") or {}
    if not isinstance(remaps, dict):
        raise GraphError(f"{where}: remaps must be a mapping of topic names, got {remaps!r}")
    for a, b in remaps.items():
        if not (isinstance(a, str) and isinstance(b, str) and _TOPIC.match(a) and (_TOPIC.match(b) or _is_placeholder(b))):
            raise GraphError(f"{where}: remap {a!r}: {b!r}: both must be topic names")
    ready = n.get("ready") or {}
    if not isinstance(ready, dict) or set(ready) - {"publishes", "subscribes"}:
        raise GraphError(f"{where}: ready must be a mapping with publishes and/or subscribes, got {ready!r}")
    topics = {}
    for key in ("publishes", "subscribes"):
        ts = ready.get(key) or []
        if not (isinstance(ts, list) and all(isinstance(t, str) and _TOPIC.match(t) for t in ts)):
            raise GraphError(f"{where}: ready {key} must be a list of topic names, got {ts!r}")
        topics[key] = tuple(ts)
    pf = n.get("params_file")
    if pf is not None and not (isinstance(pf, str) and pf and "\0" not in pf):
        raise GraphError(f"{where}: params_file must be a file name, got {pf!r}")
    args = n.get("args") or []
    if not (isinstance(args, list) and all(_is_scalar(a) and "\0" not in str(a) for a in args)):
        raise GraphError(f"{where}: args must be a list of strings, got {args!r}")
    return NodeSpec(name, exe, dict(params), pf, dict(remaps), topics["publishes"], topics["subscribes"], tuple(str(a) for a in args))


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
