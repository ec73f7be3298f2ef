"""transfer_align_node — stub: declares and validates its parameters, logs its plan, spins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dpos_ros.node_main import run_node
from dpos_ros.params import ParameterError, declare_config, format_config
from transfer_align_node.params import TransferAlignConfig

NODE_NAME = "transfer_align_node"


class TransferAlignNode(Node):
    """Transfer-alignment node (stub until its issue lands)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.config: TransferAlignConfig = declare_config(self, TransferAlignConfig)
        except ParameterError:
            self.destroy_node()
            raise
        cfg = self.config
        subs = ", ".join(f"/sub_imu/{n}/imu" for n in cfg.sub_imus) or "/sub_imu/*/imu"
        self.get_logger().info(
            f"{NODE_NAME}: "
            f"{format_config(cfg, ('method', 'particles', 'filter_rate_hz', 'output_dir', 'output_rate_hz', 'sub_imus'))}"
            f" -> would subscribe /master/nav, {subs}, /session/end, serve /{NODE_NAME}/finalize"
            " and publish /antenna/<name>/odom, /transfer_align/status (stub: not implemented yet)"
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``transfer_align_node``."""
    return run_node(TransferAlignNode, NODE_NAME, argv)
