"""Transfer-alignment inputs straight from a simulated session (evaluation without a bag)."""

from __future__ import annotations

from ..series import ImuSeries, NavSeries
from ..sim.session import SimulatedSession
from .model import Installation


def installation(session: SimulatedSession, name: str) -> Installation:
    return Installation.from_aircraft(session.scenario.aircraft, name)


def master_nav(session: SimulatedSession) -> NavSeries:
    """The main-system navigation with its body rate and covariances (``alignment: reference``)."""
    return session.master_nav_reference()


def sub_imu(session: SimulatedSession, name: str) -> ImuSeries:
    return session.sub_imu(name)
