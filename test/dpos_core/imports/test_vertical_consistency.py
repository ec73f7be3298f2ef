"""An imported navigation solution checked against itself (dpos_core.imports.navsol.vertical_consistency):
its height against the integral of its vertical speed."""

from __future__ import annotations

import numpy as np

from dpos_core.imports.navsol import vertical_consistency


def _climb(n: int = 600, dt: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 60 s climb and descent at 10 Hz: height and vertical speed consistent, each rounded to 0.1
    (a flight log's resolution)."""
    t = np.arange(n) * dt
    v = 1.5 * np.sin(2 * np.pi * t / 20.0)
    h = 50.0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    return t, np.round(h, 1), np.round(v, 1)


def test_a_consistent_solution_is_left_alone() -> None:
    t, h, v = _climb()
    s = np.full(t.size, 0.1)
    c = vertical_consistency(t, h, v, s, s)
    assert not c.widened.any() and c.spans_s == [] and c.max_sigmas < 3.0, c.max_sigmas
    np.testing.assert_array_equal(c.sigma_h_m, s)
    np.testing.assert_array_equal(c.sigma_vu_mps, s)


def test_a_height_that_leaves_the_vertical_speed_widens_both_there() -> None:
    """The height rises 1 m over 20 to 22 s that the vertical speed does not have (the reference of
    quad_mimu's path 1: up to 1 m in 2 s): both sigmas are widened around it - the difference then
    2 sigmas - and nowhere far from it."""
    t, h, v = _climb()
    h = h + np.clip((t - 20.0) / 2.0, 0.0, 1.0)
    s = np.full(t.size, 0.1)
    c = vertical_consistency(t, h, v, s, s)
    assert c.widened.any() and 0.9 < c.max_disagreement_m < 1.1, c.max_disagreement_m
    assert c.max_sigmas > 4.0
    assert all(16.0 < a and b < 26.0 for a, b in c.spans_s), c.spans_s
    assert not c.widened[(t < 17.0) | (t > 25.0)].any()
    k = int(np.argmax(c.sigma_h_m))
    assert 18.0 <= t[k] <= 24.0 and c.sigma_h_m[k] > 0.25
    np.testing.assert_allclose(c.sigma_vu_mps / 0.1, c.sigma_h_m / 0.1)  # both by the same factor
    assert np.all(c.sigma_h_m >= s)
