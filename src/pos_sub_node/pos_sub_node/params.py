"""Configuration of pos_sub_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

import re
from dataclasses import dataclass

from dpos_ros.params import DEVICES, aircraft_config_param, datum_param, param, scenario_param

_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _check_name(name: str) -> str | None:
    if name and not _NAME_RE.match(name):
        return "must be a ROS name token (letters, digits, '_', starting with a letter)"
    return None


@dataclass(frozen=True)
class PosSubConfig:
    """Validated parameters of pos_sub_node.

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` frame origin.
        aircraft_config: aircraft YAML path, '' = built-in default.
        name: sub-IMU name (required): topic /sub_imu/<name>/imu, frame sub_imu_<name>;
            mount and lever arm come from the aircraft configuration.
        device: sensor data source: ``sim`` or ``ros``.
        scenario: simulator scenario; must match pos_master_node's.
        seed: simulator random seed; must match pos_master_node's (one flight).
        rate_factor: simulation speed, 1.0 = real time, 0 = as fast as possible.
        publish_truth: publish /truth/* for this sub-IMU (simulated devices only).
    """

    datum: tuple[float, float, float] = datum_param()
    aircraft_config: str = aircraft_config_param()
    name: str = param("", "sub-IMU name (required)", non_empty=True, check=_check_name)
    device: str = param("sim", "sensor data source", choices=DEVICES)
    scenario: str = scenario_param()
    seed: int = param(1, "simulator random seed (same seed in every node = one flight)")
    rate_factor: float = param(1.0, "simulation speed: 1.0 = real time, 0 = as fast as possible", minimum=0.0)
    publish_truth: bool = param(True, "publish /truth/* (simulated devices only)")
