"""The correlation factor of a series of residuals or innovations: by how much their correlation in
time shrinks the number of independent samples (the variance of a mean of N such samples is the
factor over N instead of 1 over N)."""

from __future__ import annotations

import numpy as np

from .units import FloatArray

__all__ = ["correlation_factor"]


def correlation_factor(r: FloatArray, max_lag: int = 50) -> float:
    """``1 + 2 sum_j rho_j`` of ``r`` ((K,) or (K, m): the components pooled), ``rho_j`` its
    autocorrelation at lag j samples about its mean, summed up to the first lag where it is not
    positive, at most ``max_lag``; 1 for a constant or too short series (at least 1 always)."""
    r = np.asarray(r, dtype=float)
    r = r - r.mean(axis=0)
    den = float((r * r).sum())
    if den <= 0:
        return 1.0
    tot = 0.0
    for j in range(1, min(max_lag, r.shape[0] - 1)):
        rho = float((r[j:] * r[:-j]).sum()) / den
        if rho <= 0:
            break
        tot += rho
    return 1.0 + 2.0 * tot
