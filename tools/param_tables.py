#!/usr/bin/env python3
"""Parameter tables of docs/design.md, generated from the nodes' config dataclasses.

Every node keeps its parameters in a frozen dataclass whose fields are made by
:func:`dpos_ros.runtime.params.param` (default, description and constraints in the field metadata).
This script renders one Markdown table per node and keeps docs/design.md in step with the code:
the tables sit between the markers ``<!-- params:NODE begin -->`` and ``<!-- params:NODE end -->``.

    .venv/bin/python tools/param_tables.py            # rewrite the tables in docs/design.md
    .venv/bin/python tools/param_tables.py --check    # exit 1 if a table in the doc is stale
    .venv/bin/python tools/param_tables.py --print ifa_node   # print one table

The constraint column is what the node declares to ROS (``ros2 param describe`` shows it as
"additional constraints"): it is produced by running :func:`dpos_ros.runtime.params.declare_config` on a
recording stand-in for the node, so the text is exactly the code's.  Extra checks of a field
(``check=`` of :func:`param`) are described from :data:`CHECKS` (or named, when unknown).
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import importlib
import inspect
import pathlib
import sys
import typing
from types import SimpleNamespace
from typing import Any

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "design.md"

#: node -> "module:ConfigClass" (the order of the tables in the doc does not matter)
NODES: dict[str, str] = {
    "pos_master_node": "pos_master_node.params:PosMasterConfig",
    "pos_sub_node": "pos_sub_node.params:PosSubConfig",
    "ifa_node": "ifa_node.params:IfaConfig",
    "transfer_align_node": "transfer_align_node.params:TransferAlignConfig",
    "sar_nav_node": "sar_nav_node.params:SarNavConfig",
}

#: Extra checks (``param(check=...)``) by the check function's qualified name. A check that is
#: not listed here is shown by name, so that a new one shows up as a stale table.
CHECKS: dict[str, str] = {
    "dpos_ros.runtime.params._check_datum": "[] or [lat_deg in [-90, 90], lon_deg in [-180, 180], h_m]",
    "dpos_ros.runtime.params._check_scenario": "a built-in scenario or an existing .yaml file",
    "dpos_ros.runtime.params.scenario_param.<locals>.<lambda>": "'' or a built-in scenario or an existing .yaml file",
    "pos_sub_node.params._check_name": "letters, digits, '_', starting with a letter",
    "transfer_align_node.params._check_sub_imus": "names non-empty and unique",
}

_ROS_TYPES = {bool: "bool", int: "integer", float: "double", str: "string"}


def _begin(node: str) -> str:
    return f"<!-- params:{node} begin -->"


def _end(node: str) -> str:
    return f"<!-- params:{node} end -->"


def config_class(node: str) -> type:
    module, _, name = NODES[node].partition(":")
    return getattr(importlib.import_module(module), name)


class _RecordingNode:
    """Stands in for an rclpy node in ``declare_config``: keeps every ParameterDescriptor and
    leaves every parameter unset (so the dataclass defaults are validated)."""

    def __init__(self) -> None:
        self.descriptors: dict[str, Any] = {}

    def declare_parameter(self, name: str, value: Any, descriptor: Any) -> Any:
        from rclpy.parameter import Parameter

        self.descriptors[name] = descriptor
        return SimpleNamespace(value=None, type_=Parameter.Type.NOT_SET)


def declared_constraints(cls: type) -> dict[str, str]:
    """``additional_constraints`` of each parameter, as :func:`dpos_ros.runtime.params.declare_config`
    declares them."""
    from dpos_ros.runtime.params import ParameterError, declare_config

    node = _RecordingNode()
    try:
        declare_config(node, cls)
    except ParameterError:  # a required parameter (default ''): every descriptor is declared by now
        pass
    return {name: d.additional_constraints for name, d in node.descriptors.items()}


def _param_spec(field: dataclasses.Field) -> Any:
    from dpos_ros.runtime import params

    key = getattr(params, "_META_KEY", "dpos_param")
    spec = field.metadata.get(key)
    if spec is None:
        raise TypeError(f"field {field.name!r} is not made by dpos_ros.runtime.params.param()")
    return spec


def _ros_type(hint: Any) -> str:
    if hint in _ROS_TYPES:
        return _ROS_TYPES[hint]
    if typing.get_origin(hint) is tuple:
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        if args and all(a == args[0] for a in args) and args[0] in _ROS_TYPES:
            return _ROS_TYPES[args[0]] + "[]"
    raise TypeError(f"unsupported parameter type {hint!r}")


def _check_text(check: Any) -> str:
    if check is None:
        return ""
    qual = f"{getattr(check, '__module__', '?')}.{getattr(check, '__qualname__', repr(check))}"
    if qual in CHECKS:
        return CHECKS[qual]
    # closures of a check factory: name the factory's arguments (e.g. _check_len(0, 9))
    if "<locals>" in qual:
        free = inspect.getclosurevars(check).nonlocals
        if set(free) == {"allowed"}:
            return f"{' or '.join(str(n) for n in free['allowed'])} values"
    return f"custom check `{qual}`"


def _value(v: Any) -> str:
    """A default as it is written in a params file."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f"'{v}'"
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(v if isinstance(v, str) else _value(v) for v in v) + "]"
    return repr(v)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ").strip()


