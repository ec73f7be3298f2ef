"""Configuration files: built-in YAML by name or a user's file by path, validated into frozen
dataclasses.  Every problem is a :class:`ConfigError` naming the file and the offending key.

Built-in files live in this package (``aircraft/<name>.yaml``, ``scenarios/<name>.yaml``); any
other argument is a path, so users can write their own (copy a built-in one to start).
"""

from __future__ import annotations

from dataclasses import fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dpos_core.errors import ConfigError

#: the kinds of built-in configuration file (folders of this package).
KINDS = ("aircraft", "scenarios")


def builtin_names(kind: str) -> list[str]:
    """Names of the built-in ``aircraft`` or ``scenarios`` files."""
    return sorted(f.name[:-5] for f in resources.files(__package__).joinpath(kind).iterdir() if f.name.endswith(".yaml"))


def locate(kind: str, name_or_path: str | Path) -> tuple[Any, str]:
    """(readable resource or path, label for messages) of a built-in name or a file path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ConfigError(f"{kind} file not found: {p}")
        return p, str(p)
    res = resources.files(__package__).joinpath(kind, f"{name_or_path}.yaml")
    if not res.is_file():
        raise ConfigError(f"unknown {kind[:-1] if kind.endswith('s') else kind} {name_or_path!r}; built-in: {builtin_names(kind)}")
    return res, f"built-in {kind}/{name_or_path}.yaml"


def read_yaml(kind: str, name_or_path: str | Path) -> tuple[dict, str]:
    """The top-level mapping of a built-in or user file, and its label."""
    res, label = locate(kind, name_or_path)
    return parse_yaml(res.read_text(encoding="utf-8"), label)


def parse_yaml(text: str, label: str) -> tuple[dict, str]:
    """The top-level mapping of YAML ``text`` (``label`` names it in errors)."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{label}: invalid YAML: {e}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: expected a mapping at the top level")
    return data, label


def config_text(kind: str, name_or_path: str | Path) -> str:
    """The YAML text of a built-in or user ``scenarios``/``aircraft`` file (to embed in recordings)."""
    res, _ = locate(kind, name_or_path)
    return res.read_text(encoding="utf-8")


def build(cls: type, data: Any, where: str) -> Any:
    """Dataclass from a mapping; unknown keys and bad values raise ConfigError naming ``where``."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(names)}")
    kw = {}
    types = {f.name: str(f.type) for f in fields(cls)}
    for k, v in data.items():
        if types[k].startswith("float") and isinstance(v, str):
            try:  # YAML 1.1 reads e.g. 1.0e9 (no exponent sign) as a string
                v = float(v)
            except ValueError:
                raise ConfigError(f"{where}: {k} must be a number, got {v!r}") from None
        if types[k].startswith("float") and not isinstance(v, (int, float)):
            raise ConfigError(f"{where}: {k} must be a number, got {v!r}")
        kw[k] = tuple(v) if isinstance(v, list) else v
    try:
        return cls(**kw)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from None


def vec3(v: Any, where: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(v, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected 3 numbers, got {v!r}") from None
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{where}: values must be finite, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


