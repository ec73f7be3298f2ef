"""dpos_ros: shared ROS 2 glue of the dpos workspace (QoS, parameters, node entry points).

Everything that touches rclpy or message types and is used by more than one node package
lives here, so that dpos_core stays free of ROS.
"""

__version__ = "0.1.0"
