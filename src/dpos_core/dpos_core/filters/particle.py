"""Particle-filter utilities: log weights, effective sample size, resampling schemes."""

from __future__ import annotations

from dpos_core.units import FloatArray

import numpy as np
from numpy.typing import NDArray



def log_normalize(logw: FloatArray) -> FloatArray:
    """Normalize log weights (N,) so that sum(exp) = 1; all -inf is an error."""
    m = np.max(logw)
    if not np.isfinite(m):
        raise FloatingPointError("all particle weights are zero (or NaN)")
    return logw - (m + np.log(np.sum(np.exp(logw - m))))


def ess(logw: FloatArray) -> float:
    """Effective sample size ``1 / sum w^2`` of normalized log weights."""
    return float(1.0 / np.sum(np.exp(2.0 * logw)))


def systematic_resample(logw: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
    """Systematic resampling: indices (N,) with one uniform offset (Kitagawa 1996)."""
    N = logw.shape[0]
    c = np.cumsum(np.exp(logw))
    c[-1] = 1.0
    return np.searchsorted(c, (rng.random() + np.arange(N)) / N, side="right").clip(0, N - 1)


def stratified_resample(logw: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
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
