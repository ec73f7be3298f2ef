"""transfer_align_node's finalize with its rows spilled to files (parameter ``stream_above_s``),
in-process: the sample bag's first 25 s (paper_su_pair: two sub-IMUs) fed to the subscription
callbacks, the smoothers in threads, the antenna poses received through DDS by a subscriber in
this process.

A node whose rows are spilled (``stream_above_s`` 0; the poses published 2 s at a time) publishes
the same poses (topic for topic, message for message) and writes the same products (every file
byte for byte but the processing time, with and without the truth) as one whose rows stay in
memory.  A sub-IMU whose smoother fails costs that sub-IMU only.  Every wait is bounded; nothing sleeps.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
from collections import defaultdict
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile
from repo_paths import REPO
from ros_wait import spin_until  # test/support/ros_wait.py
from same_products import same_products  # test/support/same_products.py

from dpos_core.errors import NumericalFailure
from dpos_ros.contract import topics as T
from dpos_ros.contract.qos import NAV_QOS
from dpos_ros.io import bag
from dpos_ros.products import solve, write

pytestmark = pytest.mark.ros

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
SECONDS = 25.0
TOPICS = [T.DATUM, T.MASTER_NAV, T.sub_imu("sub_r"), T.sub_imu("sub_l")]
ANTENNAS = ("ant_r", "ant_l")
TRUTH = [T.TRUTH_MASTER, *(T.truth_antenna(a) for a in ANTENNAS)]


@pytest.fixture(scope="module")
def msgs() -> dict[str, tuple[str, list[bytes]]]:
    raw = bag.read_raw(BAG, TOPICS + TRUTH)
    t_first = raw[T.MASTER_NAV][1][0]
    return {topic: (mt, [bytes(d) for t, d in zip(t_log, data) if topic == T.DATUM or t - t_first <= SECONDS * 1e9])
            for topic, (mt, t_log, data) in raw.items()}


def _stamp(d: bytes) -> int:
    return int.from_bytes(d[4:8], "little", signed=True) * 1_000_000_000 + int.from_bytes(d[8:12], "little")


@pytest.fixture
def graph(ros_context, monkeypatch):
    """``(make, executor, received)``: ``make(out, **params)`` a transfer_align_node in this process
    (smoothers in threads), spun with a subscriber that keeps every /antenna/<name>/odom message."""
    import transfer_align_node.node as tan

    monkeypatch.setattr(tan, "_pool", lambda n: cf.ThreadPoolExecutor(max_workers=max(1, n)))
    monkeypatch.setattr(write, "BAG_BATCH_S", 2.0)  # 13 batches of poses in 25 s
    got: dict[str, list[bytes]] = defaultdict(list)
    sub = rclpy.create_node("antenna_listener", context=ros_context)
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=NAV_QOS.reliability, durability=NAV_QOS.durability)
    for a in ANTENNAS:
        sub.create_subscription(Odometry, T.antenna_odom(a), lambda raw, a=a: got[a].append(raw), keep_all, raw=True)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(sub)
    nodes = []

    def make(out: Path, **params: Any):
        over = {"method": "urtss", "aircraft_config": "paper_su_pair", "output_dir": str(out), "finalize_timeout_s": 2.0,
                "output_rate_hz": 10.0, "workers": 2} | params
        ta = tan.TransferAlignNode(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
        ta.cbs = {t: ta._make_cb(t, mt) for t, (mt, _) in {T.DATUM: (T.NAVSATFIX, 0), T.MASTER_NAV: (T.ODOMETRY, 0),
                                                            T.sub_imu("sub_r"): (T.IMU, 0), T.sub_imu("sub_l"): (T.IMU, 0),
                                                            **{t: (T.ODOMETRY, 0) for t in TRUTH}}.items()}
        ex.add_node(ta)
        nodes.append(ta)
        return ta

    yield make, ex, got
    for n in nodes:
        ex.remove_node(n)
        n.destroy_node()
    ex.remove_node(sub)
    sub.destroy_node()
    ex.shutdown(timeout_sec=5.0)


def _session(ta, ex, msgs, sid: str, truth: bool = False) -> None:
    """Feed the messages (``truth``: the truth topics too), finalize as session ``sid`` and spin
    until the finalize is done (bounded)."""
    for topic in TOPICS + (TRUTH if truth else []):
        for d in msgs[topic][1]:
            ta.cbs[topic](d)
    end = max(_stamp(d) for d in msgs[T.MASTER_NAV][1])
    assert ta._start_finalize(end, sid)
    spin_until(ex, lambda: not ta._finalize_thread.is_alive(), 240, lambda: f"the finalize ({ta._progress})")


def _rows(products: Path, a: str) -> int:
    return sum(1 for _ in (products / f"{a}.csv").open()) - 2


def test_spilled_rows_publish_and_write_what_rows_in_memory_do(graph, msgs, tmp_path: Path) -> None:
    make, ex, got = graph
    received: dict[str, dict[str, list[bytes]]] = {}
    for mode, limit in (("memory", 3600.0), ("stream", 0.0)):
        got.clear()
        ta = make(tmp_path / mode, stream_above_s=limit)
        _session(ta, ex, msgs, "s")
        products = tmp_path / mode / "s"
        assert (products / "status.json").is_file(), ta._progress
        spin_until(ex, lambda p=products: all(len(got[a]) >= _rows(p, a) for a in ANTENNAS), 30,
                   lambda: f"every pose: { {a: len(v) for a, v in got.items()} }")
        received[mode] = {a: list(got[a]) for a in ANTENNAS}
        assert not ta._errors and not any(p.name.startswith(".dpos_rows_") for p in (tmp_path / mode).iterdir())
    a, b = tmp_path / "stream" / "s", tmp_path / "memory" / "s"
    # the poses: every row published once, in stamp order, the same messages
    for ant in ANTENNAS:
        stamps = [_stamp(m) for m in received["stream"][ant]]
        assert len(stamps) == _rows(a, ant) == 251 and all(x < y for x, y in zip(stamps, stamps[1:])), ant
        assert [bytes(m) for m in received["stream"][ant]] == [bytes(m) for m in received["memory"][ant]], ant
    # the products
    files = same_products(a, b)
    assert {"ant_l.csv", "ant_r.csv", "antennas/antennas.mcap", "qc.md", "status.json"} <= set(files)
    assert json.loads((a / "status.json").read_text())["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}


def test_a_failed_sub_imu_costs_that_sub_imu_only(graph, msgs, tmp_path: Path, monkeypatch) -> None:
    make, ex, got = graph
    real = solve.align_to_store

    def align(task):
        if task.sub == "sub_l":
            raise NumericalFailure("injected: the covariance is not positive definite")
        return real(task)

    monkeypatch.setattr(solve, "align_to_store", align)
    ta = make(tmp_path / "out", stream_above_s=0.0)
    _session(ta, ex, msgs, "f")
    products = tmp_path / "out" / "f"
    st = json.loads((products / "status.json").read_text())
    assert st["antennas"]["ant_r"] == "estimated", st
    assert st["antennas"]["ant_l"].startswith("failed: NumericalFailure: injected"), st
    assert any(w.startswith("sub-IMU sub_l: the urtss smoother failed (NumericalFailure") for w in st["warnings"]), st["warnings"]
    assert set(ta._errors) == {"sub_l"} and not (products / "ant_l.csv").exists()
    spin_until(ex, lambda: len(got["ant_r"]) >= _rows(products, "ant_r"), 30, "ant_r's poses")
    assert len(got["ant_r"]) == _rows(products, "ant_r") and not got["ant_l"]


class _BrokenPool(cf.Executor):
    """A pool one of whose workers died: it refuses every task."""

    def submit(self, fn, /, *args, **kwargs):  # noqa: ANN001, ANN201
        raise BrokenProcessPool("a child process terminated abruptly")


def test_a_broken_pool_costs_the_sub_imus_tasks_only() -> None:
    """Once a worker has died (the pool broken), a sub-IMU's task still reports that sub-IMU as
    failed, and the session's other tasks (the wing fit's windows, the products' files) run in the
    node's process instead of failing the whole streamed finalize."""
    from transfer_align_node.node import _SubImuTasks

    tasks = _SubImuTasks(_BrokenPool(), "ups")
    r = tasks.submit(solve.align_to_store, SimpleNamespace(sub="sub_r")).result(timeout=5)
    assert "smoother failed" in r["rejected"] and "BrokenProcessPool" in r["rejected"]
    assert list(tasks.failed) == ["sub_r"] and isinstance(tasks.failed["sub_r"], cf.BrokenExecutor)
    assert tasks.submit(sum, [1, 2, 3]).result(timeout=5) == 6
    with pytest.raises(ZeroDivisionError):
        tasks.submit(divmod, 1, 0).result(timeout=5)


def test_spilled_rows_evaluate_against_the_truth_as_rows_in_memory(graph, msgs, tmp_path: Path, figures_on) -> None:
    """With the truth in the spill, the finalize evaluates it a part at a time (each truth log a
    block at a time, dpos_ros.products.evaluate): metrics.json, report.md and the error figures,
    the same with the rows in memory and spilled, and no warning that it did not evaluate."""
    make, ex, _ = graph
    for mode, limit in (("memory", 3600.0), ("stream", 0.0)):
        ta = make(tmp_path / mode, stream_above_s=limit)
        _session(ta, ex, msgs, "s", truth=True)
        products = tmp_path / mode / "s"
        assert (products / "status.json").is_file(), ta._progress
        assert (products / "report.md").is_file() and all((products / f"errors_{a}.png").is_file() for a in ANTENNAS), mode
        warnings = json.loads((products / "status.json").read_text())["warnings"]
        assert not any("not evaluated" in w for w in warnings), warnings
    files = same_products(tmp_path / "stream" / "s", tmp_path / "memory" / "s")
    assert "metrics.json" in files
    assert json.loads((tmp_path / "stream" / "s" / "metrics.json").read_text())["evaluation"]["path"] == "streaming"
