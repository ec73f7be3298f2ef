"""solve() aligns the sub-IMUs in worker processes (``pool``, dpos-process --workers) with the
same results, warnings and error handling as one after the other."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dpos_core.config import config_text
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_core.ta.pipeline import TASettings
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io.session import RecordedSession, session_from_streams
from dpos_ros.products.antenna import AntennaSolution
from dpos_ros.products.solve import solve
from dpos_ros.runtime.pool import process_pool

AIRCRAFT = "paper_su_pair"


@pytest.fixture(scope="module")
def session() -> tuple[RecordedSession, object]:
    """20 s of paper_su with both wings (two sub-IMUs), in memory."""
    scenario = load_scenario("paper_su", aircraft=AIRCRAFT)
    ss = SimulatedSession(scenario, 2, 20.0)
    sess = session_from_streams(session_streams(ss), session_custom_data(ss, config_text("aircraft", AIRCRAFT)), "paper_su_seed2")
    return sess, scenario.aircraft


def _solve(sess: RecordedSession, aircraft, workers: int, method: str = "urtss") -> tuple[dict[str, AntennaSolution], list[str]]:
    s = replace(sess, warnings=list(sess.warnings))
    pool = process_pool(workers) if workers > 1 else None
    try:
        ants, _ = solve(s, aircraft, TASettings(method=method, particles=10, seed=3, initial_attitude_error_deg=1.0), pool=pool)
    finally:
        if pool is not None:
            pool.shutdown()
    return ants, s.warnings


def _same(a: dict[str, AntennaSolution], b: dict[str, AntennaSolution]) -> None:
    assert list(a) == list(b)
    for name in a:
        x, y = a[name], b[name]
        assert x.status == y.status, name
        if x.rows is None:
            assert y.rows is None, name
            continue
        assert y.rows is not None and x.rows.n == y.rows.n > 0
        for k in x.rows.columns:
            assert np.array_equal(x.rows.read(k), y.rows.read(k)), (name, k)
        assert x.chol_jitter_repairs == y.chol_jitter_repairs


@pytest.mark.parametrize("method", ["urtss", "ups"])
def test_two_workers_give_the_serial_results(session, method: str) -> None:
    sess, aircraft = session
    serial, w1 = _solve(sess, aircraft, 1, method)
    parallel, w2 = _solve(sess, aircraft, 2, method)
    assert {a.status for a in serial.values()} == {"estimated"}
    _same(serial, parallel)
    assert w1 == w2


def test_a_rejected_sub_imu_in_a_worker_leaves_the_other_estimated(session) -> None:
    sess, aircraft = session
    broken = replace(sess, sub_imus={**sess.sub_imus, "sub_r": sess.sub_imus["sub_r"].select(slice(0, 3))})
    serial, w1 = _solve(broken, aircraft, 1)
    parallel, w2 = _solve(broken, aircraft, 2)
    _same(serial, parallel)
    assert parallel["ant_l"].status == "estimated"
    assert parallel["ant_r"].status.startswith("not estimated: sub-IMU sub_r: "), parallel["ant_r"].status
    assert w1 == w2 and any(w.startswith("sub-IMU sub_r: ") and "not estimated" in w for w in w2), w2


def test_a_warm_pool_gives_the_serial_results_and_stays_up_for_the_next_session(session) -> None:
    """The pool of transfer_align_node / dpos-process (runtime.pool.warm_pool): its workers ran the
    warm-up (dpos_core.ta.warmup) before the session; solve() uses it and leaves it running."""
    import concurrent.futures as cf
    from functools import partial

    from dpos_core.ta.warmup import warm_up
    from dpos_ros.runtime.pool import warm_pool

    sess, aircraft = session
    serial, w1 = _solve(sess, aircraft, 1)
    pool, warming = warm_pool(2, partial(warm_up, "urtss"))
    try:
        done, _ = cf.wait(warming, timeout=120)
        assert len(done) == 2 and all(f.result()["result"] > 0.0 for f in done)  # both warm-ups ran without error
        for _ in range(2):  # two sessions on the same pool
            s = replace(sess, warnings=list(sess.warnings))
            ants, _ = solve(s, aircraft, TASettings(method="urtss", particles=10, seed=3, initial_attitude_error_deg=1.0), pool=pool)
            _same(serial, ants)
            assert s.warnings == w1
    finally:
        pool.shutdown()
