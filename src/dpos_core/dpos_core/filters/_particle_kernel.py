"""Private numba kernel of the FFBSm backward step (:func:`dpos_core.filters.runners.ffbsm`,
[Gong2018] eq. 9): the N x N transition log densities and the two log-sum-exps of one epoch in
one pass.  Use :func:`~dpos_core.filters.runners.ffbsm`, which documents the method."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _lse(a: np.ndarray) -> float:
    """``log sum exp a`` as runners._logsumexp (a non-finite maximum is taken as 0)."""
    m = -np.inf
    for v in a:
        if v > m or math.isnan(v):
            m = v
    if not math.isfinite(m):
        m = 0.0
    acc = 0.0
    for v in a:
        acc += math.exp(v - m)
    return m + math.log(acc)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def backward_step(lwk: np.ndarray, lw_next: np.ndarray, nxt: np.ndarray, mean: np.ndarray, W: np.ndarray,
                  half_logdet: np.ndarray, out: np.ndarray) -> None:
    """One epoch of the FFBSm recursion, before normalization: ``out[i] = lwk[i] + lse_j(lw_next[j]
    + L[i, j] - lse_m(lwk[m] + L[m, j]))`` with ``L[i, j] = -|W_i (nxt_j - mean_i)|^2 / 2 -
    half_logdet[i]`` (lwk, lw_next, half_logdet, out (N,); nxt, mean (N, s); W (N, s, s) the
    inverse Cholesky factors of the predicted covariances)."""
    N, s = nxt.shape
    L = np.empty((N, N))
    for i in range(N):
        for j in range(N):
            q = 0.0
            for a in range(s):
                z = 0.0
                for b in range(s):
                    z += W[i, a, b] * (nxt[j, b] - mean[i, b])
                q += z * z
            L[i, j] = -0.5 * q - half_logdet[i]
    col = np.empty(N)
    denom = np.empty(N)
    for j in range(N):
        for i in range(N):
            col[i] = lwk[i] + L[i, j]
        denom[j] = _lse(col)
    for i in range(N):
        for j in range(N):
            col[j] = lw_next[j] + L[i, j] - denom[j]
        out[i] = lwk[i] + _lse(col)
