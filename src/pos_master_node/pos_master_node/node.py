"""pos_master_node — stub: declares and validates its parameters, logs its plan, spins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, declare_config, format_config
from pos_master_node.params import PosMasterConfig

NODE_NAME = "pos_master_node"


class PosMasterNode(Node):
    """The main POS node (stub until its issue lands)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: PosMasterConfig = declare_config(self, PosMasterConfig)
        except ParameterError:
            self.destroy_node()
            raise
        cfg = self.config
        topics = ["/dpos/datum", "/master/imu", "/gnss/fix", "/gnss/vel", "/master/nav", "/session/end"]
        if cfg.publish_truth and cfg.device == "sim":
            topics.append("/truth/...")
        self.get_logger().info(
            f"{NODE_NAME}: {format_config(cfg, ('device', 'scenario', 'seed', 'rate_factor', 'alignment', 'publish_truth'))}"
            f" datum={list(cfg.datum)} -> would publish {', '.join(topics)}"
            f" and subscribe /ifa/correction (stub: not implemented yet)"
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``pos_master_node``."""
    return run_node(PosMasterNode, NODE_NAME, argv)
