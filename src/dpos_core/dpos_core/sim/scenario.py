"""Scenario and aircraft configuration: YAML files -> validated, frozen dataclasses.

Built-in files live beside this module (``scenarios/<name>.yaml``, ``aircraft/<name>.yaml``) and are
found by name; any other argument is a path, so users can write their own.  All body vectors
in the aircraft file are in the product's FLU axes (x forward, y left, z up) of the master IMU;
the papers' RFU numbers are converted in the shipped files (see their comments).

Every problem is reported as a ``ConfigError`` naming the file and the offending key.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .flexure import FlexureModel
from .flight import Flight, FlightStart, Segment
from .sensors import GnssModel, ImuErrorModel, NavNoiseModel, NoiseInterval

DEG = np.pi / 180.0


class ConfigError(ValueError):
    """A scenario or aircraft file is invalid (the message names the file and the key)."""


@dataclass(frozen=True)
class SubImuConfig:
    """One sub-IMU on the wing.

    Attributes:
        name: used in topics ``/sub_imu/<name>/imu`` and frames ``sub_imu_<name>``.
        span_m: signed span position (+ right wing, - left wing), scales the flexure.
        lever_arm_m: (3,) from the master IMU, master FLU axes.
        mount_rpy_deg: nominal mount rotation of the sub-IMU axes w.r.t. the master's.
        rho_deg: (3,) rigid misalignment (rotation vector, sub-IMU axes) the transfer alignment estimates.
        imu: sensor error model.
    """

    name: str
    span_m: float
    lever_arm_m: tuple[float, float, float]
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rho_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu: ImuErrorModel = field(default_factory=ImuErrorModel)


@dataclass(frozen=True)
class AntennaConfig:
    """One antenna phase centre.

    Attributes:
        name: topic ``/antenna/<name>/odom``, frame ``antenna_<name>``.
        span_m: signed span position along the wing.
        sub_imu: carrier sub-IMU name, or ``None`` for an antenna without IMU (least-squares fit along the wing).
        lever_arm_m: (3,) from the carrier sub-IMU in its axes; for ``fit`` antennas from the master IMU in master axes.
    """

    name: str
    span_m: float
    sub_imu: str | None
    lever_arm_m: tuple[float, float, float]


@dataclass(frozen=True)
class AircraftConfig:
    name: str
    gnss_lever_arm_m: tuple[float, float, float]
    flexure: FlexureModel
    sub_imus: tuple[SubImuConfig, ...]
    antennas: tuple[AntennaConfig, ...]

    def sub_imu(self, name: str) -> SubImuConfig:
        for s in self.sub_imus:
            if s.name == name:
                return s
        raise KeyError(f"aircraft {self.name!r} has no sub-IMU {name!r} (has: {[s.name for s in self.sub_imus]})")


@dataclass(frozen=True)
class Rates:
    master_imu_hz: float = 100.0
    master_nav_hz: float = 100.0
    sub_imu_hz: float = 100.0


@dataclass(frozen=True)
class SarAidingConfig:
    """SAR position/heading fixes and a barometric altimeter ([Yan2016])."""

    rate_hz: float = 1.0
    pos_sigma_m: float = 10.0
    heading_sigma_deg: float = 0.05
    baro_rate_hz: float = 10.0
    baro_sigma_m: float = 2.0


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

    def with_duration(self, duration_s: float | None) -> "Scenario":
        if duration_s is None:
            return self
        if not duration_s > 0:
            raise ConfigError(f"duration must be > 0, got {duration_s}")
        from dataclasses import replace

        return replace(self, segments=tuple(_cut(self.segments, duration_s)))


def _cut(segments: tuple[Segment, ...], duration_s: float | None) -> list[Segment]:
    """Segments truncated to ``duration_s``; a cut turn keeps its turn rate (heading change scaled)."""
    if duration_s is None:
        return list(segments)
    from dataclasses import replace

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


def _locate(kind: str, name_or_path: str | Path) -> tuple[Path | Any, str]:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ConfigError(f"{kind} file not found: {p}")
        return p, str(p)
    res = resources.files("dpos_core.sim").joinpath(kind, f"{name_or_path}.yaml")
    if not res.is_file():
        known = sorted(f.name[:-5] for f in resources.files("dpos_core.sim").joinpath(kind).iterdir() if f.name.endswith(".yaml"))
        raise ConfigError(f"unknown {kind[:-1] if kind.endswith('s') else kind} {name_or_path!r}; built-in: {known}")
    return res, f"built-in {kind}/{name_or_path}.yaml"


def _read(kind: str, name_or_path: str | Path) -> tuple[dict, str]:
    res, label = _locate(kind, name_or_path)
    return _parse(res.read_text(encoding="utf-8"), label)


def _parse(text: str, label: str) -> tuple[dict, str]:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{label}: invalid YAML: {e}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: expected a mapping at the top level")
    return data, label


def config_text(kind: str, name_or_path: str | Path) -> str:
    """The YAML text of a built-in or user ``scenarios``/``aircraft`` file (to embed in recordings)."""
    res, _ = _locate(kind, name_or_path)
    return res.read_text(encoding="utf-8")


def _build(cls: type, data: Any, where: str) -> Any:
    """Dataclass from a mapping; unknown keys and bad values raise ConfigError naming ``where``."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(names)}")
    kw = {}
    types = {f.name: str(f.type) for f in fields(cls)}
    for k, v in data.items():
        if types[k].startswith("float") and isinstance(v, str):
            try:  # YAML 1.1 reads e.g. 1.0e9 (no exponent sign) as a string
                v = float(v)
            except ValueError:
                raise ConfigError(f"{where}: {k} must be a number, got {v!r}") from None
        if types[k].startswith("float") and not isinstance(v, (int, float)):
            raise ConfigError(f"{where}: {k} must be a number, got {v!r}")
        kw[k] = tuple(v) if isinstance(v, list) else v
    try:
        return cls(**kw)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from None


