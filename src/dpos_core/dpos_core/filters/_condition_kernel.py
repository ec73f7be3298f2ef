"""Private numba kernel of :func:`dpos_core.filters.runners._condition`: Gaussians conditioned on
some of their components (the Rao-Blackwellized UPF's proposal, every epoch, for 100 particles)
in one pass instead of numpy's solves, products, symmetrization and masking.  Use
:func:`~dpos_core.filters.runners._condition`, which documents the formulas."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def condition(m: np.ndarray, P: np.ndarray, S: np.ndarray, L: np.ndarray, xs: np.ndarray, m_c: np.ndarray, P_c: np.ndarray) -> None:
    """``G = P[:, S] P[S, S]^-1`` through the Cholesky factor ``L`` of ``P[S, S]`` (two triangular
    solves), ``m_c[i] = m[i] + G (xs[i] - m[i, S])``, ``P_c = sym(P - G P[:, S]^T)`` with the rows and
    columns S zeroed.  m, m_c (N, n); P, P_c (B, n, n) and L (B, s, s): B = 1 (one covariance shared
    by every particle) or N; S (s,) indices; xs (N, s)."""
    N, n = m.shape
    B = P.shape[0]
    s = S.shape[0]
    Y = np.empty((s, n))
    Gt = np.empty((B, s, n))
    for b in range(B):
        Lb = L[b]
        for c in range(n):  # Y = L^-1 P[S, :]  (= L^-1 P[:, S]^T)
            for i in range(s):
                e = P[b, c, S[i]]
                for j in range(i):
                    e -= Lb[i, j] * Y[j, c]
                Y[i, c] = e / Lb[i, i]
        for c in range(n):  # G^T = L^-T Y
            for i in range(s - 1, -1, -1):
                e = Y[i, c]
                for j in range(i + 1, s):
                    e -= Lb[j, i] * Gt[b, j, c]
                Gt[b, i, c] = e / Lb[i, i]
        A = P_c[b]
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(s):
                    acc += Gt[b, k, i] * P[b, j, S[k]]
                A[i, j] = P[b, i, j] - acc
        for i in range(n):
            for j in range(i, n):
                v = 0.5 * (A[i, j] + A[j, i])
                A[i, j] = v
                A[j, i] = v
        for k in range(s):
            for j in range(n):
                A[S[k], j] = 0.0
                A[j, S[k]] = 0.0
    d = np.empty(s)
    for p in range(N):
        b = 0 if B == 1 else p
        for k in range(s):
            d[k] = xs[p, k] - m[p, S[k]]
        for i in range(n):
            acc = 0.0
            for k in range(s):
                acc += Gt[b, k, i] * d[k]
            m_c[p, i] = m[p, i] + acc
