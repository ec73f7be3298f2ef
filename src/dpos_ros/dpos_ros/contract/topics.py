"""Topic names and message types of the interface contract (docs/design.md "Topics").

The one place that spells them: nodes, devices, recorder, player and products import these.
Frame names are in :mod:`dpos_ros.contract.conversions` (``WORLD_FRAME``, ``MASTER_FRAME``, ...).
"""

from __future__ import annotations

import importlib

# --------------------------------------------------------------------------- message types
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
TWIST_COV = "geometry_msgs/msg/TwistWithCovarianceStamped"
HEADER = "std_msgs/msg/Header"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
FLUID_PRESSURE = "sensor_msgs/msg/FluidPressure"

# --------------------------------------------------------------------------- topics
DATUM = "/dpos/datum"
MASTER_IMU = "/master/imu"
GNSS_FIX = "/gnss/fix"
GNSS_VEL = "/gnss/vel"
MASTER_NAV = "/master/nav"
SESSION_END = "/session/end"
IFA_CORRECTION = "/ifa/correction"
IFA_IMU_BIAS = "/ifa/imu_bias"
IFA_STATUS = "/ifa/status"
POS_MASTER_STATUS = "/pos_master/status"
TRANSFER_ALIGN_STATUS = "/transfer_align/status"
TRUTH_MASTER = "/truth/master"
#: SAR scene-matching fixes (horizontal position and heading, frame enu) and the barometer (frame baro)
SAR_FIX = "/sar/fix"
BARO_PRESSURE = "/baro/pressure"
#: sar_nav_node's outputs: the SAR/baro-aided navigation of the main POS and its status
SAR_NAV = "/sar_nav/nav"
SAR_NAV_STATUS = "/sar_nav/status"
#: service of transfer_align_node (std_srvs/Trigger): ends the session as /session/end does
FINALIZE_SERVICE = "/transfer_align_node/finalize"


# --------------------------------------------------------------------------- QoS (without rclpy)
#: Queue depth of the sensor and navigation streams (>= 1000 required by the design).
STREAM_DEPTH = 5000

#: The design's QoS of each kind, as (history, depth, reliability, durability): the numbers
#: :mod:`dpos_ros.contract.qos` makes rclpy profiles of, and the bag writers store as each topic's
#: ``offered_qos_profiles`` (so that ``ros2 bag play`` latches the datum and the statuses again).
QOS_KINDS: dict[str, tuple[str, int, str, str]] = {
    "sensor": ("keep_last", STREAM_DEPTH, "reliable", "volatile"),
    "nav": ("keep_last", STREAM_DEPTH, "reliable", "volatile"),
    "datum": ("keep_last", 1, "reliable", "transient_local"),
    "status": ("keep_last", 10, "reliable", "transient_local"),
}


def qos_kind(topic: str) -> str:
    """The design's QoS kind of a topic: ``datum``, ``status`` (both latched) or ``sensor`` (the
    streams; ``nav`` is the same profile)."""
    if topic == DATUM:
        return "datum"
    if topic.endswith("/status"):
        return "status"
    return "sensor"


def sub_imu(name: str) -> str:
    """``/sub_imu/<name>/imu``: one sub-IMU's samples."""
    return f"/sub_imu/{name}/imu"


def antenna_odom(name: str) -> str:
    """``/antenna/<name>/odom``: one antenna's smoothed pose."""
    return f"/antenna/{name}/odom"


def antenna_fix(name: str) -> str:
    """``/antenna/<name>/fix``: one antenna's smoothed position as sensor_msgs/NavSatFix (products' bag)."""
    return f"/antenna/{name}/fix"


def truth_sub_imu(name: str) -> str:
    """``/truth/sub_imu/<name>`` (simulated devices only)."""
    return f"/truth/sub_imu/{name}"


def truth_antenna(name: str) -> str:
    """``/truth/antenna/<name>`` (simulated devices only)."""
    return f"/truth/antenna/{name}"


def message_class(msgtype: str) -> type:
    """The Python message class of ``pkg/msg/Name`` (rosidl_runtime_py when installed)."""
    try:
        from rosidl_runtime_py.utilities import get_message
    except ImportError:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    return get_message(msgtype)
