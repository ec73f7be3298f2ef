"""The window-by-window simulator (dpos_core.sim.chunked): the same seed gives the same
streams whatever the windows, with the whole-session generator's per-run draws and statistics."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core.sim.chunked import ChunkedSession
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession


def _concat(windows, get) -> np.ndarray:
    return np.concatenate([get(w) for w in windows])


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("paper_wing")


def _streams(scenario, window_s: float, seed: int = 3, duration_s: float = 12.0) -> dict[str, np.ndarray]:
    ws = list(ChunkedSession(SimulatedSession(scenario, seed, duration_s)).windows(window_s))
    return {
        "master_imu_t": _concat(ws, lambda w: w.master_imu.t_s),
        "master_imu_f": _concat(ws, lambda w: w.master_imu.f_mps2),
        "master_imu_w": _concat(ws, lambda w: w.master_imu.omega_radps),
        "sub_t": _concat(ws, lambda w: w.sub_imus["imu01"].t_s),
        "sub_f": _concat(ws, lambda w: w.sub_imus["imu01"].f_mps2),
        "sub_w": _concat(ws, lambda w: w.sub_imus["imu11"].omega_radps),
        "nav_t": _concat(ws, lambda w: w.master_nav.t_s),
        "nav_llh": _concat(ws, lambda w: w.master_nav.llh),
        "nav_q": _concat(ws, lambda w: w.master_nav.q_nb),
        "gnss_t": _concat(ws, lambda w: w.gnss.t_s),
        "gnss_v": _concat(ws, lambda w: w.gnss.vel_n_mps),
        "truth_t": _concat(ws, lambda w: w.truth["antenna/ant01"].t_s),
        "truth_llh": _concat(ws, lambda w: w.truth["antenna/ant01"].llh),
    }


def test_same_streams_whatever_the_windows(scenario) -> None:
    a, b = _streams(scenario, 12.0), _streams(scenario, 2.35)
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_stamps_truth_and_statistics_as_the_whole_session(scenario) -> None:
    ss = SimulatedSession(scenario, 3, 12.0)
    c = _streams(scenario, 5.0)
    sub = ss.sub_imu("imu01")
    assert np.array_equal(c["sub_t"], sub.t_s)
    assert np.array_equal(c["nav_t"], ss.master_nav_reference().t_s)
    assert np.array_equal(c["gnss_t"], ss.gnss().t_s)
    tr = ss.truth("antenna/ant01")
    assert np.array_equal(c["truth_t"], tr.t_s)
    np.testing.assert_allclose(c["truth_llh"], tr.llh, rtol=0, atol=1e-12)
    # the same per-run draws and noise level, other white-noise samples
    ideal = ss.ideal_imu("sub_imu/imu01")
    e_chunked, e_whole = c["sub_f"] - ideal.f_mps2, sub.f_mps2 - ideal.f_mps2
    np.testing.assert_allclose(e_chunked.mean(axis=0), e_whole.mean(axis=0), atol=4 * e_whole.std() / np.sqrt(e_whole.shape[0]))
    np.testing.assert_allclose(e_chunked.std(axis=0), e_whole.std(axis=0), rtol=0.1)
    assert not np.array_equal(c["sub_f"], sub.f_mps2)


def test_seeds_differ(scenario) -> None:
    assert not np.array_equal(_streams(scenario, 6.0, seed=3)["sub_f"], _streams(scenario, 6.0, seed=4)["sub_f"])


def test_window_must_be_positive(scenario) -> None:
    with pytest.raises(ValueError):
        next(ChunkedSession(SimulatedSession(scenario, 1, 5.0)).windows(0.0))
