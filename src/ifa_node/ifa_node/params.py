"""Configuration of ifa_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass

from dpos_ros.params import aircraft_config_param, datum_param, param

METHODS = ("add2", "dd2", "aekf")


@dataclass(frozen=True)
class IfaConfig:
    """Validated parameters of ifa_node.

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` frame origin.
        aircraft_config: aircraft YAML path, '' = built-in default.
        method: alignment filter: ``add2`` (default), ``dd2`` or ``aekf``.
        window: window length of the adaptive estimation, in GNSS epochs (>= 2).
    """

    datum: tuple[float, float, float] = datum_param()
    aircraft_config: str = aircraft_config_param()
    method: str = param("add2", "in-flight alignment filter", choices=METHODS)
    window: int = param(10, "window length of the adaptive estimation (GNSS epochs)", minimum=2)
