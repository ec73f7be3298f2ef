"""dpos_core: pure navigation and estimation algorithms for the airborne distributed POS.

numpy / scipy (and numba in private kernels) only: no rclpy, no *_msgs, no rosbags import.
"""

__version__ = "0.1.0"
