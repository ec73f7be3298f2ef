"""Private numba kernels of :mod:`dpos_core.filters.linalg`: Cholesky factors and triangular
solves of batches of small matrices (the filters' covariances, n <= a few dozen), where numpy's
per-call overhead of its LAPACK wrappers dominated.  Use :mod:`.linalg`; a factorization that
fails here (not positive definite to rounding, non-finite entries) is left to its numpy path,
which repairs or raises."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, inline="always")
def chol_one(A: np.ndarray, F: np.ndarray) -> bool:
    """Lower Cholesky factor ``F`` (n, n) of the symmetrized ``(A + A^T) / 2`` (A (n, n)); False
    (``F`` partly written) when a pivot is not positive or not finite or an entry not finite."""
    n = A.shape[0]
    for j in range(n):
        d = 0.5 * (A[j, j] + A[j, j])
        for k in range(j):
            d -= F[j, k] * F[j, k]
        if not (d > 0.0 and d < np.inf):
            return False
        ljj = math.sqrt(d)
        F[j, j] = ljj
        for i in range(j):
            F[i, j] = 0.0
        for i in range(j + 1, n):
            e = 0.5 * (A[i, j] + A[j, i])
            for k in range(j):
                e -= F[i, k] * F[j, k]
            F[i, j] = e / ljj
        # an off-diagonal NaN leaves the pivots finite: check the column
        for i in range(j + 1, n):
            if not math.isfinite(F[i, j]):
                return False
    return True


@nb.njit(cache=True, nogil=True)
def chol(P: np.ndarray, L: np.ndarray) -> bool:
    """Lower Cholesky factors ``L`` (M, n, n) of the symmetrized ``(P + P^T) / 2`` (P (M, n, n));
    False (``L`` partly written) when a pivot is not positive or not finite (:func:`chol_one`)."""
    for m in range(P.shape[0]):
        if not chol_one(P[m], L[m]):
            return False
    return True


@nb.njit(cache=True, nogil=True)
def forward(L: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """``L^-1 B`` for lower-triangular L (M, n, n) and B (M, n, k) into ``out`` (M, n, k)."""
    M, n, k = B.shape
    for m in range(M):
        F = L[m]
        for c in range(k):
            for i in range(n):
                e = B[m, i, c]
                for j in range(i):
                    e -= F[i, j] * out[m, j, c]
                out[m, i, c] = e / F[i, i]


@nb.njit(cache=True, nogil=True)
def backward_t(L: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """``L^-T B`` for lower-triangular L (M, n, n) and B (M, n, k) into ``out`` (M, n, k)."""
    M, n, k = B.shape
    for m in range(M):
        F = L[m]
        for c in range(k):
            for i in range(n - 1, -1, -1):
                e = B[m, i, c]
                for j in range(i + 1, n):
                    e -= F[j, i] * out[m, j, c]
                out[m, i, c] = e / F[i, i]
