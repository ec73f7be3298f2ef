"""pos_sub_node — one sub-IMU device per node instance.

``device: sim`` publishes the simulated sub-IMU ``name`` live (dpos_ros.sim_device):
/sub_imu/<name>/imu and, with ``publish_truth``, /truth/sub_imu/<name> and
/truth/antenna/<its antennas> — byte for byte what ``dpos-sim`` writes for the same scenario,
aircraft, seed, duration and datum, so that it and pos_master_node show one flight. When
everything is published the node stays up until SIGINT/SIGTERM. ``device: ros`` (real drivers)
is not implemented yet.

Run one instance per sub-IMU, each with its own ``name`` and node name::

    pos_sub_node --ros-args -r __node:=sub_r -p name:=sub_r -p aircraft_config:=paper_su_pair
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, datum_llh_rad, declare_config, format_config
from dpos_ros.sim_device import SimDevice, load_sim_session, use_device_fastdds_profile
from pos_sub_node.params import PosSubConfig

NODE_NAME = "pos_sub_node"


class PosSubNode(Node):
    """One sub-IMU device; see the module docstring.

    Raises:
        ParameterError: an invalid parameter, a ``name`` that is not a sub-IMU of the aircraft,
            an unknown scenario/aircraft, a duration longer than the scenario, or ``device: ros``.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.device: SimDevice | None = None
        try:
            self.config: PosSubConfig = declare_config(self, PosSubConfig)
            cfg = self.config
            if cfg.device != "sim":
                raise ParameterError(
                    "device", cfg.device, "real drivers (device: ros) are not implemented yet; use device:=sim"
                )
            self.session = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
            aircraft = self.session.scenario.aircraft
            names = [s.name for s in aircraft.sub_imus]
            if cfg.name not in names:
                raise ParameterError(
                    "name", cfg.name,
                    f"aircraft {aircraft.name!r} has no sub-IMU {cfg.name!r}; its sub-IMUs: {', '.join(names) or 'none'}"
                    " (aircraft_config selects another aircraft)",
                )
        except ParameterError:
            self.destroy_node()
            raise
        self._start_sim()

    def _start_sim(self) -> None:
        from dpos_ros.sim_streams import device_streams, session_id

        cfg = self.config
        session = self.session
        log = self.get_logger()
        topics = [f"/sub_imu/{cfg.name}/imu"]
        if cfg.publish_truth:
            topics.append(f"/truth/sub_imu/{cfg.name}")
            topics += [f"/truth/antenna/{a.name}" for a in session.scenario.aircraft.antennas if a.sub_imu == cfg.name]
        datum = datum_llh_rad(cfg.datum)
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
