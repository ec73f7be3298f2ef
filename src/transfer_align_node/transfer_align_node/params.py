"""Configuration of transfer_align_node (ROS parameters, docs/design.md "Nodes")."""

from __future__ import annotations

from dataclasses import dataclass

from dpos_core.ta.pipeline import METHODS, TASettings
from dpos_ros.runtime.params import aircraft_config_param, datum_param, param


def _check_sub_imus(names: tuple[str, ...]) -> str | None:
    if any(not n.strip() for n in names):
        return "names must not be empty"
    if len(set(names)) != len(names):
        return "names must be unique"
    return None


def _check_tau(tau: float) -> str | None:
    return None if tau >= 0 or tau == -1 else "must be >= 0 s, or -1 (auto)"


@dataclass(frozen=True)
class TransferAlignConfig:
    """Validated parameters of transfer_align_node.

    Attributes:
        datum: [lat_deg, lon_deg, h_m] of the ``enu`` frame origin.
        aircraft_config: aircraft YAML path, '' = built-in default.
        method: smoother / filter, one of :data:`dpos_core.ta.pipeline.METHODS` (default ``ups``).
        particles: number of particles of the particle methods (>= 1).
        filter_rate_hz: measurement update rate of the filter (> 0).
        position_matching: match the lever-arm-compensated main-POS position as well as attitude and
            velocity (default); false = [Gong2018]'s own attitude + velocity matching.
        sigma_inflation: scale the output 1-sigma by the innovations' variance factor where they say
            the filter is optimistic (docs/qc.md "Sigma inflation"; default on).
        master_error_tau_s: correlation time of the main POS's position and velocity errors; > 0
            estimates them as states and the antennas follow the main POS; 0 = white noise; -1
            (default) = auto: :data:`~dpos_ros.products.master_reference.GNSS_INS_ERROR_TAU_S` when a
            /pos_master/status publisher exists at the session's end (/master/nav is
            pos_master_node's GNSS/INS mechanization), else 0 (the simulator's reference main POS).
        output_dir: session products go to ``output_dir/<session id>/``.
        output_rate_hz: rate of /antenna/<name>/odom and the CSVs; 0 = the sub-IMU rate.
        sub_imus: names of the sub-IMUs to process; empty = all.
        finalize_timeout_s: how long finalizing waits for data up to the end stamp.
        workers: worker processes for the smoother, 0 = one per core.
        seed: random seed of the particle methods.
        disk_full_buffer_mb: messages held in memory while the disk refuses the spill (full,
            read-only), in MB of message data; past it messages are lost (counted, status ERROR).
        stream_above_s: a session whose streams span more than this many seconds has its rows
            spilled to files beside the products while they are made (as ``dpos-process --stream
            on``; the default is dpos-process's ``--stream auto`` threshold, an hour; the products
            are the same); 0 = every session.
        initial_attitude_error_deg: the papers' initial-error experiment ([Gong2018]: 40 deg): the
            sub-IMUs start from the master's attitude x mount rotated by this many degrees in
            heading, pitch and roll, and the prior 1-sigma is this (at least 1 deg). 0 for real data.
    """

    datum: tuple[float, ...] = datum_param()
    aircraft_config: str = aircraft_config_param("the built-in paper_su")
    method: str = param("ups", "transfer-alignment smoother / filter", choices=METHODS)
    particles: int = param(100, "number of particles (particle methods)", minimum=1)
    filter_rate_hz: float = param(1.0, "filter measurement update rate [Hz]", minimum=0.0, exclusive_minimum=True)
    position_matching: bool = param(True, "match the main POS position too (false: attitude + velocity matching, [Gong2018])")
    sigma_inflation: bool = param(True, "inflate the output sigma where the innovations say the filter is optimistic")
    master_error_tau_s: float = param(-1.0, "correlation time of the main POS's position and velocity errors [s]: > 0 estimates them "
                                      "as states and the antennas follow the main POS (docs/mismatch.md); 0 = white noise; -1 = auto: "
                                      "20 s when /pos_master/status is published (pos_master_node's GNSS/INS), else 0", check=_check_tau)
    output_dir: str = param("out", "directory of the session products", non_empty=True)
    output_rate_hz: float = param(0.0, "output rate [Hz], 0 = the sub-IMU rate", minimum=0.0)
    sub_imus: tuple[str, ...] = param((), "sub-IMUs to process ([] = all)", check=_check_sub_imus)
    finalize_timeout_s: float = param(10.0, "bounded wait for data up to the end stamp [s]", minimum=0.0)
    workers: int = param(0, "smoother worker processes (0 = one per core)", minimum=0)
    seed: int = param(0, "random seed of the particle methods", minimum=0)
    disk_full_buffer_mb: float = param(512.0, "memory for messages while the disk refuses the spill [MB]", minimum=0.0)
    stream_above_s: float = param(
        3600.0, "sessions longer than this [s] have their rows spilled to files while the products are made (memory that does "
        "not grow with them, as dpos-process --stream on; the same products); 0 = every session", minimum=0.0)
    initial_attitude_error_deg: float = param(
        0.0, "simulation experiment: initial sub-IMU attitude offset per axis [deg] (also its prior sigma, >= 1 deg); 0 for real data", minimum=0.0)

    def core_config(self, master_error_tau_s: float) -> TASettings:
        """The transfer alignment's settings of these parameters (:class:`dpos_core.ta.pipeline.TASettings`,
        the core's names: ``position_matching`` is ``use_position``, ``sigma_inflation`` is
        ``inflate_sigma``), what the session's solve and its workers get; ``master_error_tau_s``:
        this node's ``master_error_tau_s`` resolved (-1 = auto: :func:`dpos_ros.products.master_reference.master_error_tau`
        at the session's end)."""
        return TASettings(method=self.method, particles=self.particles, seed=self.seed, filter_rate_hz=self.filter_rate_hz,
                          use_position=self.position_matching, master_error_tau_s=master_error_tau_s,
                          initial_attitude_error_deg=self.initial_attitude_error_deg, inflate_sigma=self.sigma_inflation,
                          output_rate_hz=self.output_rate_hz)
