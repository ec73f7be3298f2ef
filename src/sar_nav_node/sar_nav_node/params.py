"""Configuration of sar_nav_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass

from dpos_core.sar.navigate import SarNavSettings
from dpos_core.sar.pipeline import METHODS
from dpos_ros.runtime.params import datum_param, param


@dataclass(frozen=True)
class SarNavConfig:
    """Validated parameters of sar_nav_node (mapped into :class:`dpos_core.sar.navigate.SarNavSettings`
    by :meth:`settings`).

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` origin; ``[]`` = /dpos/datum.
        method: SINS/SAR filter, one of :data:`dpos_core.sar.pipeline.METHODS` (``ekf``, ``ukf`` and
            [Yan2016]'s particle filters ``pf``, ``rpf``, ``mcmc_rpf`` - the windowed trajectory-move
            MCMC-RPF that tracks, docs/sar.md - and ``mcmc_rpf_literal``, eq. 10-13 read literally).
        particles: particles of the particle filters (>= 2; unused by ekf / ukf).
        seed: random seed of the particle filters.
        bandwidth_scale: the regularization kernel's bandwidth in units of h_opt (rpf, the mcmc_rpf
            variants' random-walk moves; 0.5 = docs/sar.md's h_opt / 2).
        filter_rate_hz: filter epochs (and /sar_nav/nav messages) per second; SAR fixes are used at
            the epochs they are stamped at.
        initial_position_sigma_m, initial_velocity_sigma_mps, initial_attitude_sigma_arcmin: prior 1
            sigma of the initial state's errors (E, N, U; attitude about E, N, U); defaults paper_sar's.
        gyro_bias_sigma_deg_h, accel_bias_sigma_ug: the main IMU's turn-on bias 1 sigma (defaults
            paper_sar's); the white noise comes from the /master/imu covariances.
        baro_height_offset_m: ellipsoidal height minus the ISA pressure altitude of /baro/pressure [m].
        finalize_timeout_s: after /session/end, how long to wait for the IMU to reach its stamp.
    """

    datum: tuple[float, ...] = datum_param()
    method: str = param("ekf", "SINS/SAR filter", choices=METHODS)
    particles: int = param(1000, "number of particles of pf, rpf, mcmc_rpf, mcmc_rpf_literal", minimum=2)
    seed: int = param(0, "random seed of the particle filters", minimum=0)
    bandwidth_scale: float = param(1.0, "rpf, mcmc_rpf, mcmc_rpf_literal: regularization bandwidth in units of h_opt", minimum=0.0, exclusive_minimum=True)
    filter_rate_hz: float = param(1.0, "filter epochs [Hz] (one /sar_nav/nav message each)", minimum=0.0, exclusive_minimum=True)
    initial_position_sigma_m: tuple[float, float, float] = param((10.0, 10.0, 15.0), "prior 1 sigma of the initial position E, N, U [m]",
                                                                 minimum=0.0, exclusive_minimum=True, length=3)
    initial_velocity_sigma_mps: tuple[float, float, float] = param((0.8, 0.8, 0.8), "prior 1 sigma of the initial velocity E, N, U [m/s]",
                                                                   minimum=0.0, exclusive_minimum=True, length=3)
    initial_attitude_sigma_arcmin: tuple[float, float, float] = param((1.2, 1.2, 1.5), "prior 1 sigma of the initial attitude about E, N, U [arcmin]",
                                                                      minimum=0.0, exclusive_minimum=True, length=3)
    gyro_bias_sigma_deg_h: float = param(0.1, "main IMU gyro turn-on bias 1 sigma [deg/h]", minimum=0.0, exclusive_minimum=True)
    accel_bias_sigma_ug: float = param(100.0, "main IMU accelerometer turn-on bias 1 sigma [ug]", minimum=0.0, exclusive_minimum=True)
    baro_height_offset_m: float = param(0.0, "ellipsoidal height minus the ISA pressure altitude of /baro/pressure [m]")
    finalize_timeout_s: float = param(10.0, "after /session/end: longest wait [s] for /master/imu to reach its stamp", minimum=0.0)

    def settings(self) -> SarNavSettings:
        """The core's settings of these parameters (the white-noise densities come with the data)."""
        return SarNavSettings(method=self.method, n_particles=self.particles, seed=self.seed, bandwidth_scale=self.bandwidth_scale,
                              filter_rate_hz=self.filter_rate_hz,
                              pos_sigma_m=_triple(self.initial_position_sigma_m), vel_sigma_mps=_triple(self.initial_velocity_sigma_mps),
                              att_sigma_arcmin=_triple(self.initial_attitude_sigma_arcmin),
                              gyro_bias_sigma_deg_h=self.gyro_bias_sigma_deg_h, accel_bias_sigma_ug=self.accel_bias_sigma_ug)

def _triple(v: tuple[float, ...]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
