"""The first-order autoregression of the simulator's Gauss-Markov processes (numba).

``x_i = a x_{i-1} + w_i`` per column, from ``x_{-1} = x0``: the values ``scipy.signal.lfilter([1],
[1, -a], w, axis=0, zi=a x0)`` gives (the same two operations per sample), without importing
``scipy.signal`` (which imports ``scipy.stats``: about 1 s of CPU in every simulating process).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from dpos_core.units import FloatArray


@nb.njit(cache=True, nogil=True)
def _ar1(w: FloatArray, a: float, x0: FloatArray) -> FloatArray:
    out = np.empty_like(w)
    x = x0.copy()
    for i in range(w.shape[0]):
        for j in range(w.shape[1]):
            x[j] = w[i, j] + a * x[j]
            out[i, j] = x[j]
    return out


def ar1(w: FloatArray, a: float, x0: FloatArray) -> FloatArray:
    """``x`` (N, k) with ``x_i = a x_{i-1} + w_i`` from ``x_{-1} = x0`` (k,), for the driving noise ``w`` (N, k)."""
    w = np.ascontiguousarray(w, dtype=np.float64)
    x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(w.shape[1])
    return _ar1(w, float(a), x0)
