"""Private numba kernel of :func:`dpos_core.filters.points.symmetric_points`: the 2n + 1 points of
a batch of means and square roots written in one pass (numpy's transpose, scaling, two sums and
concatenation cost more than the points for the transfer alignment's n = 21-24).  Use
:mod:`dpos_core.filters.points`."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def symmetric_points(x: np.ndarray, S: np.ndarray, scale: float, out: np.ndarray) -> None:
    """``out[b] = [x_b, x_b + scale s_1 .. x_b + scale s_n, x_b - scale s_1 .. x_b - scale s_n]``
    (B, 2n + 1, n), ``s_j`` the columns of ``S[b]`` (B, n, n); x (B, n)."""
    B, n = x.shape
    for b in range(B):
        for i in range(n):
            out[b, 0, i] = x[b, i]
        for j in range(n):
            for i in range(n):
                d = scale * S[b, i, j]
                out[b, 1 + j, i] = x[b, i] + d
                out[b, 1 + n + j, i] = x[b, i] - d
