"""Private numba kernel of the wing fit's per-epoch weighted least squares
(:func:`dpos_core.ta.wingfit.wls`): one small normal-equation system per epoch (p <= 5 unknowns,
tens of thousands of epochs), where numpy's batched LAPACK calls spent microseconds per matrix.
Use :func:`~dpos_core.ta.wingfit.wls`; the method is documented there."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def normal_solve(B: np.ndarray, w: np.ndarray, yz: np.ndarray, use: np.ndarray,
                 a: np.ndarray, P: np.ndarray, bound: np.ndarray, want_P: bool) -> None:
    """Per epoch t with ``use[t]``: the normal matrix ``N = B^T diag(w_t) B`` (B (S, p), w (T, S)),
    its Cholesky factor ``L``, ``P = (L L^T)^-1 = L^-T L^-1`` (T, p, p), the coefficients
    ``a = P B^T diag(w_t) yz_t`` (T, p) and ``bound[t] = trace(N) trace(P)``, an upper bound of
    the condition number of N (inf where the factorization fails); ``P`` only with ``want_P``.
    Epochs without ``use`` are left untouched."""
    T, S = w.shape
    p = B.shape[1]
    N = np.empty((p, p))
    L = np.zeros((p, p))
    Li = np.zeros((p, p))
    rhs = np.empty(p)
    u = np.empty(p)
    for t in range(T):
        if not use[t]:
            continue
        for i in range(p):
            r = 0.0
            for s in range(S):
                r += B[s, i] * (w[t, s] * yz[t, s])
            rhs[i] = r
            for j in range(i + 1):
                acc = 0.0
                for s in range(S):
                    acc += B[s, i] * w[t, s] * B[s, j]
                N[i, j] = acc
                N[j, i] = acc
        failed = False
        for j in range(p):
            d = N[j, j]
            for k in range(j):
                d -= L[j, k] * L[j, k]
            if not d > 0.0:
                failed = True
                break
            L[j, j] = math.sqrt(d)
            for i in range(j + 1, p):
                e = N[i, j]
                for k in range(j):
                    e -= L[i, k] * L[j, k]
                L[i, j] = e / L[j, j]
        if failed:
            bound[t] = np.inf
            continue
        # Li = L^-1 (lower triangular), by forward substitution on the identity's columns
        for j in range(p):
            for i in range(p):
                if i < j:
                    Li[i, j] = 0.0
                    continue
                e = 1.0 if i == j else 0.0
                for k in range(j, i):
                    e -= L[i, k] * Li[k, j]
                Li[i, j] = e / L[i, i]
        trN = 0.0
        trP = 0.0  # trace(L^-T L^-1) = |L^-1|_F^2
        for i in range(p):
            trN += N[i, i]
            for j in range(i + 1):
                trP += Li[i, j] * Li[i, j]
        if want_P:
            for i in range(p):
                for j in range(p):
                    acc = 0.0
                    for k in range(max(i, j), p):
                        acc += Li[k, i] * Li[k, j]
                    P[t, i, j] = acc
        # a = L^-T (L^-1 rhs)
        for i in range(p):
            acc = 0.0
            for j in range(i + 1):
                acc += Li[i, j] * rhs[j]
            u[i] = acc
        for i in range(p):
            acc = 0.0
            for k in range(i, p):
                acc += Li[k, i] * u[k]
            a[t, i] = acc
        bound[t] = trN * trP
