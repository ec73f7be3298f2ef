"""Particle-filter utilities: log weights, effective sample size, resampling schemes."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dpos_core.errors import NumericalFailure
from dpos_core.units import FloatArray


def log_normalize(logw: FloatArray) -> FloatArray:
    """Normalize log weights (N,) so that sum(exp) = 1; all -inf (or NaN) weights - a particle
    filter that diverged - raise :class:`~dpos_core.errors.NumericalFailure`."""
    m = np.max(logw)
    if not np.isfinite(m):
        raise NumericalFailure("all particle weights are zero (or NaN): the particle filter diverged", what="particle filter")
    return logw - (m + np.log(np.sum(np.exp(logw - m))))


def ess(logw: FloatArray) -> float:
    """Effective sample size ``1 / sum w^2`` of normalized log weights."""
    return float(1.0 / np.sum(np.exp(2.0 * logw)))


#: the resampling schemes of :func:`resample_indices` (``run_upf(resample=...)``); the first is the default
RESAMPLING = ("systematic", "stratified", "multinomial")


def resample_indices(logw: FloatArray, rng: np.random.Generator, scheme: str = RESAMPLING[0]) -> NDArray[np.intp]:
    """Indices (N,) of the particles to keep, drawn by ``scheme`` (one of :data:`RESAMPLING`)
    from normalized log weights (N,); each scheme draws index i N w_i times in expectation."""
    if scheme not in _SCHEMES:
        raise ValueError(f"unknown resampling scheme {scheme!r}; choose one of {RESAMPLING}")
    return _SCHEMES[scheme](logw, rng)


def systematic_resample(logw: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
    """Systematic resampling: indices (N,) with one uniform offset (Kitagawa 1996)."""
    N = logw.shape[0]
    c = np.cumsum(np.exp(logw))
    c[-1] = 1.0
    return np.searchsorted(c, (rng.random() + np.arange(N)) / N, side="right").clip(0, N - 1)


def stratified_resample(logw: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
    """Stratified resampling: indices (N,), one uniform draw in each of the N strata (Kitagawa 1996)."""
    N = logw.shape[0]
    c = np.cumsum(np.exp(logw))
    c[-1] = 1.0
    return np.searchsorted(c, (rng.random(N) + np.arange(N)) / N, side="right").clip(0, N - 1)


def multinomial_resample(logw: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
    """Plain SIR resampling (Gordon, Salmond, Smith 1993)."""
    N = logw.shape[0]
    c = np.cumsum(np.exp(logw))
    c[-1] = 1.0
    return np.searchsorted(c, rng.random(N), side="right").clip(0, N - 1)


_SCHEMES = {"systematic": systematic_resample, "stratified": stratified_resample, "multinomial": multinomial_resample}
