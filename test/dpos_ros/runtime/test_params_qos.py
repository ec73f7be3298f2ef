"""dpos_ros.runtime.params (config dataclasses <-> parameters) and dpos_ros.contract.qos."""

from __future__ import annotations

import dataclasses
import importlib

import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from dpos_ros.contract import qos
from dpos_ros.runtime.params import (
    ParameterError,
    config_from_values,
    declare_config,
    packaged_params_file,
    param,
    read_params_file,
)

pytestmark = pytest.mark.ros

CONFIGS = {
    "pos_master_node": ("pos_master_node.params", "PosMasterConfig"),
    "pos_sub_node": ("pos_sub_node.params", "PosSubConfig"),
    "ifa_node": ("ifa_node.params", "IfaConfig"),
    "transfer_align_node": ("transfer_align_node.params", "TransferAlignConfig"),
}


def _config_class(package: str) -> type:
    module, name = CONFIGS[package]
    return getattr(importlib.import_module(module), name)


@dataclasses.dataclass(frozen=True)
class _Example:
    """A config for the tests of the machinery."""

    rate: float = param(1.0, "rate", minimum=0.0)
    count: int = param(3, "count", minimum=1)
    mode: str = param("a", "mode", choices=("a", "b"))
    flag: bool = param(False, "flag")
    vec: tuple[float, float] = param((1.0, 2.0), "vector", length=2)
    names: tuple[str, ...] = param((), "names")
    label: str = param("x", "label", non_empty=True)
    positive: float = param(1.0, "positive", minimum=0.0, exclusive_minimum=True)


def test_defaults_and_coercion():
    assert config_from_values(_Example, {}) == _Example()
    cfg = config_from_values(_Example, {"rate": 0, "vec": [3, 4], "names": ["p", "q"]})
    assert cfg.rate == 0.0 and isinstance(cfg.rate, float)
    assert cfg.vec == (3.0, 4.0) and cfg.names == ("p", "q")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.rate = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"rate": -1.0}, "'rate' = -1.0: must be >= 0.0"),
        ({"positive": 0.0}, "'positive' = 0.0: must be > 0.0"),
        ({"count": 0}, "'count' = 0: must be >= 1"),
        ({"count": 2.5}, "'count' = 2.5: expected an integer"),
        ({"flag": 1}, "'flag' = 1: expected a bool"),
        ({"rate": "fast"}, "'rate' = 'fast': expected a double"),
        ({"rate": float("nan")}, "'rate' = nan: must be finite"),
        ({"mode": "c"}, "'mode' = 'c': must be one of a, b"),
        ({"vec": [1.0]}, "'vec' = [1.0]: expected 2 elements"),
        ({"label": " "}, "'label' = ' ': must not be empty"),
        ({"nope": 1}, "'nope' = 1: unknown parameter"),
    ],
)
def test_invalid_values_name_parameter_and_value(values, message):
    with pytest.raises(ParameterError) as info:
        config_from_values(_Example, values)
    assert message in str(info.value)
    assert info.value.name == next(iter(values))


def test_declare_config_on_node(ros_context):
    from rclpy.node import Node

    node = Node(
        "params_test",
        context=ros_context,
        parameter_overrides=[Parameter("rate", value=0), Parameter("names", value=["a", "b"])],
    )
    try:
        cfg = declare_config(node, _Example)
        assert cfg == _Example(rate=0.0, names=("a", "b"))
        assert node.get_parameter("count").value == 3
        assert node.describe_parameter("count").read_only
    finally:
        node.destroy_node()


def test_declare_config_reports_wrong_type(ros_context):
    from rclpy.node import Node

    node = Node("params_type_test", context=ros_context, parameter_overrides=[Parameter("count", value="many")])
    try:
        with pytest.raises(ParameterError, match="'count' = 'many': wrong type, expected INTEGER"):
            declare_config(node, _Example)
    finally:
        node.destroy_node()


@pytest.mark.parametrize("package", sorted(CONFIGS))
def test_packaged_params_file_matches_defaults(package):
    path = packaged_params_file(package)
    values = read_params_file(path, package)
    assert values, f"{path} has no '{package}: ros__parameters:' section"
    cls = _config_class(package)
    if package == "pos_sub_node":
        assert "name" not in values  # required, set per instance
        values["name"] = "sub_r"
        expected = cls(name="sub_r")
    else:
        expected = cls()
    assert config_from_values(cls, values) == expected


