"""pos_sub_node — stub: declares and validates its parameters, logs its plan, spins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, declare_config, format_config
from pos_sub_node.params import PosSubConfig

NODE_NAME = "pos_sub_node"


class PosSubNode(Node):
    """One sub-IMU device (stub until its issue lands).

    Run one instance per sub-IMU, each with its own ``name`` (and node name, e.g.
    ``--ros-args -r __node:=sub_r -p name:=sub_r``).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: PosSubConfig = declare_config(self, PosSubConfig)
        except ParameterError:
            self.destroy_node()
            raise
        cfg = self.config
        topics = [f"/sub_imu/{cfg.name}/imu"]
        if cfg.publish_truth and cfg.device == "sim":
            topics.append("/truth/...")
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(cfg, ('name', 'device', 'scenario', 'seed', 'rate_factor', 'publish_truth'))}"
            f" -> would publish {', '.join(topics)} (stub: not implemented yet)"
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_sub_node``."""
    return run_node(PosSubNode, NODE_NAME, argv)
