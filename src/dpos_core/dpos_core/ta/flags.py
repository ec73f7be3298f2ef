"""Quality flags of the transfer alignment's output rows: an integer bitmask per sample.

``0`` is a row estimated from uninterrupted sub-IMU data.  A set bit says why the row deserves
care; its 1-sigma already accounts for the cause (the flags say *why* a sigma is what it is, they
do not replace it).  Written as the ``flags`` column of the antenna CSV (design.md "Session
products").

Bits 0-1 are set by :func:`dpos_core.ta.pipeline.run_segments` / :func:`~dpos_core.ta.pipeline.run`;
bits from 2 on are reserved for later checks (e.g. an unaligned main POS, inconsistent
innovations) and never set today.
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

NAMES = {RESTARTED_AFTER_GAP: "restarted_after_gap", BRIDGED_GAP: "bridged_gap"}

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
