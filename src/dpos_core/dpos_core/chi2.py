"""Chi-square quantiles from ``scipy.special.gammaincinv``, without importing ``scipy.stats``.

``chi2.ppf(q, k) = 2 P^-1(k / 2, q)``, with ``P^-1`` the inverse of the regularized lower incomplete
gamma function: the value ``scipy.stats.chi2.ppf`` computes. Importing ``scipy.stats`` costs about
1 s of CPU, in every process that starts (each node, each command, each transfer-alignment
worker), so the estimation code asks this module instead (test/dpos_core/test_chi2.py checks both
the values and that the entry points do not import ``scipy.stats``).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import gammaincinv

__all__ = ["chi2_ppf", "chi2_quantile"]


def chi2_ppf(q: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The ``q`` quantile(s) of chi^2(``dof``), broadcast over ``q`` and ``dof`` (float array).

    A scalar ``q`` with a long ``dof`` array of few distinct values (a window's degrees of freedom at
    every epoch of a flight) computes each distinct quantile once."""
    q_arr = np.asarray(q, dtype=float)
    d = np.asarray(dof, dtype=float)
    if q_arr.ndim == 0 and d.ndim > 0:
        u, inv = np.unique(d, return_inverse=True)
        return np.asarray(2.0 * gammaincinv(u / 2.0, q_arr), dtype=float)[inv].reshape(d.shape)
    return np.asarray(2.0 * gammaincinv(d / 2.0, q_arr), dtype=float)


@lru_cache(maxsize=256)
def chi2_quantile(q: float, dof: int | float) -> float:
    """The ``q`` quantile of chi^2(``dof``) as a float (cached: filters ask for the same few at every epoch)."""
    return float(2.0 * gammaincinv(float(dof) / 2.0, float(q)))
