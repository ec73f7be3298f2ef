"""Configuration of pos_sub_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

import re
from dataclasses import dataclass

from dpos_ros.devices.relay import input_reliability_param, input_rotation_param
from dpos_ros.runtime.params import (
    DEVICES,
    aircraft_config_param,
    datum_param,
    duration_param,
    min_subscribers_param,
    param,
    scenario_param,
    wait_subscribers_param,
)

_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _check_name(name: str) -> str | None:
    if name and not _NAME_RE.match(name):
        return "must be a ROS name token (letters, digits, '_', starting with a letter)"
    return None


@dataclass(frozen=True)
class PosSubConfig:
    """Validated parameters of pos_sub_node.

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` frame origin (of the /truth/* poses);
            ``[]`` = the scenario's start point. Must match pos_master_node's.
        aircraft_config: aircraft configuration, built-in name or YAML path; '' = the scenario's own.
        name: sub-IMU name (required), one of the aircraft's sub-IMUs: topic /sub_imu/<name>/imu,
            frame sub_imu_<name>; mount and lever arm come from the aircraft configuration.
        device: sensor data source: ``sim`` (the built-in simulator) or ``ros`` (relay a driver's
            sensor_msgs/Imu from the remappable topic ``imu_in``, dpos_ros.devices.relay).
        scenario: simulator scenario; must match pos_master_node's.
        seed: simulator random seed; must match pos_master_node's (one flight).
        duration: simulated session length [s], 0 = the whole scenario; must match pos_master_node's.
        rate_factor: simulation speed, 1.0 = real time, 0 = as fast as possible.
        publish_truth: publish /truth/* for this sub-IMU (simulated devices only).
        min_subscribers: the simulated device starts publishing when every topic has this many
            matched subscriptions (0 = at once) ...
        wait_subscribers_s: ... or after this many seconds.
        input_reliability: ``device: ros``: QoS reliability of the ``imu_in`` subscription,
            ``best_effort`` (matches every driver) or ``reliable``.
        input_rotation_rpy_deg: ``device: ros``: [roll, pitch, yaw] [deg] of the driver's IMU axes
            in our FLU body axes (URDF rpy; FRD -> FLU = [180, 0, 0]); default identity.

    ``device: ros`` ignores ``datum``, ``scenario``, ``seed``, ``duration``, ``rate_factor``,
    ``publish_truth``, ``min_subscribers`` and ``wait_subscribers_s``; ``device: sim`` ignores the
    ``input_*`` parameters.
    """

    datum: tuple[float, ...] = datum_param()
    aircraft_config: str = aircraft_config_param("the aircraft of the scenario")
    name: str = param("", "sub-IMU name (required)", non_empty=True, check=_check_name)
    device: str = param("sim", "sensor data source", choices=DEVICES)
    scenario: str = scenario_param()
    seed: int = param(1, "simulator random seed (same seed in every node = one flight)", minimum=0)
    duration: float = duration_param()
    rate_factor: float = param(1.0, "simulation speed: 1.0 = real time, 0 = as fast as possible", minimum=0.0)
    publish_truth: bool = param(True, "publish /truth/* (simulated devices only)")
    min_subscribers: int = min_subscribers_param()
    wait_subscribers_s: float = wait_subscribers_param()
    input_reliability: str = input_reliability_param()
    input_rotation_rpy_deg: tuple[float, float, float] = input_rotation_param()
