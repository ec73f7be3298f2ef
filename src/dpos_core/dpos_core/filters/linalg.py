"""Small dense linear algebra shared by the filters (batched over leading axes)."""

from __future__ import annotations

from dpos_core.units import FloatArray

import numpy as np
from numpy.typing import NDArray



def symmetrize(P: FloatArray) -> FloatArray:
    """``(P + P^T) / 2`` over the last two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def chol(P: FloatArray, jitter: float = 1e-12) -> FloatArray:
    """Lower Cholesky factor of (a batch of) SPD matrices.

    A matrix that is PSD up to rounding gets a relative diagonal jitter (up to 1e-6 of its
    largest diagonal element); anything worse raises ``np.linalg.LinAlgError``.
    """
    P = symmetrize(np.asarray(P, dtype=float))
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    scale = np.max(np.abs(np.diagonal(P, axis1=-2, axis2=-1)), axis=-1)[..., None, None]
    eye = np.eye(P.shape[-1])
    eps = jitter
    while eps <= 1e-6:
        try:
            return np.linalg.cholesky(P + eps * scale * eye)
        except np.linalg.LinAlgError:
            eps *= 100.0
    raise np.linalg.LinAlgError("covariance is not positive definite")


def solve_spd(S: FloatArray, B: FloatArray) -> FloatArray:
    """``S^-1 B`` for SPD ``S`` (..., p, p) and ``B`` (..., p, m) through a Cholesky factor."""
    L = chol(S)
    y = np.linalg.solve(L, B)
    return np.linalg.solve(np.swapaxes(L, -1, -2), y)


def gain(Pxy: FloatArray, Pyy: FloatArray) -> FloatArray:
    """Kalman gain ``Pxy Pyy^-1`` (..., n, p) without forming an inverse."""
    return np.swapaxes(solve_spd(Pyy, np.swapaxes(Pxy, -1, -2)), -1, -2)


def logdet_spd(S: FloatArray) -> FloatArray:
    L = chol(S)
    return 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)


def gauss_logpdf(r: FloatArray, S: FloatArray) -> FloatArray:
    """log N(r; 0, S) for residuals r (..., p) and covariances S (..., p, p), broadcast together."""
    L = chol(S)
    p = r.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], L.shape[:-2])
    z = np.linalg.solve(np.broadcast_to(L, batch + (p, p)), np.broadcast_to(r, batch + (p,))[..., None])[..., 0]
    half_logdet = np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * np.sum(z * z, axis=-1) - half_logdet - 0.5 * p * np.log(2.0 * np.pi)


def whitener(S: FloatArray) -> tuple[FloatArray, float]:
    """``(W, log_norm)`` with ``W = L^-1`` (``S = L L^T``, (p, p)) and ``log_norm = -log det(L) - p/2 log 2 pi``,
    so that ``log N(r; 0, S) = log_norm - |r W^T|^2 / 2`` for any number of residuals r (..., p)."""
    L = chol(S)
    p = S.shape[-1]
    W = np.linalg.solve(L, np.eye(p))
    return W, float(-np.sum(np.log(np.diag(L))) - 0.5 * p * np.log(2.0 * np.pi))


def householder_tria(A: FloatArray) -> FloatArray:
    """Square-root triangularization: lower-triangular ``S`` (..., n, n) with ``S S^T = A A^T``
    for ``A`` (..., n, m), m >= n, via Householder QR of ``A^T`` (Norgaard et al. 2000)."""
    r = np.linalg.qr(np.swapaxes(A, -1, -2), mode="r")
    S = np.swapaxes(r, -1, -2)
    # make the diagonal non-negative (QR is unique up to signs)
    sgn = np.sign(np.diagonal(S, axis1=-2, axis2=-1))
    sgn = np.where(sgn == 0, 1.0, sgn)
    return S * sgn[..., None, :]
