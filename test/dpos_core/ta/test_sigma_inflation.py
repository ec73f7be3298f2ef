"""The innovation-based sigma inflation (dpos_core.ta.qc.sigma_scale)."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.filters.model import LinearGaussianModel
from dpos_core.filters.runners import run_sigma_point_filter, smooth_gaussian
from dpos_core.ta import qc


def _ta_like(K: int, c: float, seed: int = 0, p: int = 9):
    """A linear stand-in of the transfer alignment's state (attitude, velocity, position errors;
    position integrates velocity) matched in all three groups (``p`` 9) or in attitude and velocity
    (6), filtered and RTS-smoothed by a filter whose Q and R are both ``c`` times too small.
    Returns the QC, the true states (K, 9) and the smoothed mean (K, 9) and sigma (K, 9)."""
    rng = np.random.default_rng(seed)
    n = 9
    F_ = np.eye(n)
    F_[6:9, 3:6] = np.eye(3)
    q = np.array([1e-4] * 3 + [1e-3] * 3 + [1e-4] * 3)
    r = np.array([0.01] * 3 + [0.04] * 3 + [0.09] * 3)[:p]
    H = np.eye(n)[:p]
    x = np.zeros(n)
    xs_true, ys = np.empty((K, n)), np.empty((K, p))
    for k in range(K):
        if k:
            x = F_ @ x + np.sqrt(q) * rng.normal(size=n)
        xs_true[k] = x
        ys[k] = H @ x + np.sqrt(r) * rng.normal(size=p)
    tr = run_sigma_point_filter(LinearGaussianModel(F_, np.diag(q / c), H, np.diag(r / c), ys), np.zeros(n), np.eye(n) * 1e-6)
    xs, Ps = smooth_gaussian(tr)
    return (qc.epoch_qc(np.arange(K, dtype=float), tr.nu, tr.S, tr.x_f, tr.P_f, xs, Ps), xs_true, xs,
            np.sqrt(np.diagonal(Ps, axis1=1, axis2=2)))


def test_a_consistent_filter_keeps_its_sigma() -> None:
    q, *_ = _ta_like(1500, 1.0)
    s = qc.sigma_scale(q, q.epochs_s)
    assert np.mean(s == 1.0) > 0.97, np.mean(s == 1.0)  # the 99 % bound of each window: rare by chance
    assert s.max() < 1.2  # a window just past its bound (the half windows at the ends: 90 samples)


@pytest.mark.parametrize("p", [9, 6])
def test_optimistic_filter_is_inflated_to_honest(p: int) -> None:
    """Q and R 4x too small: the smoothed sigma covers the errors 2 sigma only ~68 % of the time;
    scaled by the innovations' factor (sqrt 4 = 2) it covers them ~95 % (issue: 95 % within 2 sigma).
    Without position matching (p = 6) the position takes the velocity matches' factor."""
    q, x_true, xs, sig = _ta_like(1500, 4.0, p=p)
    e = (xs - x_true)[100:]
    before = np.mean(np.abs(e) < 2 * sig[100:], axis=0)
    s = qc.sigma_scale(q, q.epochs_s)
    after = np.mean(np.abs(e) < 2 * (sig * s)[100:], axis=0)
    np.testing.assert_allclose(np.median(s[100:], axis=0), 2.0, rtol=0.12)
    assert np.all(before < 0.85), before
    assert np.all((after > 0.90) & (after < 0.99)), after
    if p == 6:
        np.testing.assert_array_equal(s[:, 6:9], s[:, 3:6])


def test_only_the_optimistic_group_is_inflated() -> None:
    """Velocity matches 9x optimistic, the others consistent: only the velocity sigma x3."""
    q, *_ = _ta_like(600, 1.0)
    q.nz2[:, 3:6] *= 9.0
    s = qc.sigma_scale(q, q.epochs_s)
    np.testing.assert_allclose(np.median(s[:, 3:6]), 3.0, rtol=0.1)
    assert np.mean(s[:, 0:3] == 1.0) > 0.95 and np.mean(s[:, 6:9] == 1.0) > 0.95
    rows = np.linspace(0.0, 599.0, 2397)  # between the epochs: interpolated
    assert qc.sigma_scale(q, rows).shape == (rows.size, 9)
    assert np.all(qc.sigma_scale(None, rows) == 1.0)
