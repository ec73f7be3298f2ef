"""The aircraft (vehicle) configuration: GNSS antenna, sub-IMUs, antennas and the wing flexure.

All body vectors are in the product's FLU axes (x forward, y left, z up) of the master IMU; the
papers' RFU numbers are converted in the shipped files (see their comments).  Read by every node
(``aircraft_config``), the offline tools and the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from .. import plausibility
from .files import ConfigError, build, parse_yaml, read_yaml, vec3
from .flexure import FlexureModel, ModalWing, WingMode
from .sensors import ImuErrorModel, imu_model

#: ``mount_rpy_deg: estimate`` - a mounting the aircraft file leaves to the data (dpos-import --nav)
MOUNT_ESTIMATE = "estimate"


@dataclass(frozen=True)
class SubImuConfig:
    """One sub-IMU on the wing.

    Attributes:
        name: used in topics ``/sub_imu/<name>/imu`` and frames ``sub_imu_<name>``.
        span_m: signed span position (+ right wing, - left wing), scales the flexure.
        lever_arm_m: (3,) from the master IMU, master FLU axes.
        mount_rpy_deg: nominal mount rotation of the sub-IMU axes w.r.t. the master's.
        mount_sigma_deg: 1 sigma [deg] per axis of ``mount_rpy_deg`` (the same on each axis): the
            prior of the rigid misalignment rho the transfer alignment estimates
            (``Installation.rho_sigma_deg``); None: not stated, the alignment's default
            (``TAConfig.rho_sigma_deg``, 1 deg).  dpos-import writes it beside an estimated mounting.
        rho_deg: (3,) rigid misalignment (rotation vector, sub-IMU axes) the transfer alignment estimates.
        imu: sensor error model.
        lever_arm_sigma_m: 1 sigma per axis of the lever arm's survey; > 0: the transfer alignment
            estimates the survey error (3 states, docs/mismatch.md), 0: the arm is taken as exact.
        time_offset_sigma_ms: 1 sigma of the sub-IMU's time offset against the main system (its
            stamps minus the main system's time of the same instant); > 0: the transfer alignment
            estimates it (one state) and moves the output to its stamps, 0: taken as synchronized.
        axis_error_states: the transfer alignment estimates the sub-IMU's scale factors and
            misalignments (9 states per triad whose datasheet states them, ``imu`` ``*_scale_ppm`` /
            ``*_misalignment_mrad`` as their prior 1 sigma; docs/mismatch.md).
    """

    name: str
    span_m: float
    lever_arm_m: tuple[float, float, float]
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_sigma_deg: float | None = None
    rho_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu: ImuErrorModel = field(default_factory=ImuErrorModel)
    lever_arm_sigma_m: float = 0.0
    time_offset_sigma_ms: float = 0.0
    axis_error_states: bool = False

    def __post_init__(self) -> None:
        for k in ("lever_arm_sigma_m", "time_offset_sigma_ms"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v):
                raise ValueError(f"{k} must be a finite number >= 0, got {v!r}")
        v = self.mount_sigma_deg
        if v is not None and not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0.0):
            raise ValueError(f"mount_sigma_deg must be a finite number > 0 [deg] (or absent: 1 deg), got {v!r}")


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
    #: the main IMU's datasheet model (``master_imu:``, may name a ``preset``); None = not stated
    #: (ifa_node then takes its ``imu_preset`` / parameters, or a simulated scenario's sensor)
    master_imu: ImuErrorModel | None = None
    #: the simulator's modal wing (``flexure: {model: modal}``); None: the simulator flexes the wing
    #: with ``flexure`` itself (``model: gauss_markov``, the default).  ``flexure`` stays the
    #: transfer alignment's model ([Gong2018] eq. 13) either way.
    wing: ModalWing | None = None

    def sub_imu(self, name: str) -> SubImuConfig:
        for s in self.sub_imus:
            if s.name == name:
                return s
        raise KeyError(f"aircraft {self.name!r} has no sub-IMU {name!r} (has: {[s.name for s in self.sub_imus]})")


def load_aircraft(name_or_path: str | Path, *, text: str | None = None) -> AircraftConfig:
    """Load a built-in aircraft configuration by name, or a YAML file by path (or its ``text``)."""
    d, label = parse_yaml(text, f"aircraft {name_or_path}") if text is not None else read_yaml("aircraft", name_or_path)
    allowed = {"name", "gnss_lever_arm_m", "flexure", "sub_imus", "antennas", "description", "master_imu"}
    if set(d) - allowed:
        raise ConfigError(f"{label}: unknown key(s) {sorted(set(d) - allowed)}")
    wing = None
    if d.get("flexure") is None and not d.get("sub_imus"):
        flex = FlexureModel(tau_s=(5.0, 2.0, 2.0), variance_deg2=(0.0, 0.0, 0.0))  # no wing: a rigid vehicle
    else:
        flex, wing = _flexure(d.get("flexure"), f"{label}: flexure")
    subs = []
    for i, s in enumerate(d.get("sub_imus") or []):
        where = f"{label}: sub_imus[{i}]"
        if not isinstance(s, dict) or not s.get("name"):
            raise ConfigError(f"{where}: needs a non-empty name")
        s = dict(s)
        imu = imu_model(s.pop("imu", None), f"{where}.imu")
        if s.get("mount_rpy_deg") == MOUNT_ESTIMATE:
            raise ConfigError(f"{where}.mount_rpy_deg: {MOUNT_ESTIMATE!r} is resolved by dpos-import --nav --aircraft (it estimates the "
                              "mounting from the data and writes it into the recording's copy of this file); give roll, pitch, yaw [deg] here "
                              "(and its mount_sigma_deg, which the import's report prints)")
        if "mount_sigma_deg" in s and s["mount_sigma_deg"] is None:
            del s["mount_sigma_deg"]  # (null: not stated)
        for k in ("lever_arm_m", "mount_rpy_deg", "rho_deg"):
            if k in s:
                s[k] = vec3(s[k], f"{where}.{k}")
        if "span_m" not in s or "lever_arm_m" not in s:
            raise ConfigError(f"{where}: span_m and lever_arm_m are required")
        sub = build(SubImuConfig, {**s, "imu": imu}, where)
        _check_side(where, f"sub-IMU {sub.name!r}", sub.span_m, sub.lever_arm_m[1], "its lever_arm_m y (from the master IMU, FLU: y left)")
        subs.append(sub)
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
        a["lever_arm_m"] = vec3(a.get("lever_arm_m", [0, 0, 0]), f"{where}.lever_arm_m")
        if "span_m" not in a:
            raise ConfigError(f"{where}: span_m is required")
        ant = build(AntennaConfig, a, where)
        if ant.sub_imu is None:
            _check_side(where, f"antenna {ant.name!r}", ant.span_m, ant.lever_arm_m[1],
                        "its lever_arm_m y (from the master IMU, FLU: y left)")
        else:
            carrier_sub = subs[names.index(ant.sub_imu)]
            _check_side(where, f"antenna {ant.name!r}", ant.span_m, carrier_sub.lever_arm_m[1],
                        f"the lever_arm_m y of its sub-IMU {ant.sub_imu!r} (FLU: y left)")
        ants.append(ant)
    if len({a.name for a in ants}) != len(ants):
        raise ConfigError(f"{label}: duplicate antenna names")
    if wing is not None:
        for what, span in [(f"sub-IMU {x.name!r}", x.span_m) for x in subs] + [(f"antenna {x.name!r}", x.span_m) for x in ants]:
            if abs(span) > wing.semi_span_m:
                raise ConfigError(f"{label}: {what} at span {span:g} m is beyond the wing's semi_span_m {wing.semi_span_m:g} m")
    gnss_arm = vec3(d.get("gnss_lever_arm_m", [0, 0, 0]), f"{label}: gnss_lever_arm_m")
    _check_sizes(label, gnss_arm, subs, ants, wing)
    return AircraftConfig(
        name=str(d.get("name", Path(str(name_or_path)).stem)),
        gnss_lever_arm_m=gnss_arm,
        flexure=flex,
        sub_imus=tuple(subs),
        antennas=tuple(ants),
        master_imu=imu_model(d["master_imu"], f"{label}: master_imu") if d.get("master_imu") is not None else None,
        wing=wing,
    )


def _flexure(d: object, where: str) -> tuple[FlexureModel, ModalWing | None]:
    """The ``flexure:`` block: ``model: gauss_markov`` (default; :class:`FlexureModel`, simulated
    as such) or ``model: modal`` (:class:`ModalWing` for the simulator, plus the transfer alignment's
    Gauss-Markov model: ``tau_s`` and ``span_exponent`` as given (default 5/2/2 s, 1), the variances
    those of the modes at the reference span, per axis)."""
    if not isinstance(d, dict):
        return build(FlexureModel, d, where), None
    d = dict(d)
    model = d.pop("model", "gauss_markov")
    if model == "gauss_markov":
        return build(FlexureModel, d, where), None
    if model != "modal":
        raise ConfigError(f"{where}: model must be gauss_markov or modal, got {model!r}")
    if "variance_deg2" in d:
        raise ConfigError(f"{where}: a modal wing's variance_deg2 follows from its modes' sigma_deg; remove it")
    ta = {k: d.pop(k) for k in ("tau_s", "span_exponent") if k in d}
    raw = d.pop("modes", None)
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where}: a modal wing needs a non-empty list of modes")
    d["modes"] = tuple(build(WingMode, m, f"{where}.modes[{i}]") for i, m in enumerate(raw))
    wing = build(ModalWing, d, where)
    flex = build(FlexureModel, {"tau_s": ta.get("tau_s", [5.0, 2.0, 2.0]), "span_exponent": ta.get("span_exponent", 1.0),
                                "reference_span_m": wing.reference_span_m, "variance_deg2": list(wing.variance_deg2())}, where)
    return flex, wing


def _check_sizes(label: str, gnss_arm: tuple[float, float, float], subs: list[SubImuConfig], ants: list[AntennaConfig],
                 wing: ModalWing | None) -> None:
    """Every lever arm (and span) within the aircraft's size (dpos_core.plausibility.size_bound_m:
    its largest span position, or its wing's semi-span, + 30 m, at least 60 m): a ConfigError
    naming the first one that is not (1000 m, or millimetres given as metres)."""
    if wing is not None:
        found = plausibility.check_lever_arm(f"{label}: flexure semi_span_m", (wing.semi_span_m, 0.0, 0.0), plausibility.MAX_SEMI_SPAN_M)
        if found is not None:
            raise ConfigError(str(found))
    bound = plausibility.size_bound_m([], wing.semi_span_m if wing is not None else None)
    items: list[tuple[str, tuple[float, float, float]]] = [(f"{label}: gnss_lever_arm_m", gnss_arm)]
    items += [(f"{label}: sub-IMU {x.name!r} span_m", (x.span_m, 0.0, 0.0)) for x in subs]
    items += [(f"{label}: antenna {x.name!r} span_m", (x.span_m, 0.0, 0.0)) for x in ants]
    items += [(f"{label}: sub-IMU {x.name!r} lever_arm_m", x.lever_arm_m) for x in subs]
    items += [(f"{label}: antenna {x.name!r} lever_arm_m", x.lever_arm_m) for x in ants]
    items += [(f"{label}: sub-IMU {x.name!r} lever_arm_sigma_m", (x.lever_arm_sigma_m, 0.0, 0.0)) for x in subs]
    for what, arm in items:
        found = plausibility.check_lever_arm(what, arm, bound)
        if found is not None:
            raise ConfigError(str(found))


def _side(y: float) -> str:
    return "the right wing" if y < 0 else "the left wing"


def _check_side(where: str, what: str, span_m: float, y_m: float, whose_y: str) -> None:
    """``span_m`` is signed, + on the right wing (FLU y < 0), - on the left (y > 0): a span whose
    sign contradicts the side given by the lever arm's y is a ConfigError. Zero on either side
    (on the fuselage) is accepted."""
    if span_m == 0.0 or y_m == 0.0 or (span_m > 0.0) == (y_m < 0.0):
        return
    raise ConfigError(f"{where}.span_m: {what} has span_m {span_m:g} m, which puts it on {_side(-span_m)} "
                      f"(span_m is signed, + right wing, - left wing), but {whose_y} is {y_m:g} m: {_side(y_m)}")


def scenario_aircraft_ref(scenario: str | Path) -> str:
    """The aircraft a scenario file flies: its ``aircraft`` key (a built-in name, or a path that a
    user scenario file may give relative to itself), else the scenario's name."""
    d, _ = read_yaml("scenarios", scenario)
    ref = str(d.get("aircraft", d.get("name", Path(str(scenario)).stem)))
    base = Path(str(scenario))
    if ref.endswith((".yaml", ".yml")) and not Path(ref).is_absolute() and base.suffix in (".yaml", ".yml"):
        beside = base.parent / ref
        if beside.is_file():
            return str(beside)
    return ref


def scenario_aircraft(scenario: str | Path) -> AircraftConfig:
    """The aircraft of a built-in or user scenario (see :func:`scenario_aircraft_ref`)."""
    try:
        return load_aircraft(scenario_aircraft_ref(scenario))
    except ConfigError as e:
        raise ConfigError(f"scenario {scenario}: aircraft: {e}") from None
