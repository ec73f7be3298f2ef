"""``dpos-ifa``, the in-flight alignment of a recording offline with ifa_node's parameter file:
the command is :mod:`dpos_ros.cli.ifa`; this module gives it the node's configuration
(:class:`ifa_node.params.IfaConfig`), which the shared library does not import (node packages sit
above it, test/test_layering.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.config.aircraft import AircraftConfig
from dpos_core.errors import InputError
from dpos_core.ifa.model import IfaFilterConfig
from dpos_core.units import FloatArray
from dpos_ros.cli import ifa
from ifa_node.params import IfaConfig


def load_config(params_file: Path, method: str | None) -> tuple[IfaFilterConfig, AircraftConfig, str, FloatArray]:
    """ifa_node's parameter file as the core's settings (:data:`dpos_ros.cli.ifa.ConfigLoader`): the filter
    configuration, the aircraft (``aircraft_config``, looked for beside the file too), the method
    (``method`` overrides the file's) and the GNSS lever arm [m] (3,); InputError naming what is wrong."""
    try:
        node_cfg = IfaConfig.from_params_file(params_file)
    except ValueError as e:
        raise InputError(str(e)) from None
    if not node_cfg.aircraft_config:
        raise InputError(f"{params_file}: aircraft_config is required (the vehicle file: IMU model and GNSS lever arm)")
    ac_path = Path(node_cfg.aircraft_config)
    if not ac_path.is_absolute() and not ac_path.exists():
        beside = params_file.parent / ac_path.name
        ac_path = beside if beside.exists() else ac_path
    try:
        aircraft = load_aircraft(ac_path if ac_path.exists() else node_cfg.aircraft_config)
    except ConfigError as e:
        raise InputError(str(e)) from None
    return node_cfg.core_config(aircraft.master_imu), aircraft, method or node_cfg.method, np.asarray(aircraft.gnss_lever_arm_m, dtype=float)


def main(argv: list[str] | None = None) -> int:
    """Console script ``dpos-ifa`` (:func:`dpos_ros.cli.ifa.main`)."""
    return ifa.main(argv, load_config)


if __name__ == "__main__":
    raise SystemExit(main())
