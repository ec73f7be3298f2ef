"""The antenna type of the transfer alignment's session products (design.md "Session products"):
what :func:`dpos_ros.products.solve.solve` gives per antenna, the writers and the evaluation read."""

from __future__ import annotations

from dataclasses import dataclass, field

from dpos_core.filters.variational import CGStats
from dpos_core.ta import qc as ta_qc

from .rows import RowBlock, RowStore


@dataclass
class AntennaSolution:
    """An antenna's smoothed rows (``rows``: :data:`dpos_ros.products.rows.ROW_COLUMNS`, stamps,
    attitude, velocity, position and their 1-sigma (N, 9), quality flags), or None with a status
    saying why there are none.
    ``chol_jitter_repairs``: Cholesky jitter repairs made by its sub-IMU's smoother (counted, not silent).
    ``not_estimated``: the spans ``(t_from_s, t_to_s, reason)`` without rows (sub-IMU gaps).
    ``qc``: its sub-IMU's consistency measures at the filter epochs (:class:`dpos_core.ta.qc.EpochQC`;
    None for a ``fit`` antenna); ``cg``: the CDVF's conjugate-gradient record per epoch
    (:class:`dpos_core.filters.variational.CGStats`; None for the other methods); ``wing_fit``: for a
    ``fit`` antenna, the fit's basis choice and cross-validation (:class:`dpos_core.ta.wingfit.WingFit`);
    ``installation``: its sub-IMU's installation-state estimates
    (:attr:`dpos_core.ta.pipeline.TAResult.installation`; empty without them)."""

    name: str
    sub_imu: str | None
    status: str
    rows: RowStore | None = None
    chol_jitter_repairs: int = 0
    not_estimated: list[tuple[float, float, str]] = field(default_factory=list)
    qc: ta_qc.EpochQC | None = None
    cg: CGStats | None = None
    wing_fit: dict | None = None
    installation: dict = field(default_factory=dict)

    @property
    def estimated(self) -> bool:
        return self.rows is not None

    def block(self, i0: int = 0, i1: int | None = None, step: int = 1) -> RowBlock:
        """Its rows ``i0:i1`` (every ``step``-th) as arrays (:meth:`dpos_ros.products.rows.RowBlock.of`)."""
        assert self.rows is not None
        return RowBlock.of(self.rows, i0, i1, step)
