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
