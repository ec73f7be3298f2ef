"""Numerical Jacobian by central differences, for the models whose Jacobians are not written out
(the AEKF of the in-flight alignment, [Fang2012]'s baseline; the oracle's linearization of the
transfer-alignment model about the truth, dpos_core.ta.oracle).

    J[:, j] = (f(x + d_j e_j) - f(x - d_j e_j)) / (2 d_j)

The error is ``d_j^2 / 6 f'''`` (second order in the step) plus the rounding of ``f`` divided by
``d_j``; steps of about ``1e-6`` of the component's scale balance the two.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dpos_core.units import FloatArray


def central_difference_jacobian(fn: Callable[[FloatArray], FloatArray], x: FloatArray, step: FloatArray) -> FloatArray:
    """Jacobian (m, n) of ``fn`` at ``x`` (n,) by central differences.

    Args:
        fn: vectorized function (k, n) -> (k, m); it is called once with the 2n points
            ``x + d_j e_j`` (rows 0..n-1) and ``x - d_j e_j`` (rows n..2n-1).
        x: the point (n,).
        step: per-component steps ``d_j`` (n,), > 0, in the units of ``x``.
    """
    n = x.shape[0]
    D = np.diag(step)
    Y = fn(np.concatenate([x[None] + D, x[None] - D]))
    return ((Y[:n] - Y[n:]) / (2.0 * step[:, None])).T


def steps_from_cov(P: FloatArray, rel_step: float = 1e-6) -> FloatArray:
    """Steps (n,) of ``rel_step`` times each state's standard deviation (from the covariance P
    (n, n)), at least ``rel_step * 1e-12``: the AEKF's choice ([Fang2012]'s baseline)."""
    return rel_step * np.maximum(np.sqrt(np.diag(P)), 1e-12)
