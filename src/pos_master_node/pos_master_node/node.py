"""pos_master_node — the main POS.

The node is a *source* of the master device's data and a *navigator* that makes /master/nav
(nav_msgs/Odometry, frame ``enu``, child ``master_imu``), each chosen once from the validated
parameters and wired together here:

``device`` (pos_master_node.sources)
    ``sim``: the simulated master device, published live (dpos_ros.devices.sim_device): /dpos/datum,
    /master/imu, /gnss/fix, /gnss/vel, /truth/*, /session/end, byte for byte as ``dpos-sim``.
    ``ros``: the real drivers relayed (dpos_ros.devices.relay): ``imu_in``, ``fix_in``, ``vel_in``
    -> /master/imu, /gnss/fix, /gnss/vel, /dpos/datum from the ``datum`` parameter or the first fix.
``alignment`` (pos_master_node.navigators)
    ``reference`` (simulation only): the simulated device's own /master/nav, truth + the paper's
    main-system noise. ``ifa``: the master IMU mechanized from a coarse initial state with the
    ifa_node's corrections, flagged UNALIGNED on /pos_master/status until /ifa/status ALIGNED.
    ``given``: the same mechanization from a configured ``initial_state``, flagged GIVEN.

The source hands the navigator the IMU samples (simulation: a tap of the device thread; relay: a
timer over the queued samples) and the data of its initial state; the navigator subscribes to
/ifa/correction, /ifa/imu_bias and /ifa/status and publishes /pos_master/status. The modules'
docstrings give the details. An invalid parameter raises ParameterError (exit status 2 from
``main``), before anything is published.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node

from dpos_core.ifa.mechanization import MasterMechanization
from dpos_ros.devices.relay import DeviceRelay
from dpos_ros.devices.sim_device import SimDevice, use_device_fastdds_profile
from dpos_ros.runtime.node_main import run_node
from dpos_ros.runtime.params import ParameterError, declare_config
from pos_master_node import NODE_NAME
from pos_master_node.navigators import GivenNavigator, IfaNavigator, Navigator, ReferenceNavigator
from pos_master_node.params import PosMasterConfig
from pos_master_node.sources import RelaySource, SimSource, Source

__all__ = ["PosMasterNode", "NODE_NAME", "NAVIGATORS", "SOURCES", "main"]

#: ``alignment`` -> the navigator (pure: reads the parameters)
NAVIGATORS: dict[str, Callable[[Node, PosMasterConfig], Navigator]] = {
    "reference": ReferenceNavigator, "given": GivenNavigator, "ifa": IfaNavigator}
#: ``device`` -> the source (checks what the device needs of the parameters and the navigator)
SOURCES: dict[str, Callable[[Node, PosMasterConfig, Navigator], Source]] = {"sim": SimSource, "ros": RelaySource}


class PosMasterNode(Node):
    """The main POS node; see the module docstring.

    Attributes:
        config: the validated parameters.
        navigator: what makes /master/nav (``alignment``).
        source: where the data come from (``device``).

    Raises:
        ParameterError: an invalid parameter, an unknown scenario/aircraft, a duration longer than
            the scenario; with ``device: ros``: ``alignment: reference`` or ``alignment: given``
            without ``initial_state``.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: PosMasterConfig = declare_config(self, PosMasterConfig)
            self.navigator: Navigator = NAVIGATORS[self.config.alignment](self, self.config)
            self.source: Source = SOURCES[self.config.device](self, self.config, self.navigator)
        except ParameterError:
            super().destroy_node()
            raise
        self.navigator.attach()  # the feedback subscriptions and the first status, before any data
        self.source.start()

    # ------------------------------------------------------------------ views (tests, tools)
    @property
    def session(self) -> Any:
        """The simulated session (``device: sim``), else None."""
        return self.source.session

    @property
    def device(self) -> SimDevice | None:
        """The simulated device (``device: sim``), else None."""
        return self.source.device

    @property
    def relay(self) -> DeviceRelay | None:
        """The driver relay (``device: ros``), else None."""
        return self.source.relay

    @property
    def nav_pub(self) -> Any:
        """The /master/nav publisher of ``device: ros`` (the simulated device's tap publishes its own), else None."""
        return self.source.nav_pub

    @property
    def mech(self) -> MasterMechanization | None:
        """The mechanization (``alignment: ifa | given``, once started), else None."""
        return self.navigator.mech

    @property
    def aligned(self) -> bool:
        """The flag of /master/nav."""
        return self.navigator.aligned

    @property
    def imu_before_start(self) -> int:
        """Relayed IMU samples not integrated because they precede the start."""
        return self.navigator.imu_before_start

    def destroy_node(self) -> None:
        self.source.stop()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_master_node``."""
    use_device_fastdds_profile()  # prompt acknowledgements for the device's flow control
    return run_node(PosMasterNode, NODE_NAME, argv)
