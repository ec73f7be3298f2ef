"""Private numba kernel of :mod:`dpos_core.filters.linalg`: the Gaussian log densities of many
residuals under one covariance in one pass (the particle filter's weights: N = 100 residuals of
p = 9 a filter epoch), where numpy's per-call overhead (reductions over short axes, a broadcast
copy of the factor) dominated.  Use :func:`~dpos_core.filters.linalg.gauss_logpdf`."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def gauss_logpdf_rows(L: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = log N(r_i; 0, L L^T)`` (N,) of residuals r (N, p) under one covariance given by its
    lower Cholesky factor L (p, p): ``-|L^-1 r_i|^2 / 2 - sum log L_jj - p/2 log 2 pi``."""
    N, p = r.shape
    half_logdet = 0.0
    for j in range(p):
        half_logdet += math.log(L[j, j])
    c = half_logdet + 0.5 * p * math.log(2.0 * math.pi)
    z = np.empty(p)
    for i in range(N):
        q = 0.0
        for a in range(p):
            e = r[i, a]
            for b in range(a):
                e -= L[a, b] * z[b]
            z[a] = e / L[a, a]
            q += z[a] * z[a]
        out[i] = -0.5 * q - c
