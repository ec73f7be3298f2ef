"""Quality flags of the transfer alignment's output rows: an integer bitmask per sample.

``0`` is a row estimated from uninterrupted sub-IMU data.  A set bit says why the row deserves
care (or, :data:`WING_FIT`, how it was made); its 1-sigma already accounts for the cause (the flags
say *why* a sigma is what it is, they do not replace it).  Written as the ``flags`` column of the
antenna CSV (design.md "Session products").

Bits 0-1 are set by :func:`dpos_core.ta.pipeline.run_segments` / :func:`~dpos_core.ta.pipeline.run`
on a sub-IMU's rows (and on its antennas'); a ``fit`` antenna's row carries them when any sub-IMU
that entered the least-squares wing fit at that epoch has them.  Bits 2-4 are set on the rows of
the ``fit`` antennas by :func:`dpos_core.ta.wingfit.fit_wing` (and
``dpos_ros.products.solve.fit_antennas``: :data:`FEWER_SUB_IMUS` on every row when a sub-IMU of the
wing is not estimated at all).  Bits 5-6 are the quality control's (:mod:`.qc`, set by
``dpos_ros.products.solve.solve`` on a sub-IMU's rows and carried into the wing fit's like bits
0-1).  Bits from 7 on are reserved.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: the row is in the first ``TAConfig.restart_flag_s`` of a segment that restarted from the main
#: POS after a sub-IMU gap longer than ``TAConfig.max_imu_gap_s`` (the filter is converging again)
RESTARTED_AFTER_GAP = 1 << 0
#: the filter interval holding the row contained a short sub-IMU gap (longer than
#: ``dpos_core.series.GAP_FACTOR`` nominal steps, up to ``TAConfig.max_imu_gap_s``) that the strapdown
#: integrated across; its process noise includes what the IMU did not measure
BRIDGED_GAP = 1 << 1
#: the row is from the least-squares wing fit (a ``fit`` antenna, no IMU of its own): set on every
#: such row, so that they can be selected
WING_FIT = 1 << 2
#: wing fit: the antenna's span is outside the spans of the sub-IMUs that entered the fit at this
#: epoch (beyond the outermost or inside the innermost): the polynomial is extrapolated there
EXTRAPOLATED = 1 << 3
#: wing fit: fewer sub-IMUs entered the fit at this epoch than the wing carries (one in a gap, or
#: not estimated in this session)
FEWER_SUB_IMUS = 1 << 4
#: the main POS's attitude 1-sigma (its /master/nav covariance) was at or above the aligned
#: threshold (0.1 deg) at the master epoch before or after the row: the main POS lost its
#: alignment mid-session (the rows before its first alignment are not output at all)
MASTER_UNALIGNED = 1 << 5
#: the transfer alignment's innovations over the 60 s around the row's filter interval are
#: inconsistent with their covariance (windowed NIS outside its two-sided 99 % bounds,
#: :func:`.qc.inconsistent`): the sigma of the row may not describe its error
INCONSISTENT_INNOVATIONS = 1 << 6

NAMES = {RESTARTED_AFTER_GAP: "restarted_after_gap", BRIDGED_GAP: "bridged_gap", WING_FIT: "wing_fit",
         EXTRAPOLATED: "extrapolated", FEWER_SUB_IMUS: "fewer_sub_imus", MASTER_UNALIGNED: "master_unaligned",
         INCONSISTENT_INNOVATIONS: "inconsistent_innovations"}
#: the bits a sub-IMU's own rows carry into the wing fit's rows (OR over the sub-IMUs used at the epoch)
CARRIER_BITS = RESTARTED_AFTER_GAP | BRIDGED_GAP | MASTER_UNALIGNED | INCONSISTENT_INNOVATIONS

#: the dtype of the flags arrays
FlagArray = NDArray[np.uint32]


def none(n: int) -> FlagArray:
    """No flag on ``n`` rows: zeros (n,)."""
    return np.zeros(n, dtype=np.uint32)


def describe(flags: int) -> list[str]:
    """The names of the bits set in ``flags`` (unknown bits as ``bit<i>``)."""
    out = []
    for i in range(32):
        b = 1 << i
        if flags & b:
            out.append(NAMES.get(b, f"bit{i}"))
    return out
