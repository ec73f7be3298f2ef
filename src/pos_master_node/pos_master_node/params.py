"""Configuration of pos_master_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass

from dpos_ros.devices.relay import input_reliability_param, input_rotation_param
from dpos_ros.runtime.params import (
    DEVICES,
    aircraft_config_param,
    datum_param,
    duration_param,
    min_subscribers_param,
    param,
    scenario_param,
    wait_subscribers_param,
)

ALIGNMENTS = ("ifa", "given", "reference")


def _check_len(*allowed: int):
    def check(value: tuple[float, ...]) -> str | None:
        return None if len(value) in allowed else f"expected {' or '.join(str(n) for n in allowed)} values, got {len(value)}"

    return check


@dataclass(frozen=True)
class PosMasterConfig:
    """Validated parameters of pos_master_node.

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` frame origin, published on /dpos/datum;
            ``[]`` = the scenario's start point (``device: sim``) or the first valid /gnss/fix
            (``device: ros``).
        aircraft_config: aircraft configuration, built-in name or YAML path; '' = the scenario's own.
        device: sensor data source: ``sim`` (built-in simulator) or ``ros`` (relay real drivers'
            sensor_msgs/Imu, NavSatFix and TwistWithCovarianceStamped from the remappable topics
            ``imu_in``, ``fix_in``, ``vel_in``; dpos_ros.devices.relay).
        scenario: simulator scenario (``device: sim``).
        seed: simulator random seed; all nodes with the same seed see one flight.
        duration: simulated session length [s], 0 = the whole scenario.
        rate_factor: simulation speed, 1.0 = real time, 0 = as fast as subscribers keep up.
        alignment: ``ifa`` (wait for IFA corrections), ``given`` (configured initial state),
            ``reference`` (simulation only: truth + main-system noise).
        publish_truth: publish /truth/* (simulated devices only).
        min_subscribers: the simulated device starts publishing when every topic but the datum
            has this many matched subscriptions (0 = at once) ...
        wait_subscribers_s: ... or after this many seconds.
        initial_heading_error_deg: ``alignment: ifa`` in simulation: the mechanization starts from
            truth with this heading error [deg] (level errors 0); ``[]`` = the scenario's
            ``ifa.initial_heading_error_deg``, else 0.
        initial_state: ``alignment: given``: [lat_deg, lon_deg, h_m, vE, vN, vU, heading_deg,
            pitch_deg, roll_deg] at the session start (``device: ros``: at the first relayed IMU
            stamp; required); ``[]`` = truth (simulation). ``alignment: ifa`` with ``device: ros``:
            only its heading is used, when the ground speed is too low for the course.
        initial_sigma: 1 sigma [pos_m, vel_mps, heading_deg, pitch_deg, roll_deg] of /master/nav
            until the first /ifa/correction (then the filter's covariance); default: the
            ifa_node's prior.
        ring_s: seconds of IMU samples kept for re-integration after a correction.
        max_lead_s: ``rate_factor`` 0 with an ifa_node running: the simulated device waits while
            the mechanization is more than this many seconds ahead of the last correction (0 = never).
        input_reliability: ``device: ros``: QoS reliability of the driver subscriptions,
            ``best_effort`` (matches every driver) or ``reliable``.
        input_rotation_rpy_deg: ``device: ros``: [roll, pitch, yaw] [deg] of the driver's IMU axes
            in our FLU body axes (URDF rpy; FRD -> FLU = [180, 0, 0]); default identity.
        min_course_speed_mps: ``device: ros``, ``alignment: ifa``: the initial heading is the
            GNSS course over ground when the ground speed is at least this [m/s]; below it the
            ``initial_state`` heading is used, or the node waits for a faster fix.
        nav_delay_s: ``device: ros`` while an ifa_node aligns: a relayed IMU sample is integrated
            (and its /master/nav published) once IMU data this much newer [s] has been relayed and
            it was relayed this long ago in wall time (a replay as fast as possible), or
            the IMU has been silent for ``sources.NAV_FLUSH_S`` (wall clock: the end of the data). A GNSS receiver
            delivers its fix 50-100 ms after the fix's stamp; with a delay above that the fix is
            here before the samples after it are integrated, the node holds them until the
            ifa_node's correction, and every /master/nav message has every correction before it
            (pos_master_node.sources). 0 = as soon as relayed: the samples between a fix's stamp
            and its arrival lack its correction (counted, ``late_samples``).
        aligned_max_heading_sigma_deg: ``alignment: ifa``: an /ifa/status ALIGNED (or DEGRADED)
            carrying a heading sigma above this [deg] is refused (dpos_core.gates.check_aligned,
            counted ``gate/ifa_status/unsupported``), and /master/nav is flagged aligned only while
            its own covariance (the accepted corrections') has a heading sigma at most this; keep it
            at or above the ifa_node's ``aligned_heading_sigma_deg``.

    ``device: ros`` ignores ``scenario``, ``seed``, ``duration``, ``rate_factor``,
    ``publish_truth``, ``min_subscribers``, ``wait_subscribers_s``, ``initial_heading_error_deg``
    and ``max_lead_s``; ``device: sim`` ignores the ``input_*`` parameters,
    ``min_course_speed_mps`` and ``nav_delay_s``.
    """

    datum: tuple[float, ...] = datum_param()
    aircraft_config: str = aircraft_config_param("the aircraft of the scenario; device ros: no GNSS lever arm")
    device: str = param("sim", "sensor data source", choices=DEVICES)
    scenario: str = scenario_param()
    seed: int = param(1, "simulator random seed (same seed in every node = one flight)", minimum=0)
    duration: float = duration_param()
    rate_factor: float = param(1.0, "simulation speed: 1.0 = real time, 0 = as fast as possible", minimum=0.0)
    alignment: str = param("ifa", "initial alignment of the main POS", choices=ALIGNMENTS)
    publish_truth: bool = param(True, "publish /truth/* (simulated devices only)")
    min_subscribers: int = min_subscribers_param()
    wait_subscribers_s: float = wait_subscribers_param()
    initial_heading_error_deg: tuple[float, ...] = param(
        (), "alignment ifa (simulation): heading error [deg] of the initial state; [] = the scenario's", check=_check_len(0, 1))
    initial_state: tuple[float, ...] = param(
        (), "alignment given: [lat_deg, lon_deg, h_m, vE, vN, vU, heading_deg, pitch_deg, roll_deg]; [] = truth (simulation)",
        check=_check_len(0, 9))
    initial_sigma: tuple[float, ...] = param(
        (5.0, 0.5, 100.0, 1.0, 1.0), "1 sigma [pos_m, vel_mps, heading_deg, pitch_deg, roll_deg] of /master/nav before the first correction",
        minimum=0.0, exclusive_minimum=True, length=5)
    max_lead_s: float = param(2.0, "rate_factor 0 with an ifa_node: stay at most this many seconds ahead of its corrections (0 = no limit)", minimum=0.0)
    ring_s: float = param(60.0, "seconds of IMU samples kept for re-integration after an IFA correction", minimum=1.0)
    input_reliability: str = input_reliability_param()
    input_rotation_rpy_deg: tuple[float, float, float] = input_rotation_param()
    min_course_speed_mps: float = param(
        5.0, "device ros, alignment ifa: least ground speed [m/s] for the course over ground as initial heading", minimum=0.0)
    nav_delay_s: float = param(
        0.2, "device ros with an ifa_node aligning: integrate a relayed IMU sample once IMU data this much [s] newer came "
        "(or the IMU was silent for 2 s), so that late GNSS fixes arrive first and /master/nav has every correction before it",
        minimum=0.0)
    aligned_max_heading_sigma_deg: float = param(
        1.0, "alignment ifa: heading 1 sigma [deg] above which an ALIGNED /ifa/status (and /master/nav's own covariance) "
        "does not support the aligned flag", minimum=0.0, exclusive_minimum=True)