def render_table(cls: type) -> str:
    """The Markdown table of a config dataclass: name, type, default, constraint, description."""
    hints = typing.get_type_hints(cls)
    declared = declared_constraints(cls)
    lines = ["| name | type | default | constraint | description |", "| --- | --- | --- | --- | --- |"]
    for f in dataclasses.fields(cls):
        spec = _param_spec(f)
        constraint = "; ".join(c for c in (declared.get(f.name, ""), _check_text(spec.check)) if c)
        lines.append(
            f"| `{f.name}` | {_ros_type(hints[f.name])} | `{_value(f.default)}` | {_cell(constraint) or '-'} "
            f"| {_cell(spec.description)} |"
        )
    return "\n".join(lines)


def tables() -> dict[str, str]:
    """Every node's table, by node name."""
    return {node: render_table(config_class(node)) for node in NODES}


def update(text: str, rendered: dict[str, str] | None = None) -> str:
    """``text`` with every table between its markers replaced by the rendered one.

    Raises:
        ValueError: a node's markers are missing, repeated or out of order.
    """
    rendered = tables() if rendered is None else rendered
    for node, table in rendered.items():
        b, e = _begin(node), _end(node)
        if text.count(b) != 1 or text.count(e) != 1 or text.index(b) > text.index(e):
            raise ValueError(f"expected one '{b}' followed by one '{e}'")
        head, rest = text.split(b, 1)
        _, tail = rest.split(e, 1)
        text = f"{head}{b}\n{table}\n{e}{tail}"
    return text


def stale(doc: pathlib.Path = DOC) -> list[str]:
    """Problems of the doc's tables: '' list when they equal what the code declares."""
    text = doc.read_text(encoding="utf-8")
    try:
        new = update(text)
    except ValueError as e:
        return [str(e)]
    if new == text:
        return []
    return list(difflib.unified_diff(text.splitlines(), new.splitlines(), str(doc), "generated", lineterm="", n=0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--doc", type=pathlib.Path, default=DOC, help="the design document (default docs/design.md)")
    ap.add_argument("--check", action="store_true", help="exit 1 (printing the difference) if the doc's tables are stale")
    ap.add_argument("--print", dest="print_node", choices=sorted(NODES), metavar="NODE", help="print one node's table")
    args = ap.parse_args(argv)
    if args.print_node:
        print(render_table(config_class(args.print_node)))
        return 0
    if args.check:
        problems = stale(args.doc)
        if problems:
            print("\n".join(problems))
            print(f"{args.doc}: parameter tables are stale; run tools/param_tables.py", file=sys.stderr)
            return 1
        print(f"{args.doc}: parameter tables are up to date")
        return 0
    text = args.doc.read_text(encoding="utf-8")
    new = update(text)
    if new != text:
        args.doc.write_text(new, encoding="utf-8")
        print(f"{args.doc}: parameter tables rewritten")
    else:
        print(f"{args.doc}: parameter tables already up to date")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
