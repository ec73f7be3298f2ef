"""Private numba kernel of the unscented transforms of :mod:`dpos_core.filters.gaussian` and
:func:`dpos_core.filters.runners._predict_given_sampled`: the weighted covariance and
cross-covariance of a point set's deviations in one pass (numpy's chain of swapaxes, products,
batched matmuls, the noise's sum and the symmetrization cost more than the sums themselves for
the transfer alignment's 49 points of 24 states).  Use those functions ([Gong2018] eq. 4-5)."""

from __future__ import annotations

import numba as nb
import numpy as np

from ._linalg_kernel import chol_one


@nb.njit(cache=True, nogil=True)
def moments(dX: np.ndarray, dY: np.ndarray, wc: np.ndarray, noise: np.ndarray, cov: np.ndarray, cross: np.ndarray) -> None:
    """For each batch b: ``cov[b] = sym(sum_l wc_l dY_bl dY_bl^T + noise)`` (q, q), ``sym(A) = (A + A^T) / 2``,
    and ``cross[b] = sum_l wc_l dX_bl dY_bl^T`` (a, q); dX (B, L, a), dY (B, L, q) the points'
    deviations from their means, wc (L,) the covariance weights, noise (q, q)."""
    B, L, q = dY.shape
    na = dX.shape[2]
    A = np.empty((q, q))
    wd = np.empty(max(q, na))
    for b in range(B):
        A[:, :] = 0.0
        C = cross[b]
        C[:, :] = 0.0
        for l in range(L):
            w = wc[l]
            for i in range(q):
                wd[i] = dY[b, l, i] * w
            for i in range(q):
                wi = wd[i]
                for j in range(q):
                    A[i, j] += wi * dY[b, l, j]
            for i in range(na):
                wd[i] = dX[b, l, i] * w
            for i in range(na):
                wi = wd[i]
                for j in range(q):
                    C[i, j] += wi * dY[b, l, j]
        S = cov[b]
        for i in range(q):
            for j in range(i, q):
                v = 0.5 * ((A[i, j] + noise[i, j]) + (A[j, i] + noise[j, i]))
                S[i, j] = v
                S[j, i] = v


@nb.njit(cache=True, nogil=True)
def correct(x: np.ndarray, P: np.ndarray, Pxz: np.ndarray, S: np.ndarray, nu: np.ndarray, xn: np.ndarray, Pn: np.ndarray,
            K: np.ndarray) -> bool:
    """The Kalman correction of each batch b: ``K = Pxz S^-1`` through the Cholesky factor of S
    (``S = L L^T``, ``K^T = L^-T L^-1 Pxz^T``), ``xn = x + K nu``, ``Pn = sym(P - K S K^T)``; x, nu,
    xn (B, n) / (B, p); P, Pn (B, n, n); Pxz, K (B, n, p); S (B, p, p) symmetric.  False (outputs
    partly written) when an S is not positive definite and finite: the caller's numpy path repairs
    or raises."""
    B, n, p = Pxz.shape
    L = np.empty((p, p))
    Y = np.empty((p, n))
    Kt = np.empty((p, n))
    KS = np.empty((n, p))
    A = np.empty((n, n))
    for b in range(B):
        if not chol_one(S[b], L):  # the Cholesky factor of S[b]
            return False
        for c in range(n):  # Y = L^-1 Pxz^T (as _linalg_kernel.forward)
            for i in range(p):
                e = Pxz[b, c, i]
                for j in range(i):
                    e -= L[i, j] * Y[j, c]
                Y[i, c] = e / L[i, i]
        for c in range(n):  # K^T = L^-T Y (as _linalg_kernel.backward_t)
            for i in range(p - 1, -1, -1):
                e = Y[i, c]
                for j in range(i + 1, p):
                    e -= L[j, i] * Kt[j, c]
                Kt[i, c] = e / L[i, i]
        for i in range(n):
            acc = 0.0
            for j in range(p):
                K[b, i, j] = Kt[j, i]
                acc += Kt[j, i] * nu[b, j]
            xn[b, i] = x[b, i] + acc
        for i in range(n):  # K S, then (K S) K^T
            for j in range(p):
                acc = 0.0
                for k in range(p):
                    acc += Kt[k, i] * S[b, k, j]
                KS[i, j] = acc
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(p):
                    acc += KS[i, k] * Kt[k, j]
                A[i, j] = P[b, i, j] - acc
        for i in range(n):
            for j in range(i, n):
                v = 0.5 * (A[i, j] + A[j, i])
                Pn[b, i, j] = v
                Pn[b, j, i] = v
    return True
