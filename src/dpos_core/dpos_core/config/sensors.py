"""Sensor models in datasheet units: IMU errors, GNSS, and the main system's navigation output.

The papers specify sensor errors as a "constant" and a "random" part ([Gong2018] sec. 4.1.2:
gyro 0.01 deg/h + 0.01 deg/h, accelerometer 50 ug + 50 ug): the constant part is a per-run bias
with that 1 sigma per axis, the random part white noise with that standard deviation on every
output sample (the mean rate / specific force over the sample interval).  The simulator draws
them (:mod:`dpos_core.sim.sensors`); the estimators take their statistics from here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources

import numpy as np
import yaml

from ..units import DEG, DEG_PER_H, UG_MPS2, FloatArray
from .files import ConfigError, build

#: how a filter carries the gyro axis errors (ImuErrorModel and IfaFilterConfig.gyro_axis_errors; not YAML
#: booleans such as on / off)
GYRO_AXIS_ERRORS = ("auto", "states", "noise")


@dataclass(frozen=True)
class ImuErrorModel:
    """An IMU's errors in the units of a datasheet (1 sigma per axis); one schema for every IMU
    (main and sub), read by the simulator (:mod:`dpos_core.sim.sensors`) and the filters alike.

    Reading a datasheet (docs/sensors.md):

    * ``*_bias_*``: turn-on (run-to-run) bias, constant over a session.  Gyro [deg/h]
      (1 deg/s = 3600 deg/h), accelerometer [ug] (1 mg = 1000 ug).
    * ``*_noise_*``: white noise on every output sample, the papers' "random" part (its effect
      depends on the sample rate).  ``gyro_arw_deg_rth`` [deg/sqrt(h)] and ``accel_vrw_mps_rth``
      [m/s/sqrt(h)] are the datasheet's rate-independent densities (angle / velocity random walk);
      a sample over ``dt`` then has the standard deviation ``ARW / sqrt(dt)``.  Both may be given:
      the variances add (:meth:`white_sigma`).
    * ``*_bias_instability_*`` with ``*_bias_tau_s``: the in-run bias variation, a first-order
      Gauss-Markov process with that steady-state sigma and correlation time (the datasheet's
      Allan-deviation floor; tau of the order of the floor's averaging time).
    * ``*_scale_ppm``: scale-factor error (1 % = 10000 ppm), constant per session.
    * ``*_misalignment_mrad``: non-orthogonality / cross-axis sensitivity (1 % = 10 mrad), each of
      the six off-diagonal terms constant per session.
    * ``gyro_axis_errors``: not a datasheet figure but the grade's model choice for the filters
      (``noise`` in the MEMS presets: factory-calibrated units, docs/sensors.md).

    The mount rotation and the lever arms belong to the installation, not to the sensor: see
    :class:`~dpos_core.config.aircraft.SubImuConfig` and ``gnss_lever_arm_m``.  ``preset`` names
    a grade of :data:`IMU_PRESETS` (keys given beside it override the preset's values).
    """

    gyro_bias_deg_h: float = 0.0
    gyro_noise_deg_h: float = 0.0
    gyro_arw_deg_rth: float = 0.0
    gyro_bias_instability_deg_h: float = 0.0
    gyro_bias_tau_s: float = 3600.0
    gyro_scale_ppm: float = 0.0
    gyro_misalignment_mrad: float = 0.0
    accel_bias_ug: float = 0.0
    accel_noise_ug: float = 0.0
    accel_vrw_mps_rth: float = 0.0
    accel_bias_instability_ug: float = 0.0
    accel_bias_tau_s: float = 3600.0
    accel_scale_ppm: float = 0.0
    accel_misalignment_mrad: float = 0.0
    #: how a filter carries this unit's gyro scale factors and misalignments (the grade's model
    #: choice, :attr:`dpos_core.ifa.model.IfaFilterConfig.gyro_axis_errors`): ``states``, ``noise``
    #: or ``auto`` (by the scale factor / misalignment; docs/sensors.md)
    gyro_axis_errors: str = "auto"

    def __post_init__(self) -> None:
        if self.gyro_axis_errors not in GYRO_AXIS_ERRORS:
            raise ValueError(f"IMU error model: gyro_axis_errors must be auto, states or noise, got {self.gyro_axis_errors!r}")
        for k, v in self.__dict__.items():
            if k == "gyro_axis_errors":
                continue
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"IMU error model: {k} must be finite and >= 0, got {v}")
        for k in ("gyro_bias_tau_s", "accel_bias_tau_s"):
            if not getattr(self, k) > 0:
                raise ValueError(f"IMU error model: {k} must be > 0, got {getattr(self, k)}")

    def white_sigma(self, dt_s: float) -> tuple[float, float]:
        """White noise 1 sigma of one sample over ``dt_s``: (gyro [rad/s], accel [m/s^2])."""
        if not dt_s > 0:
            raise ValueError(f"sample interval must be > 0, got {dt_s}")
        g = np.hypot(self.gyro_noise_deg_h * DEG_PER_H, self.gyro_arw_deg_rth * DEG / 60.0 / np.sqrt(dt_s))
        a = np.hypot(self.accel_noise_ug * UG_MPS2, self.accel_vrw_mps_rth / 60.0 / np.sqrt(dt_s))
        return float(g), float(a)

    def bias_walk_variance(self, T_s: float) -> tuple[float, float]:
        """Variance of the in-run bias change over an interval ``T_s`` << tau (the first-order
        Gauss-Markov process as a random walk, ``2 sigma_BI^2 T / tau``): (gyro [rad^2/s^2],
        accel [m^2/s^4]), the process noise of constant-bias filter states."""
        g = 2.0 * (self.gyro_bias_instability_deg_h * DEG_PER_H) ** 2 * T_s / self.gyro_bias_tau_s
        a = 2.0 * (self.accel_bias_instability_ug * UG_MPS2) ** 2 * T_s / self.accel_bias_tau_s
        return float(g), float(a)

    @property
    def has_in_run_bias(self) -> bool:
        return self.gyro_bias_instability_deg_h > 0 or self.accel_bias_instability_ug > 0


def _presets() -> dict[str, dict[str, float | str]]:
    text = resources.files(__package__).joinpath("imu_presets.yaml").read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    return {str(k): dict(v) for k, v in data.items()}


#: grade presets (``imu_presets.yaml`` of this package): name -> ImuErrorModel fields
IMU_PRESETS: dict[str, dict[str, float | str]] = _presets()


def imu_model(data: dict | None, where: str) -> ImuErrorModel:
    """An :class:`ImuErrorModel` from a config mapping, with an optional ``preset`` (class
    docstring); unknown keys, unknown presets and bad values raise ConfigError naming ``where``."""
    d = dict(data or {})
    name = d.pop("preset", None)
    if name is not None:
        if name not in IMU_PRESETS:
            raise ConfigError(f"{where}: unknown IMU preset {name!r}; presets: {sorted(IMU_PRESETS)}")
        d = {**IMU_PRESETS[name], **d}
    return build(ImuErrorModel, d, where)


@dataclass(frozen=True)
class NoiseInterval:
    """GNSS noise scaling (``scale`` x nominal sigma) or outage (``outage``) over [t_start, t_end)."""

    t_start_s: float
    t_end_s: float
    scale: float = 1.0
    outage: bool = False

    def __post_init__(self) -> None:
        if not self.t_end_s > self.t_start_s:
            raise ValueError(f"GNSS interval: t_end_s {self.t_end_s} must be after t_start_s {self.t_start_s}")
        if not self.scale > 0:
            raise ValueError(f"GNSS interval: scale must be > 0, got {self.scale}")


@dataclass(frozen=True)
class GnssModel:
    """GNSS position / velocity at the antenna.

    Attributes:
        rate_hz: fix rate.
        pos_sigma_m: (E, N, U) 1 sigma of the position noise.
        vel_sigma_mps: (E, N, U) 1 sigma of the velocity noise.
        schedule: noise changes and outages over time.
        phase_s: the fixes are taken at ``k / rate_hz + phase_s`` (a receiver's epochs need not
            fall on IMU samples), in [0, 1 / rate_hz).
        stamp_offset_s: the fixes are stamped ``stamp_offset_s`` after the instant they describe
            (a GNSS-IMU clock offset; ifa_node's ``gnss_time_offset_s`` undoes it).
    """

    rate_hz: float = 1.0
    pos_sigma_m: tuple[float, float, float] = (1.5, 1.5, 1.5)
    vel_sigma_mps: tuple[float, float, float] = (0.03, 0.03, 0.03)
    schedule: tuple[NoiseInterval, ...] = field(default_factory=tuple)
    phase_s: float = 0.0
    stamp_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"GNSS rate_hz must be > 0, got {self.rate_hz}")
        if any(s <= 0 for s in (*self.pos_sigma_m, *self.vel_sigma_mps)):
            raise ValueError("GNSS sigmas must be > 0 (a zero covariance is not a measurement)")
        if not 0.0 <= self.phase_s < 1.0 / self.rate_hz:
            raise ValueError(f"GNSS phase_s must be in [0, 1 / rate_hz), got {self.phase_s}")
        if not (np.isfinite(self.stamp_offset_s) and abs(self.stamp_offset_s) < 1.0):
            raise ValueError(f"GNSS stamp_offset_s must be finite and below 1 s, got {self.stamp_offset_s}")

    def scale_at(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Noise scale (N,) and availability mask (N,) at times t."""
        t = np.asarray(t_s, dtype=float)
        scale = np.ones_like(t)
        ok = np.ones(t.shape, dtype=bool)
        for iv in self.schedule:
            inside = (t >= iv.t_start_s) & (t < iv.t_end_s)
            if iv.outage:
                ok &= ~inside
            else:
                scale = np.where(inside, iv.scale, scale)
        return scale, ok


@dataclass(frozen=True)
class NavNoiseModel:
    """Main-system navigation output = truth + white noise (``alignment: reference``, [Gong2018])."""

    heading_deg: float = 0.005
    pitch_deg: float = 0.0025
    roll_deg: float = 0.0025
    vel_mps: float = 0.005
    pos_m: float = 0.0
