"""ifa_node — stub: declares and validates its parameters, logs its plan, spins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, declare_config, format_config
from ifa_node.params import IfaConfig

NODE_NAME = "ifa_node"


class IfaNode(Node):
    """In-flight alignment node (stub until its issue lands)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: IfaConfig = declare_config(self, IfaConfig)
        except ParameterError:
            self.destroy_node()
            raise
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(self.config, ('method', 'window'))}"
            " -> would subscribe /master/nav, /master/imu, /gnss/fix, /gnss/vel"
            " and publish /ifa/correction, /ifa/imu_bias, /ifa/status (stub: not implemented yet)"
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``ifa_node``."""
    return run_node(IfaNode, NODE_NAME, argv)
