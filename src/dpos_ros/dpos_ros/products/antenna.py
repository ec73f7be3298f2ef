"""The antenna type of the transfer alignment's session products (design.md "Session products"):
what :func:`dpos_ros.products.solve.solve` gives per antenna and the writers and the evaluation read."""

from __future__ import annotations

from dataclasses import dataclass, field

from dpos_core.filters.variational import CGStats
from dpos_core.series import NavSeries
from dpos_core.ta import flags as ta_flags
from dpos_core.ta import qc as ta_qc
from dpos_core.ta.wingfit import SubImuTrack
from dpos_core.units import FloatArray


@dataclass
class AntennaSolution:
    """An antenna's smoothed trajectory (``traj``) with 1-sigma (N, 9): attitude (rad, rotation
    about local ENU), velocity (m/s, ENU), position (m, ENU); or a status saying why there is none.
    ``chol_jitter_repairs``: Cholesky jitter repairs made by its sub-IMU's smoother (counted, not silent).
    ``flags`` (N,): each row's quality bits (:mod:`dpos_core.ta.flags`; none set when None).
    ``not_estimated``: the spans ``(t_from_s, t_to_s, reason)`` without rows (sub-IMU gaps).
    ``carrier``: its sub-IMU's own solution at the same rows (the input of the least-squares wing
    fit, :func:`fit_antennas`); ``wing_fit``: for a ``fit`` antenna, the fit's basis choice and
    cross-validation (:class:`dpos_core.ta.wingfit.WingFit`); ``qc``: its sub-IMU's consistency
    measures at the filter epochs (:class:`dpos_core.ta.qc.EpochQC`; None for a ``fit`` antenna);
    ``cg``: the CDVF's conjugate-gradient record per epoch (:class:`dpos_core.filters.variational.CGStats`;
    None for the other methods); ``installation``: its sub-IMU's installation-state estimates
    (:attr:`dpos_core.ta.pipeline.TAResult.installation`; empty without them)."""

    name: str
    sub_imu: str | None
    status: str
    traj: NavSeries | None = None
    sigma: FloatArray | None = None
    chol_jitter_repairs: int = 0
    flags: ta_flags.FlagArray | None = None
    not_estimated: list[tuple[float, float, str]] = field(default_factory=list)
    carrier: SubImuTrack | None = None
    wing_fit: dict | None = None
    qc: ta_qc.EpochQC | None = None
    cg: CGStats | None = None
    installation: dict = field(default_factory=dict)
