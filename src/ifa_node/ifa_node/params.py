"""Configuration of ifa_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from dpos_core import plausibility
from dpos_core.config.sensors import IMU_PRESETS, imu_model
from dpos_core.ifa.model import BIAS_FEEDBACK, GYRO_AXIS_ERRORS, PAPER_IFA_IMU, R_ESTIMATORS, IfaFilterConfig
from dpos_core.ifa.pipeline import METHODS
from dpos_ros.runtime.params import ParameterError, aircraft_config_param, config_from_values, datum_param, param, scenario_param

if TYPE_CHECKING:
    from dpos_core.config.sensors import ImuErrorModel
    from dpos_core.ifa.model import IfaFilterConfig



def _plausible_offset(v: float) -> str | None:
    """A GNSS-IMU time offset within +-60 s (dpos_core.plausibility.check_time_offset)."""
    found = plausibility.check_time_offset("gnss_time_offset_s", v)
    return None if found is None else f"{found.statistic}: {found.mistake}"

@dataclass(frozen=True)
class IfaConfig:
    """Validated parameters of ifa_node (mapped into :class:`dpos_core.ifa.model.IfaFilterConfig` by
    :meth:`core_config`).

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` origin; ``[]`` = /dpos/datum.
        aircraft_config: aircraft (built-in name or YAML path) whose ``gnss_lever_arm_m`` is used;
            '' = the aircraft of ``scenario`` (a simulated session). One of the two is required:
            the lever arm is what only the user knows about a real installation.
        scenario: a simulated session's scenario (only to find its aircraft when aircraft_config
            is ''); '' = none.
        method: alignment filter, one of :data:`dpos_core.ifa.pipeline.METHODS` (default ``add2``).
        window: window length of the adaptive estimation, in GNSS epochs (>= 2): eq. 22's window
            (``r_estimator: window``) and the NIS consistency window.
        r_estimator, r_window_max, r_min_epochs, r_change_quantile: ADD2 / AEKF's estimate of the
            GNSS noise (``changepoint``: a window of up to ``r_window_max`` epochs restarted at
            detected noise changes; ``window``: eq. 22), see :class:`dpos_core.ifa.model.IfaFilterConfig`.
        gnss_pos_sigma_m, gnss_vel_sigma_mps: nominal GNSS noise (E, N, U) of the filter's R.
        use_reported_sigma: R from each fix's own covariance instead of the nominal sigmas.
        aligned_heading_sigma_deg: heading 1 sigma below which ALIGNED may be declared (with a
            consistent innovation window); a floor: the core takes at least what the IMU's grade
            reaches (``IfaFilterConfig.aligned_heading_threshold_rad``).
        heading_sigma_deg: prior heading 1 sigma [deg] (large: any initial heading).
        vertical: 15 states with the vertical channel (True) or the paper's 13.
        imu_preset: main IMU model, a grade preset; '' = the aircraft file's ``master_imu``, else
            [Fang2012] Table 1 (navigation grade).
        level_sigma_deg: prior pitch / roll 1 sigma [deg].
        gnss_time_offset_s, max_fix_bridge_s, predict_interval_s, restart_on_divergence,
            bias_feedback, gyro_axis_errors, standstill_updates, nhc: see
            :class:`dpos_core.ifa.model.IfaFilterConfig`.
        outage_wait_s: a time update alone due at IMU time ``t`` (no fix since ``predict_interval_s``:
            an outage) is made, and published as an /ifa/correction with the grown covariance, once
            IMU samples stamped ``t + outage_wait_s`` are here and the sample at ``t`` has been here
            for ``outage_wait_s`` of wall time; a fix stamped before ``t`` that comes later still is
            rejected (``stale``). /master/nav waits as long for it during an outage.
        pair_tolerance_s: a /gnss/fix and a /gnss/vel closer than this are one epoch.
        pair_timeout_s: a fix (velocity) whose partner has not come when the partner's stream is
            this much newer [s], or after this long in wall time, is dropped with a warning.
    """

    datum: tuple[float, ...] = datum_param()
    aircraft_config: str = aircraft_config_param("the aircraft of scenario; one of the two is required")
    scenario: str = scenario_param("a simulated session's scenario: its aircraft gives the GNSS lever arm when aircraft_config is ''", default="")
    method: str = param("add2", "in-flight alignment filter", choices=METHODS)
    window: int = param(10, "window length of the adaptive estimation (GNSS epochs)", minimum=2)
    r_estimator: str = param("changepoint", "GNSS noise estimate of add2 / aekf: changepoint (window restarted at noise changes) or window (eq. 22)",
                             choices=R_ESTIMATORS)
    r_window_max: int = param(30, "changepoint: longest window of the noise estimate (GNSS epochs)", minimum=2)
    r_min_epochs: int = param(3, "changepoint: epochs before the estimate is used, also the change-test length (<= r_window_max)", minimum=1)
    r_change_quantile: float = param(0.999, "changepoint: two-sided chi-square quantile of the change test, in (0.5, 1)",
                                     check=lambda v: None if 0.5 < v < 1.0 else "must be in (0.5, 1)")
    gnss_pos_sigma_m: tuple[float, float, float] = param((1.5, 1.5, 1.5), "nominal GNSS position sigma E, N, U [m]", minimum=0.0, exclusive_minimum=True)
    gnss_vel_sigma_mps: tuple[float, float, float] = param((0.03, 0.03, 0.03), "nominal GNSS velocity sigma E, N, U [m/s]", minimum=0.0, exclusive_minimum=True)
    use_reported_sigma: bool = param(False, "R from each fix's covariance instead of the nominal sigmas")
    aligned_heading_sigma_deg: float = param(0.1, "heading 1 sigma [deg] below which ALIGNED may be declared", minimum=0.0, exclusive_minimum=True)
    heading_sigma_deg: float = param(100.0, "prior heading 1 sigma [deg]", minimum=0.0, exclusive_minimum=True)
    vertical: bool = param(True, "15 states with the vertical channel (false: the paper's 13)")
    imu_preset: str = param("", "main IMU model: a grade preset (dpos_core.config.sensors.IMU_PRESETS); '' = the aircraft's master_imu, else [Fang2012] Table 1",
                            choices=("", *IMU_PRESETS))
    level_sigma_deg: float = param(1.0, "prior pitch / roll 1 sigma [deg] (the levelling of the initial state)", minimum=0.0, exclusive_minimum=True)
    gnss_time_offset_s: float = param(0.0, "GNSS stamps minus the IMU time of the same instant [s]", check=_plausible_offset)
    max_fix_bridge_s: float = param(0.05, "a fix may lie this far [s] from the last IMU sample (bridged with the velocity)",
                                    minimum=0.0, exclusive_minimum=True)
    predict_interval_s: float = param(1.5, "time update alone after this long [s] without a fix (outages)", minimum=0.0, exclusive_minimum=True)
    restart_on_divergence: bool = param(True, "restart the alignment when the innovations diverge")
    bias_feedback: str = param("auto", "when bias estimates are fed back: auto (by the IMU grade), aligned, always", choices=BIAS_FEEDBACK)
    gyro_axis_errors: str = param("auto", "gyro scale factor / misalignment as states or noise: auto (the IMU preset's choice, "
                                          "else states for an uncalibrated MEMS unit), states, noise", choices=GYRO_AXIS_ERRORS)
    standstill_updates: bool = param(True, "zero-angular-rate update about the vertical (ZARU) at the GNSS epochs detected at rest (docs/ifa.md)")
    nhc: bool = param(False, "non-holonomic constraint (a wheeled ground vehicle: no sideways or vertical body velocity)")
    outage_wait_s: float = param(0.25, "outage: make a due time update alone once IMU data this much [s] newer is here, and this long [s] in wall time",
                                 minimum=0.0, exclusive_minimum=True)
    pair_tolerance_s: float = param(0.001, "a /gnss/fix and /gnss/vel closer than this [s] form one epoch", minimum=0.0)
    pair_timeout_s: float = param(2.0, "drop a fix without velocity once the velocity stream is this much [s] newer, or after this long in wall time", minimum=0.0)

    @classmethod
    def from_params_file(cls, path: Path) -> IfaConfig:
        """The configuration of an ifa_node ROS parameter file (``ifa_node: ros__parameters:``), as
        the node gets it from ``--params-file`` (offline tools and tests use the file the live graph
        runs with).  ValueError naming the file when it is not one, or holds an unknown parameter."""
        try:
            params = dict(yaml.safe_load(Path(path).read_text())["ifa_node"]["ros__parameters"])
        except (OSError, yaml.YAMLError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: not an ifa_node parameter file ({type(e).__name__}: {e})") from None
        try:  # the node's own checks of every value (types, ranges, choices), as declare_config makes them
            return config_from_values(cls, params)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None

    def core_config(self, master_imu: ImuErrorModel | None = None) -> IfaFilterConfig:
        """The :class:`dpos_core.ifa.model.IfaFilterConfig` of these parameters; the IMU model is
        ``imu_preset`` when set, else ``master_imu`` (the aircraft file's), else [Fang2012]'s."""
        if self.r_min_epochs > self.r_window_max:
            raise ParameterError("r_min_epochs", self.r_min_epochs, f"must be <= r_window_max ({self.r_window_max})")
        if self.imu_preset:
            imu = imu_model({"preset": self.imu_preset}, "ifa_node imu_preset")
        else:
            imu = master_imu if master_imu is not None else PAPER_IFA_IMU
        return IfaFilterConfig(imu=imu, level_sigma_deg=self.level_sigma_deg, gnss_time_offset_s=self.gnss_time_offset_s,
                               max_fix_bridge_s=self.max_fix_bridge_s, predict_interval_s=self.predict_interval_s,
                               restart_on_divergence=self.restart_on_divergence, bias_feedback=self.bias_feedback,
                               gyro_axis_errors=self.gyro_axis_errors, standstill_updates=self.standstill_updates, nhc=self.nhc,
                               vertical=self.vertical, window=self.window, r_estimator=self.r_estimator,
                               r_window_max=self.r_window_max, r_min_epochs=self.r_min_epochs,
                               r_change_quantile=self.r_change_quantile,
                               gnss_pos_sigma_m=_enu3("gnss_pos_sigma_m", self.gnss_pos_sigma_m),
                               gnss_vel_sigma_mps=_enu3("gnss_vel_sigma_mps", self.gnss_vel_sigma_mps), use_reported_sigma=self.use_reported_sigma,
                               aligned_heading_sigma_deg=self.aligned_heading_sigma_deg, heading_sigma_deg=self.heading_sigma_deg)


def _enu3(name: str, value: tuple[float, ...]) -> tuple[float, float, float]:
    """The (E, N, U) triple of an array parameter (the parameter layer does not check a fixed tuple's length)."""
    if len(value) != 3:
        raise ParameterError(name, list(value), "expected 3 elements")
    return (float(value[0]), float(value[1]), float(value[2]))
