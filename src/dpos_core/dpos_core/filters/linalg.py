"""Small dense linear algebra shared by the filters (batched over leading axes).

Repairs are counted, not silent: :func:`chol` may add a small diagonal jitter to a covariance
that is positive semi-definite only up to rounding.  Every such repair increments the process
total (:func:`total_jitter_repairs`) and every active :class:`JitterRepairs` counter of the
calling thread (an estimator wraps its work in ``with counter:`` and reports
``counter.count``, e.g. ``chol_jitter_repairs`` in ``/ifa/status`` and the session products); the
first repair per call site is also warned (:class:`~dpos_core.errors.NumericalRepairWarning`,
with the jitter's magnitude).  A matrix that even the largest jitter does not make positive
definite raises :class:`~dpos_core.errors.NumericalFailure`.
"""

from __future__ import annotations

import sys
import threading
import warnings
from dataclasses import dataclass
from typing import cast

import numpy as np

from dpos_core.errors import NumericalFailure, NumericalRepairWarning
from dpos_core.units import FloatArray

from . import _linalg_kernel as _k
from . import _logpdf_kernel as _lk

#: the largest relative diagonal jitter :func:`chol` tries (of the matrix's largest diagonal element)
MAX_RELATIVE_JITTER = 1e-6


@dataclass
class JitterRepairs:
    """Counter of :func:`chol` jitter repairs (module docstring).

    Active in the thread that enters it (``with counter: ...``), nestable (every active counter
    of the thread counts), re-enterable; ``count`` keeps adding up over several ``with`` blocks.

    Attributes:
        count: repairs made (one per :func:`chol` call that needed a jitter; a batched call
            counts once).
        max_relative: the largest relative jitter used (of the largest diagonal element).
        max_absolute: the largest absolute jitter added to a diagonal element.
    """

    count: int = 0
    max_relative: float = 0.0
    max_absolute: float = 0.0

    def __enter__(self) -> JitterRepairs:
        _active().append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        stack = _active()
        for i in range(len(stack) - 1, -1, -1):  # the innermost entry of this counter
            if stack[i] is self:
                del stack[i]
                break

    def add(self, relative: float, absolute: float) -> None:
        self.count += 1
        self.max_relative = max(self.max_relative, relative)
        self.max_absolute = max(self.max_absolute, absolute)


_local = threading.local()
_total = JitterRepairs()
_total_lock = threading.Lock()
_warned_sites: set[tuple[str, int]] = set()


def _active() -> list[JitterRepairs]:
    stack = getattr(_local, "stack", None)
    if stack is None:
        stack = _local.stack = []
    return stack


def total_jitter_repairs() -> int:
    """Jitter repairs made by :func:`chol` in this process so far (every thread)."""
    return _total.count


def reset_repair_warnings() -> None:
    """Forget which call sites were warned (the next repair at each is warned again; tests)."""
    _warned_sites.clear()


def _record_repair(relative: float, absolute: float, n: int) -> None:
    """Count a repair in the process total and the thread's active counters; warn the first one
    of each call site (the first frame outside this module)."""
    with _total_lock:
        _total.add(relative, absolute)
    for c in _active():
        c.add(relative, absolute)
    frame = sys._getframe(0)
    level = 1
    while frame.f_back is not None and frame.f_code.co_filename == __file__:
        frame = frame.f_back
        level += 1
    site = (frame.f_code.co_filename, frame.f_lineno)
    if site in _warned_sites:
        return
    _warned_sites.add(site)
    warnings.warn(f"chol: a {n}x{n} covariance is not positive definite to rounding; repaired with a relative diagonal "
                  f"jitter of {relative:.0e} (absolute {absolute:.3g}); later repairs at this call site are only counted",
                  NumericalRepairWarning, stacklevel=level)


