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


def test_a_disagreement_that_accumulates_over_a_span_is_covered_there() -> None:
    """The height swings +-1 m over 16 to 40 s (8 s period) that the vertical speed does not have
    (quad_mimu's path 1: 1 m within 2 s, 2 m within 6 s): a 2 s window sees at most about 1.4 m,
    the span 2 m, which a filter integrating the speed over the span meets.  The widened sigmas
    make the span's largest difference (between its extremes of h - int v_up dt) 2 sigmas, not
    the window's, and leave the epochs far from it alone."""
    t, h, v = _climb()
    on = (t >= 16.0) & (t <= 40.0)
    h = h + np.where(on, np.sin(2 * np.pi * (t - 16.0) / 8.0), 0.0)
    s = np.full(t.size, 0.1)
    c = vertical_consistency(t, h, v, s, s)
    assert 1.9 < c.span_disagreement_m < 2.1 and c.span_disagreement_m > c.max_disagreement_m + 0.4, (c.span_disagreement_m, c.max_disagreement_m)
    assert c.span_sigmas > c.max_sigmas
    dt = np.diff(t)
    D = h - np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    w = np.concatenate([[0.0], 0.5 * dt]) + np.concatenate([0.5 * dt, [0.0]])
    for a, b in c.spans_s:
        m = (t >= a) & (t <= b)
        p, q = sorted((np.flatnonzero(m)[np.argmax(D[m])], np.flatnonzero(m)[np.argmin(D[m])]))
        # the difference between the extremes within 2 of its widened sigma: both heights' and the speed's between
        sig = np.sqrt(c.sigma_h_m[p] ** 2 + c.sigma_h_m[q] ** 2 + np.sum((c.sigma_vu_mps[p:q + 1] * w[p:q + 1]) ** 2))
        assert abs(D[p] - D[q]) <= 2.0 * sig + 1e-9, (a, b, D[p] - D[q], sig)  # (the window's factor alone: 2.8 sigmas)
    assert not c.widened[(t < 12.0) | (t > 44.0)].any()


def test_epochs_near_repeated_failures_are_widened_by_their_neighbourhood_rms() -> None:
    """The height swings +-0.6 m over 10 to 30 s (6 s period) that the vertical speed does not
    have: the failing windows widen 8.8-32 s.  The solution's errors are correlated, so the windows
    that pass just after it are no evidence that its sigmas hold there: every epoch whose windows
    within VERTICAL_NEIGHBOURHOOD_S disagree by more than 1 sigma rms has both sigmas multiplied by
    at least that rms (33 s: x2.9, which no failing window covers), and epochs whose neighbourhood
    is consistent (beyond 10 s of the swing) keep their sigmas exactly (quad_mimu's path 1: x2.9-3.9
    at every epoch, its last 3 s included, which pass)."""
    from dpos_core.imports.navsol import VERTICAL_NEIGHBOURHOOD_S, VERTICAL_WINDOW_S

    t, h, v = _climb()
    on = (t >= 10.0) & (t <= 30.0)
    h = h + np.where(on, 0.6 * np.sin(2 * np.pi * (t - 10.0) / 6.0), 0.0)
    s = np.full(t.size, 0.1)
    c = vertical_consistency(t, h, v, s, s)
    assert c.rms_factor is not None and c.widened.any()
    # the factor is the rms of the windows' differences in sigmas within the neighbourhood (recomputed here)
    integ = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    k = int(np.searchsorted(t, 33.0))  # after the swing: no failing window holds this epoch
    i = np.flatnonzero((t >= t[k] - VERTICAL_NEIGHBOURHOOD_S - 1e-9) & (t <= t[k] + VERTICAL_NEIGHBOURHOOD_S + 1e-9)
                       & (t + VERTICAL_WINDOW_S <= t[-1] + 1e-9))
    j = np.searchsorted(t, t[i] + VERTICAL_WINDOW_S - 1e-9)
    z = ((h[j] - h[i]) - (integ[j] - integ[i])) / np.sqrt(0.02 + (j - i + 1) * (0.1 * 0.1) ** 2)
    assert not c.widened[k] and c.rms_factor[k] > 1.5
    np.testing.assert_allclose(c.rms_factor[k], np.sqrt(np.mean(z**2)), rtol=0.02)
    np.testing.assert_allclose(c.sigma_h_m[k], 0.1 * c.rms_factor[k])
    assert np.all(c.sigma_h_m >= 0.1 * c.rms_factor - 1e-12) and np.all(c.sigma_vu_mps >= 0.1 * c.rms_factor - 1e-12)
    far = (t < 10.0 - VERTICAL_NEIGHBOURHOOD_S - VERTICAL_WINDOW_S) | (t > 30.0 + VERTICAL_NEIGHBOURHOOD_S + 1.0)
    assert far.sum() > 100 and not c.widened[far].any()
    np.testing.assert_array_equal(c.sigma_h_m[far], s[far])
    np.testing.assert_array_equal(c.sigma_vu_mps[far], s[far])