def _vec3(v: Any, where: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(v, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected 3 numbers, got {v!r}") from None
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{where}: values must be finite, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def load_aircraft(name_or_path: str | Path, *, text: str | None = None) -> AircraftConfig:
    """Load a built-in aircraft configuration by name, or a YAML file by path (or its ``text``)."""
    d, label = _parse(text, f"aircraft {name_or_path}") if text is not None else _read("aircraft", name_or_path)
    allowed = {"name", "gnss_lever_arm_m", "flexure", "sub_imus", "antennas", "description"}
    if set(d) - allowed:
        raise ConfigError(f"{label}: unknown key(s) {sorted(set(d) - allowed)}")
    flex = _build(FlexureModel, d.get("flexure"), f"{label}: flexure")
    subs = []
    for i, s in enumerate(d.get("sub_imus") or []):
        where = f"{label}: sub_imus[{i}]"
        if not isinstance(s, dict) or not s.get("name"):
            raise ConfigError(f"{where}: needs a non-empty name")
        s = dict(s)
        imu = _build(ImuErrorModel, s.pop("imu", None), f"{where}.imu")
        for k in ("lever_arm_m", "mount_rpy_deg", "rho_deg"):
            if k in s:
                s[k] = _vec3(s[k], f"{where}.{k}")
        if "span_m" not in s or "lever_arm_m" not in s:
            raise ConfigError(f"{where}: span_m and lever_arm_m are required")
        subs.append(_build(SubImuConfig, {**s, "imu": imu}, where))
    names = [s.name for s in subs]
    if len(set(names)) != len(names):
        raise ConfigError(f"{label}: duplicate sub-IMU names {names}")
    ants = []
    for i, a in enumerate(d.get("antennas") or []):
        where = f"{label}: antennas[{i}]"
        if not isinstance(a, dict) or not a.get("name"):
            raise ConfigError(f"{where}: needs a non-empty name")
        a = dict(a)
        carrier = a.get("sub_imu", "fit")
        a["sub_imu"] = None if carrier in (None, "fit") else str(carrier)
        if a["sub_imu"] is not None and a["sub_imu"] not in names:
            raise ConfigError(f"{where}: sub_imu {carrier!r} is not a configured sub-IMU {names}")
        a["lever_arm_m"] = _vec3(a.get("lever_arm_m", [0, 0, 0]), f"{where}.lever_arm_m")
        if "span_m" not in a:
            raise ConfigError(f"{where}: span_m is required")
        ants.append(_build(AntennaConfig, a, where))
    if len({a.name for a in ants}) != len(ants):
        raise ConfigError(f"{label}: duplicate antenna names")
    return AircraftConfig(
        name=str(d.get("name", Path(str(name_or_path)).stem)),
        gnss_lever_arm_m=_vec3(d.get("gnss_lever_arm_m", [0, 0, 0]), f"{label}: gnss_lever_arm_m"),
        flexure=flex,
        sub_imus=tuple(subs),
        antennas=tuple(ants),
    )


def load_scenario(name_or_path: str | Path, aircraft: str | Path | None = None) -> Scenario:
    """Load a built-in scenario by name, or a YAML file by path; ``aircraft`` overrides its aircraft."""
    d, label = _read("scenarios", name_or_path)
    allowed = {f.name for f in fields(Scenario)} | {"flight", "rates_hz"}
    allowed -= {"start", "segments", "rates"}
    if set(d) - allowed:
        raise ConfigError(f"{label}: unknown key(s) {sorted(set(d) - allowed)}")
    fl = d.get("flight") or {}
    if not isinstance(fl, dict) or "start" not in fl or not fl.get("segments"):
        raise ConfigError(f"{label}: flight needs start and segments")
    start = _build(FlightStart, fl["start"], f"{label}: flight.start")
    segs = tuple(_build(Segment, s, f"{label}: flight.segments[{i}]") for i, s in enumerate(fl["segments"]))
    imaging = tuple(d.get("imaging_segments") or ())
    seg_names = {s.name for s in segs}
    for n in imaging:
        if n not in seg_names:
            raise ConfigError(f"{label}: imaging segment {n!r} is not a named flight segment")
    g = dict(d.get("gnss") or {})
    sched = tuple(_build(NoiseInterval, iv, f"{label}: gnss.schedule[{i}]") for i, iv in enumerate(g.pop("schedule", []) or []))
    for k in ("pos_sigma_m", "vel_sigma_mps"):
        if k in g:
            g[k] = _vec3(g[k], f"{label}: gnss.{k}")
    gnss = _build(GnssModel, {**g, "schedule": sched}, f"{label}: gnss")
    sar = d.get("sar")
    try:
        ac = load_aircraft(aircraft if aircraft is not None else d.get("aircraft", d.get("name")))
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
        rates=_build(Rates, d.get("rates_hz"), f"{label}: rates_hz"),
        master_imu=_build(ImuErrorModel, d.get("master_imu"), f"{label}: master_imu"),
        gnss=gnss,
        master_nav_noise=_build(NavNoiseModel, d.get("master_nav_noise"), f"{label}: master_nav_noise"),
        imaging_segments=imaging,
        transfer_alignment=dict(d.get("transfer_alignment") or {}),
        ifa=dict(d.get("ifa") or {}),
        sar=None if sar is None else _build(SarAidingConfig, sar, f"{label}: sar"),
    )


def builtin_scenarios() -> list[str]:
    return sorted(f.name[:-5] for f in resources.files("dpos_core.sim").joinpath("scenarios").iterdir() if f.name.endswith(".yaml"))
