"""Configuration of pos_master_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass

from dpos_ros.params import (
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
            ``[]`` = the scenario's start point (``device: sim``).
        aircraft_config: aircraft configuration, built-in name or YAML path; '' = the scenario's own.
        device: sensor data source: ``sim`` (built-in simulator) or ``ros`` (driver topics, not
            implemented yet).
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
            pitch_deg, roll_deg] at the session start; ``[]`` = truth (simulation).
        initial_sigma: 1 sigma [pos_m, vel_mps, heading_deg, pitch_deg, roll_deg] of /master/nav
            until the first /ifa/correction (then the filter's covariance); default: the
            ifa_node's prior.
        ring_s: seconds of IMU samples kept for re-integration after a correction.
        max_lead_s: ``rate_factor`` 0 with an ifa_node running: the simulated device waits while
            the mechanization is more than this many seconds ahead of the last correction (0 = never).
    """

    datum: tuple[float, ...] = datum_param()
    aircraft_config: str = aircraft_config_param()
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
        minimum=0.0, length=5)
    max_lead_s: float = param(2.0, "rate_factor 0 with an ifa_node: stay at most this many seconds ahead of its corrections (0 = no limit)", minimum=0.0)
    ring_s: float = param(60.0, "seconds of IMU samples kept for re-integration after an IFA correction", minimum=1.0)