def symmetrize(P: FloatArray) -> FloatArray:
    """``(P + P^T) / 2`` over the last two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def chol(P: FloatArray, jitter: float = 1e-12) -> FloatArray:
    """Lower Cholesky factor of (a batch of) SPD matrices.

    A matrix that is PSD up to rounding gets a relative diagonal jitter (``jitter``, then x100
    steps up to ``MAX_RELATIVE_JITTER`` of its largest diagonal element): the repair is counted
    and warned once per call site (module docstring).  Anything worse - an indefinite matrix,
    non-finite entries (which LAPACK would pass through as a NaN factor) - raises
    :class:`~dpos_core.errors.NumericalFailure`.
    """
    P = np.asarray(P, dtype=float)
    fast = chol_unrepaired(P)  # the common case (positive definite, finite); anything else below
    if fast is not None:
        return fast
    P = symmetrize(P)
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    else:
        if np.all(np.isfinite(L)):
            return cast(FloatArray, L)  # float64 in, float64 out (numpy's stub says floating[Any])
        raise NumericalFailure(f"a {P.shape[-1]}x{P.shape[-1]} covariance has non-finite entries (the filter diverged)",
                               what="covariance")
    scale = np.max(np.abs(np.diagonal(P, axis1=-2, axis2=-1)), axis=-1)[..., None, None]
    eye = np.eye(P.shape[-1])
    eps = jitter
    while eps <= MAX_RELATIVE_JITTER:
        try:
            L = np.linalg.cholesky(P + eps * scale * eye)
        except np.linalg.LinAlgError:
            eps *= 100.0
            continue
        _record_repair(eps, float(eps * np.max(scale)), P.shape[-1])
        return cast(FloatArray, L)
    raise NumericalFailure(f"a {P.shape[-1]}x{P.shape[-1]} covariance is not positive definite, even with a relative "
                           f"diagonal jitter of {MAX_RELATIVE_JITTER:g} ({_why_not_pd(P)})", what="covariance")


def chol_unrepaired(P: FloatArray) -> FloatArray | None:
    """The lower Cholesky factors (..., n, n) of the symmetrized ``P`` (..., n, n) when every matrix
    is positive definite and finite as it is, else None (no repair: :func:`chol` repairs)."""
    if P.ndim < 2 or P.shape[-1] != P.shape[-2] or not P.size:
        return None
    flat = np.ascontiguousarray(P, dtype=float).reshape((-1,) + P.shape[-2:])
    L = np.empty_like(flat)
    return L.reshape(P.shape) if _k.chol(flat, L) else None


def _why_not_pd(P: FloatArray) -> str:
    """A short diagnosis of a matrix that has no Cholesky factor (for the error message)."""
    if not np.all(np.isfinite(P)):
        return "it has non-finite entries"
    try:
        ev = np.linalg.eigvalsh(P)
    except np.linalg.LinAlgError:
        return "its eigenvalues do not converge"
    return f"smallest eigenvalue {float(np.min(ev)):.3g}, largest {float(np.max(ev)):.3g}"


def _lower_solve(L: FloatArray, B: FloatArray, transposed: bool = False) -> FloatArray:
    """``L^-1 B`` (or ``L^-T B``) for lower-triangular ``L`` (..., n, n) and ``B`` (..., n, k), broadcast together."""
    n, k = B.shape[-2], B.shape[-1]
    batch = L.shape[:-2] if L.shape[:-2] == B.shape[:-2] else np.broadcast_shapes(L.shape[:-2], B.shape[:-2])
    Lb = np.ascontiguousarray(L if L.shape[:-2] == batch else np.broadcast_to(L, batch + (n, n))).reshape(-1, n, n)
    Bb = np.ascontiguousarray(B if B.shape[:-2] == batch else np.broadcast_to(B, batch + (n, k)), dtype=float).reshape(-1, n, k)
    out = np.empty_like(Bb)
    (_k.backward_t if transposed else _k.forward)(Lb, Bb, out)
    return out.reshape(batch + (n, k))


def solve_lower(L: FloatArray, B: FloatArray) -> FloatArray:
    """``L^-1 B`` for lower-triangular ``L`` (..., n, n) (a :func:`chol` factor) and ``B`` (..., n, k)."""
    return _lower_solve(L, B)


def solve_spd(S: FloatArray, B: FloatArray) -> FloatArray:
    """``S^-1 B`` for SPD ``S`` (..., p, p) and ``B`` (..., p, m) through a Cholesky factor."""
    L = chol(S)
    return _lower_solve(L, _lower_solve(L, np.asarray(B, dtype=float)), transposed=True)


def gain(Pxy: FloatArray, Pyy: FloatArray) -> FloatArray:
    """Kalman gain ``Pxy Pyy^-1`` (..., n, p) without forming an inverse."""
    return np.swapaxes(solve_spd(Pyy, np.swapaxes(Pxy, -1, -2)), -1, -2)


def gauss_logpdf(r: FloatArray, S: FloatArray) -> FloatArray:
    """log N(r; 0, S) for residuals r (..., p) and covariances S (..., p, p), broadcast together."""
    L = chol(S)
    p = r.shape[-1]
    r = np.asarray(r, dtype=float)
    if L.ndim == 2 and r.ndim == 2:  # one covariance for every residual (N, p): one pass (numba kernel)
        out = np.empty(r.shape[0])
        _lk.gauss_logpdf_rows(L, np.ascontiguousarray(r), out)
        return out
    z = _lower_solve(L, r[..., None])[..., 0]
    half_logdet = np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * np.sum(z * z, axis=-1) - half_logdet - 0.5 * p * np.log(2.0 * np.pi)


def whitener(S: FloatArray) -> tuple[FloatArray, float]:
    """``(W, log_norm)`` with ``W = L^-1`` (``S = L L^T``, (p, p)) and ``log_norm = -log det(L) - p/2 log 2 pi``,
    so that ``log N(r; 0, S) = log_norm - |r W^T|^2 / 2`` for any number of residuals r (..., p)."""
    L = chol(S)
    p = S.shape[-1]
    W = _lower_solve(L, np.eye(p))
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
