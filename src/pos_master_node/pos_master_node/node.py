"""pos_master_node — the main POS.

``device: sim`` publishes the simulated master device live (dpos_ros.sim_device): the latched
/dpos/datum, /master/imu, /gnss/fix, /gnss/vel, /master/nav (``alignment: reference`` only),
/truth/master and /truth/antenna/<antennas without IMU> (``publish_truth``), and /session/end
after the last sample. The bytes are those of ``dpos-sim`` for the same scenario, aircraft,
seed, duration and datum. When everything is published the node stays up (late subscribers of
the latched datum still get it) until SIGINT/SIGTERM.

Not yet: the master mechanization with IFA feedback (``alignment: ifa`` / ``given`` publish no
/master/nav until in-flight alignment lands) and ``device: ros`` (real drivers).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, datum_llh_rad, declare_config, format_config
from dpos_ros.sim_device import SimDevice, load_sim_session, use_device_fastdds_profile
from pos_master_node.params import PosMasterConfig

NODE_NAME = "pos_master_node"
NAV_TOPIC = "/master/nav"


class PosMasterNode(Node):
    """The main POS node; see the module docstring.

    Raises:
        ParameterError: an invalid parameter, an unknown scenario/aircraft, a duration longer than
            the scenario, or ``device: ros`` (not implemented yet).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.device: SimDevice | None = None
        try:
            self.config: PosMasterConfig = declare_config(self, PosMasterConfig)
            cfg = self.config
            if cfg.device != "sim":
                raise ParameterError(
                    "device", cfg.device, "real drivers (device: ros) are not implemented yet; use device:=sim"
                )
            self.session = load_sim_session(cfg.scenario, cfg.aircraft_config, cfg.seed, cfg.duration)
        except ParameterError:
            self.destroy_node()
            raise
        self._start_sim()

    def _start_sim(self) -> None:
        from dpos_ros.sim_streams import device_streams, session_id

        cfg = self.config
        session = self.session
        log = self.get_logger()
        with_nav = cfg.alignment == "reference"
        topics = ["/dpos/datum", "/master/imu", "/gnss/fix", "/gnss/vel"]
        if with_nav:
            topics.append(NAV_TOPIC)
        if cfg.publish_truth:
            topics.append("/truth/master")
            topics += [f"/truth/antenna/{a.name}" for a in session.scenario.aircraft.antennas if a.sub_imu is None]
        topics.append("/session/end")
        datum = datum_llh_rad(cfg.datum)
        log.info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'scenario', 'aircraft_config', 'seed', 'duration', 'rate_factor', 'alignment', 'publish_truth'))}"
            f" datum={list(cfg.datum) if cfg.datum else 'scenario start'}: session {session_id(session)},"
            f" aircraft {session.scenario.aircraft.name}, {session.duration_s:g} s -> publishing {', '.join(topics)}"
        )
        if not with_nav:
            log.warning(
                f"alignment '{cfg.alignment}': {NAV_TOPIC} is not produced until the master mechanization with "
                f"in-flight alignment lands; use alignment:=reference for the simulated reference navigation"
            )

        def streams():
            out = device_streams(session, "master", truth=cfg.publish_truth, datum_llh=datum)
            return [s for s in out if with_nav or s.topic != NAV_TOPIC]

        def finished(device: SimDevice) -> None:
            log.info(
                f"session {session_id(session)} ended ({device.published} messages published); staying up so that "
                f"late subscribers get the latched /dpos/datum (SIGINT/SIGTERM to stop)"
            )

        self.device = SimDevice(
            self, streams, cfg.rate_factor, min_subscribers=cfg.min_subscribers,
            wait_subscribers_s=cfg.wait_subscribers_s, on_finished=finished,
        ).start()

    def destroy_node(self) -> None:
        if self.device is not None:
            self.device.stop()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_master_node``."""
    use_device_fastdds_profile()  # prompt acknowledgements for the device's flow control
    return run_node(PosMasterNode, NODE_NAME, argv)