@pytest.mark.parametrize("package", sorted(CONFIGS))
def test_config_classes_have_common_parameters(package):
    cls = _config_class(package)
    names = {f.name for f in dataclasses.fields(cls)}
    assert {"datum", "aircraft_config"} <= names
    assert cls.__doc__


def test_stream_qos_is_reliable_and_deep():
    for profile in (qos.SENSOR_QOS, qos.NAV_QOS):
        assert profile.reliability == ReliabilityPolicy.RELIABLE
        assert profile.history == HistoryPolicy.KEEP_LAST and profile.depth >= 1000
        assert profile.durability == DurabilityPolicy.VOLATILE


def test_latched_qos_is_transient_local():
    for profile in (qos.DATUM_QOS, qos.STATUS_QOS):
        assert profile.reliability == ReliabilityPolicy.RELIABLE
        assert profile.durability == DurabilityPolicy.TRANSIENT_LOCAL


def test_datum_parameter_empty_means_session_datum():
    from dpos_ros.runtime.params import datum_llh_rad
    from pos_master_node.params import PosMasterConfig

    assert PosMasterConfig().datum == ()
    assert datum_llh_rad(()) is None
    cfg = config_from_values(PosMasterConfig, {"datum": [40, 116, 500]})
    assert cfg.datum == (40.0, 116.0, 500.0)
    lat, lon, h = datum_llh_rad(cfg.datum)
    assert lat == pytest.approx(0.6981317007977318) and lon == pytest.approx(2.0245819323134224) and h == 500.0


@pytest.mark.parametrize(
    ("datum", "message"),
    [
        ([40.0, 116.0], "expected [] (the session's own datum) or [lat_deg, lon_deg, h_m]"),
        ([91.0, 116.0, 0.0], "latitude must be in [-90, 90] deg"),
        ([40.0, -181.0, 0.0], "longitude must be in [-180, 180] deg"),
        ([95.0, 200.0, 0.0], "latitude must be in [-90, 90] deg, got 95"),
        ([float("nan"), 116.0, 0.0], "must be finite"),
        ([40.0, 116.0, float("inf")], "must be finite"),
        ([40.0, 116.0, float("nan")], "must be finite"),
    ],
)
def test_datum_parameter_is_validated(datum, message):
    from pos_master_node.params import PosMasterConfig

    with pytest.raises(ParameterError, match="'datum'") as info:
        config_from_values(PosMasterConfig, {"datum": datum})
    assert message in str(info.value)


@pytest.mark.parametrize("override", [[], [40.0, 116.0, 500.0], [40, 116, 500]])
def test_datum_parameter_on_node(ros_context, override):
    from rclpy.node import Node

    from pos_sub_node.params import PosSubConfig

    node = Node("datum_test", context=ros_context,
                parameter_overrides=[Parameter("name", value="sub_r"), Parameter("datum", value=override)])
    try:
        assert declare_config(node, PosSubConfig).datum == tuple(float(x) for x in override)
    finally:
        node.destroy_node()


def test_fixed_size_tuples_need_their_length() -> None:
    """A ``tuple[float, float, float]`` field takes exactly 3 values (ifa_node's GNSS sigmas once
    accepted 2 and crashed at the first fix)."""
    from ifa_node.params import IfaConfig

    with pytest.raises(ParameterError, match=r"'gnss_pos_sigma_m' = \[1.0, 2.0\]: expected 3 elements"):
        config_from_values(IfaConfig, {"gnss_pos_sigma_m": [1.0, 2.0]})
    assert config_from_values(IfaConfig, {"gnss_vel_sigma_mps": [0.1, 0.2, 0.3]}).gnss_vel_sigma_mps == (0.1, 0.2, 0.3)


@pytest.mark.parametrize("package", sorted(CONFIGS))
def test_unknown_node_parameter_is_an_error(package: str, ros_context) -> None:
    """``-p rate_factr:=10.0`` is a typo: the node refuses to start and names it (never ignored)."""
    node_module = importlib.import_module(f"{package}.node")
    cls = next(v for k, v in vars(node_module).items() if isinstance(v, type) and k.endswith("Node") and v.__module__ == node_module.__name__)
    overrides = [Parameter("rate_factr", value=10.0)]
    if package == "pos_sub_node":
        overrides.append(Parameter("name", value="sub_r"))
    if package == "ifa_node":
        overrides.append(Parameter("scenario", value="paper_su"))
    with pytest.raises(ParameterError, match="'rate_factr' = 10.0: unknown parameter of this node"):
        cls(context=ros_context, parameter_overrides=overrides)
