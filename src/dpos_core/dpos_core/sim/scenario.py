"""Simulated sessions: a scenario YAML file (flight, sensors, rates, the aircraft it flies) ->
a validated, frozen :class:`Scenario`.

Built-in scenarios live in :mod:`dpos_core.config` (``scenarios/<name>.yaml``) and are found by
name; any other argument is a path.  The aircraft and sensor models are those of
:mod:`dpos_core.config`; every problem is a ``ConfigError`` naming the file and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from dpos_core.units import DEG

from ..config.aircraft import AircraftConfig, load_aircraft, scenario_aircraft_ref
from ..config.files import ConfigError, build, builtin_names, read_yaml, vec3
from ..config.sensors import GnssModel, ImuErrorModel, NavNoiseModel, NoiseInterval, imu_model
from .flight import Flight, FlightStart, Segment


@dataclass(frozen=True)
class Rates:
    """Sample rates and the main IMU's real-device timing.

    Attributes:
        master_imu_hz, master_nav_hz, sub_imu_hz: nominal rates [Hz].
        master_imu_jitter_s: each main IMU sample instant moves by U(-j, j) from its grid point
            (a driver's timestamps jitter; j < half the interval).
        master_imu_drop_fraction: fraction of main IMU samples lost (the sample after a lost one
            still covers only its own interval: the motion of the lost one is missing, as when a
            driver drops a message).
    """

    master_imu_hz: float = 100.0
    master_nav_hz: float = 100.0
    sub_imu_hz: float = 100.0
    master_imu_jitter_s: float = 0.0
    master_imu_drop_fraction: float = 0.0

    def __post_init__(self) -> None:
        for k in ("master_imu_hz", "master_nav_hz", "sub_imu_hz"):
            if not getattr(self, k) > 0:
                raise ValueError(f"{k} must be > 0, got {getattr(self, k)}")
        if not 0.0 <= self.master_imu_jitter_s < 0.5 / self.master_imu_hz:
            raise ValueError(f"master_imu_jitter_s must be in [0, half the interval), got {self.master_imu_jitter_s}")
        if not 0.0 <= self.master_imu_drop_fraction < 0.5:
            raise ValueError(f"master_imu_drop_fraction must be in [0, 0.5), got {self.master_imu_drop_fraction}")


@dataclass(frozen=True)
class SarAidingConfig:
    """SAR position/heading fixes and a barometric altimeter ([Yan2016]); simulated by
    :mod:`dpos_core.sim.sar` (docs/sar.md).

    Attributes:
        rate_hz: scene-matching fixes per second, only while the radar images (the scenario's
            ``imaging_segments``; all the flight when it names none).
        pos_sigma_m: 1 sigma of a fix's north and east position (white).
        heading_sigma_deg: 1 sigma of a fix's heading (white).
        baro_rate_hz, baro_sigma_m: barometric height samples per second and their 1 sigma (white).
    """

    rate_hz: float = 1.0
    pos_sigma_m: float = 10.0
    heading_sigma_deg: float = 0.05
    baro_rate_hz: float = 10.0
    baro_sigma_m: float = 2.0

    def __post_init__(self) -> None:
        for k in ("rate_hz", "pos_sigma_m", "heading_sigma_deg", "baro_rate_hz", "baro_sigma_m"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"sar.{k} must be > 0, got {v}")


@dataclass(frozen=True)
class Scenario:
    """A simulated session: flight, sensors and evaluation settings."""

    name: str
    source: str
    description: str
    aircraft: AircraftConfig
    start: FlightStart
    segments: tuple[Segment, ...]
    start_time_s: float
    rates: Rates
    master_imu: ImuErrorModel
    gnss: GnssModel
    master_nav_noise: NavNoiseModel
    imaging_segments: tuple[str, ...] = ()
    transfer_alignment: dict[str, Any] = field(default_factory=dict)
    ifa: dict[str, Any] = field(default_factory=dict)
    sar: SarAidingConfig | None = None

    @property
    def duration_s(self) -> float:
        return float(sum(s.duration_s for s in self.segments))

    @property
    def datum_llh(self) -> np.ndarray:
        """Session datum ``[lat_rad, lon_rad, h_m]``: the start point."""
        return np.array([self.start.lat_deg * DEG, self.start.lon_deg * DEG, self.start.h_m])

    def flight(self, duration_s: float | None = None) -> Flight:
        """The truth flight, optionally cut to ``duration_s``."""
        return Flight(self.start, list(_cut(self.segments, duration_s)), grid_hz=max(100.0, self.rates.master_imu_hz))

    def with_duration(self, duration_s: float | None) -> Scenario:
        if duration_s is None:
            return self
        if not duration_s > 0:
            raise ConfigError(f"duration must be > 0, got {duration_s}")

        return replace(self, segments=tuple(_cut(self.segments, duration_s)))


def _cut(segments: tuple[Segment, ...], duration_s: float | None) -> list[Segment]:
    """Segments truncated to ``duration_s``; a cut turn keeps its turn rate (heading change scaled)."""
    if duration_s is None:
        return list(segments)

    out, t = [], 0.0
    for s in segments:
        if t + s.duration_s <= duration_s + 1e-9:
            out.append(s)
            t += s.duration_s
            continue
        rest = duration_s - t
        if rest > 1e-9:
            # keep the flight smooth: a truncated manoeuvre segment becomes a straight one
            out.append(replace(s, duration_s=rest, heading_change_deg=0.0, speed_change_mps=0.0, climb_rate_mps=0.0, ramp_s=None))
        break
    return out


# ---------------------------------------------------------------------------- loading


def load_scenario(name_or_path: str | Path, aircraft: str | Path | None = None) -> Scenario:
    """Load a built-in scenario by name, or a YAML file by path; ``aircraft`` overrides its aircraft."""
    d, label = read_yaml("scenarios", name_or_path)
    allowed = {f.name for f in fields(Scenario)} | {"flight", "rates_hz"}
    allowed -= {"start", "segments", "rates"}
    if set(d) - allowed:
        raise ConfigError(f"{label}: unknown key(s) {sorted(set(d) - allowed)}")
    fl = d.get("flight") or {}
    if not isinstance(fl, dict) or "start" not in fl or not fl.get("segments"):
        raise ConfigError(f"{label}: flight needs start and segments")
    start = build(FlightStart, fl["start"], f"{label}: flight.start")
    segs = tuple(build(Segment, s, f"{label}: flight.segments[{i}]") for i, s in enumerate(fl["segments"]))
    imaging = tuple(d.get("imaging_segments") or ())
    seg_names = {s.name for s in segs}
    for n in imaging:
        if n not in seg_names:
            raise ConfigError(f"{label}: imaging segment {n!r} is not a named flight segment")
    g = dict(d.get("gnss") or {})
    sched = tuple(build(NoiseInterval, iv, f"{label}: gnss.schedule[{i}]") for i, iv in enumerate(g.pop("schedule", []) or []))
    for k in ("pos_sigma_m", "vel_sigma_mps"):
        if k in g:
            g[k] = vec3(g[k], f"{label}: gnss.{k}")
    gnss = build(GnssModel, {**g, "schedule": sched}, f"{label}: gnss")
    sar = d.get("sar")
    try:
        ac = load_aircraft(aircraft if aircraft is not None else scenario_aircraft_ref(name_or_path))
    except ConfigError as e:
        raise ConfigError(f"{label}: aircraft: {e}") from None
    return Scenario(
        name=str(d.get("name", Path(str(name_or_path)).stem)),
        source=str(d.get("source", "")),
        description=str(d.get("description", "")),
        aircraft=ac,
        start=start,
        segments=segs,
        start_time_s=float(d.get("start_time_s", 1.7e9)),
        rates=build(Rates, d.get("rates_hz"), f"{label}: rates_hz"),
        master_imu=imu_model(d.get("master_imu"), f"{label}: master_imu"),
        gnss=gnss,
        master_nav_noise=build(NavNoiseModel, d.get("master_nav_noise"), f"{label}: master_nav_noise"),
        imaging_segments=imaging,
        transfer_alignment=dict(d.get("transfer_alignment") or {}),
        ifa=dict(d.get("ifa") or {}),
        sar=None if sar is None else build(SarAidingConfig, sar, f"{label}: sar"),
    )


def builtin_scenarios() -> list[str]:
    """Names of the built-in scenarios."""
    return builtin_names("scenarios")
