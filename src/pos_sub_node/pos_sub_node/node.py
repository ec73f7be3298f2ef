"""pos_sub_node — one sub-IMU device per node instance.

``device: sim`` (default) publishes the simulated sub-IMU ``name`` live (dpos_ros.devices.sim_device):
/sub_imu/<name>/imu and, with ``publish_truth``, /truth/sub_imu/<name> and
/truth/antenna/<its antennas> — byte for byte what ``dpos-sim`` writes for the same scenario,
aircraft, seed, duration and datum, so that it and pos_master_node show one flight. When
everything is published the node stays up until SIGINT/SIGTERM.

``device: ros`` relays a real IMU driver (dpos_ros.devices.relay.DeviceRelay): every good
sensor_msgs/Imu on the relative topic ``imu_in`` (remap it to the driver's topic) is republished
on /sub_imu/<name>/imu with frame ``sub_imu_<name>``, its stamp kept, rotated into our FLU body axes
by ``input_rotation_rpy_deg``; NaN, duplicate or out-of-order stamps and unavailable fields are
rejected and counted, gaps are counted; the counts are on the DiagnosticArray ``/<node name>/status``
(1 Hz, latched). ``input_reliability`` selects the subscription's QoS. The simulator parameters
(scenario, seed, duration, rate_factor, publish_truth, min_subscribers, wait_subscribers_s, datum)
do not apply and are ignored (an info line names those that were set). With ``aircraft_config``
set, ``name`` must be one of its sub-IMUs.

Run one instance per sub-IMU, each with its own ``name`` and node name::

    pos_sub_node --ros-args -r __node:=sub_r -p name:=sub_r -p aircraft_config:=paper_su_pair
    pos_sub_node --ros-args -r __node:=sub_r -p name:=sub_r -p device:=ros -r imu_in:=/vn100/imu \\
        -p input_rotation_rpy_deg:="[180.0, 0.0, 0.0]"
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from rclpy.node import Node

from dpos_core.config import ConfigError, load_aircraft
from dpos_ros.contract import topics as T
from dpos_ros.contract.conversions import sub_imu_frame
from dpos_ros.devices.relay import DeviceRelay, Route, rotation_from_rpy_deg
from dpos_ros.devices.sim_device import SimDevice
from dpos_ros.devices.sim_session import load_sim_session
from dpos_ros.devices.sim_streams import device_streams, session_id
from dpos_ros.io.flow import use_device_fastdds_profile
from dpos_ros.runtime.node_main import run_node
from dpos_ros.runtime.params import ParameterError, datum_llh_rad, declare_config, format_config
from pos_sub_node.params import PosSubConfig

NODE_NAME = "pos_sub_node"
#: The driver topic of ``device: ros`` (relative: remap it, ``-r imu_in:=/driver/imu``).
IMU_INPUT = "imu_in"
#: Parameters of the simulated device only (ignored by ``device: ros``).
SIM_ONLY = ("datum", "scenario", "seed", "duration", "rate_factor", "publish_truth", "min_subscribers",
            "wait_subscribers_s")


class PosSubNode(Node):
    """One sub-IMU device; see the module docstring.

    Raises:
        ParameterError: an invalid parameter, a ``name`` that is not a sub-IMU of the aircraft,
            an unknown scenario/aircraft, or a duration longer than the scenario (``device: sim``).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.device: SimDevice | None = None
        self.relay: DeviceRelay | None = None
        try:
            self.config: PosSubConfig = declare_config(self, PosSubConfig)
            cfg = self.config
            if cfg.device == "ros":
                aircraft = self._load_aircraft(cfg.aircraft_config) if cfg.aircraft_config else None
            else:
                self.session = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
                aircraft = self.session.scenario.aircraft
            names = [] if aircraft is None else [s.name for s in aircraft.sub_imus]
            if aircraft is not None and cfg.name not in names:
                raise ParameterError(
                    "name", cfg.name,
                    f"aircraft {aircraft.name!r} has no sub-IMU {cfg.name!r}; its sub-IMUs: {', '.join(names) or 'none'}"
                    " (aircraft_config selects another aircraft)",
                )
        except ParameterError:
            self.destroy_node()
            raise
        if cfg.device == "ros":
            self._start_relay()
        else:
            self._start_sim()

    @staticmethod
    def _load_aircraft(aircraft_config: str) -> Any:
        try:
            return load_aircraft(aircraft_config)
        except ConfigError as exc:
            raise ParameterError("aircraft_config", aircraft_config, str(exc)) from None

    def _start_relay(self) -> None:
        cfg = self.config
        log = self.get_logger()
        defaults = PosSubConfig(name=cfg.name)
        overridden = [f.name for f in dataclasses.fields(cfg)
                      if f.name in SIM_ONLY and getattr(cfg, f.name) != getattr(defaults, f.name)]
        if overridden:
            log.info(f"device: ros ignores the simulator parameters {format_config(cfg, tuple(overridden))}")
        rotation = None if not any(cfg.input_rotation_rpy_deg) else rotation_from_rpy_deg(cfg.input_rotation_rpy_deg)
        route = Route("imu", IMU_INPUT, T.sub_imu(cfg.name), sub_imu_frame(cfg.name))
        self.relay = DeviceRelay(self, [route], input_reliability=cfg.input_reliability, R_out_in=rotation)
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('name', 'device', 'aircraft_config', 'input_reliability', 'input_rotation_rpy_deg'))}"
            f" -> relaying {self.relay.describe()}; status on {self.get_fully_qualified_name()}/status"
        )

    def _start_sim(self) -> None:
        cfg = self.config
        session = self.session
        log = self.get_logger()
        topics = [T.sub_imu(cfg.name)]
        if cfg.publish_truth:
            topics.append(T.truth_sub_imu(cfg.name))
            topics += [T.truth_antenna(a.name) for a in session.scenario.aircraft.antennas if a.sub_imu == cfg.name]
        datum_rad = datum_llh_rad(cfg.datum)
        datum = None if datum_rad is None else np.asarray(datum_rad, dtype=float)
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('name', 'device', 'scenario', 'aircraft_config', 'seed', 'duration', 'rate_factor', 'publish_truth'))}"
            f" datum={list(cfg.datum) if cfg.datum else 'scenario start'}: session {session_id(session)},"
            f" aircraft {session.scenario.aircraft.name}, {session.duration_s:g} s -> publishing {', '.join(topics)}"
        )

        def streams():
            return device_streams(session, f"sub_imu/{cfg.name}", truth=cfg.publish_truth, datum_llh=datum)

        def finished(device: SimDevice) -> None:
            log.info(f"sub-IMU {cfg.name}: session {session_id(session)} ended ({device.published} messages published)")

        self.device = SimDevice(
            self, streams, cfg.rate_factor, min_subscribers=cfg.min_subscribers,
            wait_subscribers_s=cfg.wait_subscribers_s, on_finished=finished,
        ).start()

    def destroy_node(self) -> None:
        if self.device is not None:
            self.device.stop()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_sub_node``."""
    use_device_fastdds_profile()  # prompt acknowledgements for the device's flow control
    return run_node(PosSubNode, NODE_NAME, argv)
