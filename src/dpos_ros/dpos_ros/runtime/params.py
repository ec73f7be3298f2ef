"""ROS parameters <-> frozen config dataclasses.

A node describes its configuration as a frozen dataclass whose fields are declared with
:func:`param` (default, description and constraints)::

    @dataclass(frozen=True)
    class MyConfig:
        rate_factor: float = param(1.0, "1.0 = real time, 0 = as fast as possible", minimum=0.0)
        method: str = param("add2", "alignment method", choices=("add2", "dd2", "aekf"))

    config = declare_config(node, MyConfig)   # declares, reads and validates

Field types map to ROS parameter types: ``bool``, ``int``, ``float``, ``str`` and
``tuple[float, ...]`` / ``tuple[int, ...]`` / ``tuple[str, ...]`` / ``tuple[bool, ...]``
(fixed-length tuples such as ``tuple[float, float, float]`` too). Parameters are declared
read-only: a config is frozen when the node starts. ``float`` parameters also accept integers
(``-p rate_factor:=0`` works like ``0.0``).

Any invalid value raises :class:`ParameterError`, whose message names the parameter and the
value; :func:`dpos_ros.runtime.node_main.run_node` logs it and exits with a non-zero status.

:func:`config_from_values` is the pure part (no rclpy), usable on a params YAML file.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.resources
import math
import pathlib
import typing
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import yaml

from dpos_core.config import builtin_names
from dpos_core.errors import ParameterError

__all__ = [
    "ParameterError",
    "param",
    "config_from_values",
    "declare_config",
    "format_config",
    "packaged_params_file",
    "read_params_file",
    "datum_param",
    "datum_problem",
    "datum_llh_rad",
    "aircraft_config_param",
    "DEVICES",
    "scenario_param",
    "duration_param",
    "min_subscribers_param",
    "wait_subscribers_param",
]

C = TypeVar("C")

#: Sensor data sources of the device nodes.
DEVICES = ("sim", "ros")


_META_KEY = "dpos_param"


@dataclasses.dataclass(frozen=True)
class _Spec:
    description: str
    choices: tuple[Any, ...] | None = None
    minimum: float | None = None
    exclusive_minimum: bool = False
    non_empty: bool = False
    length: int | None = None
    check: Callable[[Any], str | None] | None = None


def param(
    default: Any,
    description: str,
    *,
    choices: tuple[Any, ...] | None = None,
    minimum: float | None = None,
    exclusive_minimum: bool = False,
    non_empty: bool = False,
    length: int | None = None,
    check: Callable[[Any], str | None] | None = None,
) -> Any:
    """A dataclass field that is also a ROS parameter.

    Args:
        default: default value (use tuples for arrays).
        description: shown by ``ros2 param describe``.
        choices: allowed values.
        minimum: lower bound (inclusive unless ``exclusive_minimum``); for arrays, per element.
        exclusive_minimum: the bound itself is not allowed (``> minimum``).
        non_empty: strings and arrays must not be empty (a required parameter: default '').
        length: exact array length.
        check: extra check, returns an error message or None.
    """
    spec = _Spec(description, choices, minimum, exclusive_minimum, non_empty, length, check)
    return dataclasses.field(default=default, metadata={_META_KEY: spec})


def datum_problem(lat_deg: float, lon_deg: float, h_m: float) -> str | None:
    """What is wrong with a datum [lat_deg, lon_deg, h_m] (WGS-84), or None: latitude outside
    [-90, 90], longitude outside [-180, 180] (NaN is outside), a non-finite height. The nodes'
    ``datum`` parameter and ``dpos-sim --datum`` check the same."""
    if not -90.0 <= lat_deg <= 90.0:
        return f"latitude must be in [-90, 90] deg, got {lat_deg:g}"
    if not -180.0 <= lon_deg <= 180.0:
        return f"longitude must be in [-180, 180] deg, got {lon_deg:g}"
    if not math.isfinite(h_m):
        return f"height must be a finite number of metres, got {h_m:g}"
    return None


def _check_datum(datum: tuple[float, ...]) -> str | None:
    if len(datum) == 0:
        return None
    if len(datum) != 3:
        return "expected [] (the session's own datum) or [lat_deg, lon_deg, h_m]"
    return datum_problem(*datum)


def datum_param() -> Any:
    """The ``datum`` parameter every node has: [lat_deg, lon_deg, h_m] of the ``enu`` origin.

    ``[]`` (the default) means the session's own datum: for a simulated device the scenario's
    start point, for the other nodes the datum that pos_master_node publishes on /dpos/datum.
    Use :func:`datum_llh_rad` to turn the value into [lat_rad, lon_rad, h_m].
    """
    return param(
        (),
        "session datum [lat_deg, lon_deg, h_m] (WGS-84) of the enu frame; [] = the session's own "
        "(simulation: the scenario's start point)",
        check=_check_datum,
    )


def datum_llh_rad(datum: tuple[float, ...]) -> list[float] | None:
    """[lat_rad, lon_rad, h_m] of a validated ``datum`` parameter; None for ``[]``."""
    if len(datum) == 0:
        return None
    lat, lon, h = datum
    return [math.radians(lat), math.radians(lon), float(h)]


def aircraft_config_param(empty: str) -> Any:
    """The ``aircraft_config`` parameter every node has: a built-in aircraft name or a YAML path;
    ``empty`` says what '' means for that node."""
    return param("", f"aircraft configuration: built-in name or YAML path ('' = {empty})")


# ----------------------------------------------------------------------------- pure part

_SCALARS = {bool: "bool", int: "integer", float: "double", str: "string"}


def _field_kind(tp: Any) -> tuple[type, bool]:
    """(element type, is_array) of a field type hint."""
    if tp in _SCALARS:
        return tp, False
    if typing.get_origin(tp) is tuple:
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        if args and all(a == args[0] for a in args) and args[0] in _SCALARS:
            return args[0], True
    raise TypeError(f"unsupported parameter type {tp!r}")


def _fields(cls: type) -> list[tuple[dataclasses.Field, type, bool, _Spec]]:
    if not (dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen):  # type: ignore[attr-defined]
        raise TypeError(f"{cls!r} is not a frozen dataclass")
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        elem, is_array = _field_kind(hints[f.name])
        spec = f.metadata.get(_META_KEY) or _Spec(description="")
        args = typing.get_args(hints[f.name]) if is_array else ()
        if args and Ellipsis not in args and spec.length is None:  # tuple[float, float, float]: exactly 3
            spec = dataclasses.replace(spec, length=len(args))
        out.append((f, elem, is_array, spec))
    return out


def _coerce_scalar(name: str, value: Any, elem: type, shown: Any) -> Any:
    if elem is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(name, shown, "expected a double")
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(name, shown, "must be finite")
        return value
    if elem is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(name, shown, "expected an integer")
        return value
    if not isinstance(value, elem):
        raise ParameterError(name, shown, f"expected a {_SCALARS[elem]}")
    return value


def _check_bound(name: str, value: Any, x: Any, spec: _Spec) -> None:
    if spec.minimum is None:
        return
    if spec.exclusive_minimum and not x > spec.minimum:
        raise ParameterError(name, value, f"must be > {spec.minimum}")
    if not spec.exclusive_minimum and not x >= spec.minimum:
        raise ParameterError(name, value, f"must be >= {spec.minimum}")


def _validate(name: str, value: Any, elem: type, is_array: bool, spec: _Spec) -> Any:
    if is_array:
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ParameterError(name, value, f"expected a {_SCALARS[elem]} array")
        value = tuple(_coerce_scalar(name, v, elem, value) for v in value)
        if spec.length is not None and len(value) != spec.length:
            raise ParameterError(name, list(value), f"expected {spec.length} elements")
        for x in value:
            _check_bound(name, list(value), x, spec)
            if spec.choices is not None and x not in spec.choices:
                raise ParameterError(
                    name, list(value), f"element {x!r} is not one of {', '.join(map(str, spec.choices))}"
                )
    else:
        value = _coerce_scalar(name, value, elem, value)
        _check_bound(name, value, value, spec)
        if spec.choices is not None and value not in spec.choices:
            raise ParameterError(name, value, f"must be one of {', '.join(map(str, spec.choices))}")
    if spec.non_empty and (len(value) == 0 or (elem is str and not is_array and not value.strip())):
        raise ParameterError(name, list(value) if is_array else value, "must not be empty")
    if spec.check is not None:
        message = spec.check(value)
        if message:
            raise ParameterError(name, list(value) if is_array else value, message)
    return value


def config_from_values(cls: type[C], values: Mapping[str, Any]) -> C:
    """Validate ``values`` (missing keys take the field default) into a ``cls`` instance.

    Raises:
        ParameterError: a value has the wrong type or violates a constraint, or an
            unknown key is given.
    """
    fields = _fields(cls)
    known = {f.name for f, *_ in fields}
    for key in values:
        if key not in known:
            raise ParameterError(key, values[key], f"unknown parameter (known: {', '.join(sorted(known))})")
    kwargs = {}
    for f, elem, is_array, spec in fields:
        value = values.get(f.name, f.default)
        kwargs[f.name] = _validate(f.name, value, elem, is_array, spec)
    return cls(**kwargs)


def format_config(config: Any, names: tuple[str, ...] | None = None) -> str:
    """``"a=1 b=x"`` for the given field names (all fields by default), for log lines."""
    if names is None:
        names = tuple(f.name for f in dataclasses.fields(config))
    parts = []
    for name in names:
        value = getattr(config, name)
        parts.append(f"{name}={list(value) if isinstance(value, tuple) else value}")
    return " ".join(parts)


def packaged_params_file(package: str, filename: str | None = None) -> pathlib.Path:
    """Path of the default params YAML shipped as package data (``<package>/config/<package>.yaml``).

    Uses importlib.resources, so it works in a venv without AMENT_PREFIX_PATH.
    """
    resource = importlib.resources.files(package) / "config" / (filename or f"{package}.yaml")
    path = pathlib.Path(str(resource))
    if not path.is_file():
        raise FileNotFoundError(f"{package} ships no params file {path}")
    return path


def read_params_file(path: str | pathlib.Path, node_name: str) -> dict[str, Any]:
    """The ``ros__parameters`` of ``node_name`` (or ``/**``) in a ROS 2 params YAML file."""
    data = yaml.safe_load(pathlib.Path(path).read_text()) or {}
    out: dict[str, Any] = {}
    for key in ("/**", node_name, "/" + node_name):
        section = data.get(key)
        if isinstance(section, dict):
            out.update(section.get("ros__parameters") or {})
    return out


# ----------------------------------------------------------------------------- ROS part

def declare_config(node: Any, cls: type[C]) -> C:
    """Declare one read-only ROS parameter per field of ``cls`` on ``node``, read and validate.

    Raises:
        ParameterError: a parameter override has the wrong type or an invalid value.
    """
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.parameter import Parameter

    ptypes = {
        (bool, False): Parameter.Type.BOOL,
        (int, False): Parameter.Type.INTEGER,
        (float, False): Parameter.Type.DOUBLE,
        (str, False): Parameter.Type.STRING,
        (bool, True): Parameter.Type.BOOL_ARRAY,
        (int, True): Parameter.Type.INTEGER_ARRAY,
        (float, True): Parameter.Type.DOUBLE_ARRAY,
        (str, True): Parameter.Type.STRING_ARRAY,
    }
    values: dict[str, Any] = {}
    for f, elem, is_array, spec in _fields(cls):
        ptype = ptypes[(elem, is_array)]
        constraints = []
        if spec.choices is not None:
            constraints.append("one of: " + ", ".join(map(str, spec.choices)))
        if spec.minimum is not None:
            constraints.append(f"{'>' if spec.exclusive_minimum else '>='} {spec.minimum}")
        if spec.non_empty:
            constraints.append("required, non-empty")
        if spec.length is not None:
            constraints.append(f"{spec.length} elements")
        # Doubles are dynamically typed so that integer overrides ("-p rate_factor:=0") are
        # accepted; config_from_values converts and checks them. read_only keeps them fixed.
        dynamic = elem is float
        descriptor = ParameterDescriptor(
            description=spec.description,
            additional_constraints="; ".join(constraints),
            read_only=True,
            dynamic_typing=dynamic,
        )
        if not dynamic:
            descriptor.type = ptype.value
        default = list(f.default) if is_array else f.default  # type: ignore[arg-type]
        # An empty array default has no inferable type: declare it typed and uninitialised
        # (dynamically typed doubles: untyped and unset, so that [] and integer arrays pass).
        initial = default
        if is_array and not default:
            initial = None if dynamic else ptype
        try:
            parameter = node.declare_parameter(f.name, initial, descriptor)
        except InvalidParameterTypeException as exc:
            raise ParameterError(f.name, _override_value(exc), f"wrong type, expected {ptype.name}") from None
        value = parameter.value
        if parameter.type_ == Parameter.Type.NOT_SET:
            value = f.default
        values[f.name] = list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value
    _refuse_unknown_overrides(node, cls)
    return config_from_values(cls, values)


def _refuse_unknown_overrides(node: Any, cls: type) -> None:
    """A parameter given to the node (``-p name:=value``, a params file) that it does not declare
    is a typo or a parameter of another node: an error naming it, never silently ignored.
    rclpy's own parameters (``use_sim_time``, ``qos_overrides.*``) are not ours to judge."""
    overrides = getattr(node, "_parameter_overrides", {}) or {}  # rclpy keeps them here (Jazzy)
    known = {f.name for f in dataclasses.fields(cls)}
    for name in sorted(overrides):
        if name in known or name.startswith("qos_overrides.") or node.has_parameter(name):
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1)
        if close:
            hint = f"; did you mean '{close[0]}'?"
        else:  # nothing alike (often another node's parameter): the nearest name, and all of them
            nearest = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.0)
            hint = (f"; the closest known is '{nearest[0]}'" if nearest else "") + f"; {cls.__name__} has: {', '.join(sorted(known))}"
        raise ParameterError(name, overrides[name].value, f"unknown parameter of this node{hint}")


def _override_value(exc: Exception) -> Any:
    parameter = getattr(exc, "parameter", None)
    value = getattr(parameter, "value", None)
    if value is not None:
        return value
    # rclpy's message: "Trying to set parameter 'x' to 'v' of type 'T', expecting type 'U'"
    text = str(exc)
    marker = "' to '"
    if marker in text:
        return text.split(marker, 1)[1].split("' of type", 1)[0]
    return text


def _check_scenario(value: str) -> str | None:
    known = builtin_names("scenarios")
    if value in known:
        return None
    if value.endswith((".yaml", ".yml")):
        return None if pathlib.Path(value).is_file() else f"scenario file not found: {value}"
    return f"not a built-in scenario {known} nor a .yaml file"


def duration_param() -> Any:
    """The ``duration`` parameter of the simulated devices: seconds of the scenario, 0 = all of it."""
    return param(0.0, "simulated session length [s] (device: sim); 0 = the whole scenario", minimum=0.0)


def min_subscribers_param() -> Any:
    """The ``min_subscribers`` parameter of the simulated devices (see dpos_ros.devices.sim_device)."""
    return param(
        0,
        "device: sim waits until every published topic but the latched datum has this many "
        "matched subscriptions (at most wait_subscribers_s) before it starts",
        minimum=0,
    )


def wait_subscribers_param() -> Any:
    """The ``wait_subscribers_s`` parameter of the simulated devices (see dpos_ros.devices.sim_device)."""
    return param(
        30.0,
        "longest wait [s] for min_subscribers before the simulated device starts anyway",
        minimum=0.0,
    )


def scenario_param(description: str = "simulator scenario (device: sim): built-in name or YAML path", default: str = "paper_su") -> Any:
    """The ``scenario`` parameter: a built-in scenario of the simulator or a user's YAML file
    (``default=''``: optional, '' = none)."""
    if default == "":
        return param("", description, check=lambda v: _check_scenario(v) if v else None)
    return param(default, description, non_empty=True, check=_check_scenario)
