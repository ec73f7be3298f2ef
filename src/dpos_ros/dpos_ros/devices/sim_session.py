"""The simulated session of a ``device: sim`` node's parameters (pos_master_node, pos_sub_node).

Apart from :mod:`dpos_ros.devices.sim_device` (which publishes any streams, e.g. transfer_align_node's
antenna poses) so that a node that publishes but never simulates does not load the simulator.
"""

from __future__ import annotations

from dpos_core.config import ConfigError, load_aircraft
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.runtime.params import ParameterError


def load_sim_session(scenario: str, aircraft_config: str, seed: int, duration_s: float) -> SimulatedSession:
    """The :class:`~dpos_core.sim.session.SimulatedSession` of a device node's parameters.

    ``aircraft_config`` '' = the scenario's own aircraft; ``duration_s`` 0 = the whole scenario.
    Cheap: samples are generated lazily. Raises :class:`~dpos_ros.runtime.params.ParameterError` naming
    the parameter (``scenario``, ``aircraft_config``, ``duration`` or ``seed``).
    """
    if aircraft_config:
        try:
            load_aircraft(aircraft_config)
        except ConfigError as exc:
            raise ParameterError("aircraft_config", aircraft_config, str(exc)) from None
    try:
        sc = load_scenario(scenario, aircraft=aircraft_config or None)
    except ConfigError as exc:
        raise ParameterError("scenario", scenario, str(exc)) from None
    if duration_s > sc.duration_s:
        raise ParameterError(
            "duration", duration_s, f"longer than scenario {sc.name!r} ({sc.duration_s:g} s); 0 = the whole scenario"
        )
    try:
        return SimulatedSession(sc, seed, duration_s if duration_s > 0 else None)
    except (ConfigError, ValueError) as exc:
        name = "seed" if "seed" in str(exc) else "duration"
        raise ParameterError(name, seed if name == "seed" else duration_s, str(exc)) from None


__all__ = ["load_sim_session"]
