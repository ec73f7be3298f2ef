"""Bags written batch by batch: ``dpos-sim --window`` simulates and writes a session
window by window; the bag reads as one written at once, and the window size does not change a
message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli import sim as sim_cli
from dpos_ros.devices.sim_streams import chunked_session_streams, session_streams
from dpos_ros.io import bag
from dpos_ros.io.session import read_session
from dpos_ros.io.streams import TopicStream


def _raw(path: Path) -> dict:
    return {t: (mt, list(times), [bytes(b) for b in blobs]) for t, (mt, times, blobs) in bag.read_raw(path).items()}


def test_window_size_does_not_change_a_message(tmp_path: Path) -> None:
    for w in ("4", "2.5"):
        assert sim_cli.main(["--scenario", "paper_su", "--aircraft", "paper_su_pair", "--duration", "8", "--window", w,
                             "--out", str(tmp_path / w)]) == 0
    a, b = _raw(tmp_path / "4"), _raw(tmp_path / "2.5")
    assert a.keys() == b.keys() and a == b
    # the same bag through rosbags (the summary and indexes of a batched file are valid)
    slow = bag.read_raw_rosbags(tmp_path / "2.5")
    assert {t: (mt, list(times), [bytes(x) for x in blobs]) for t, (mt, times, blobs) in slow.items()} == b


def test_batches_give_the_topics_and_stamps_of_the_whole_session(tmp_path: Path) -> None:
    ss = SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 1, 6.0)
    whole = session_streams(ss)
    n, counts = bag.write_stream_batches(tmp_path / "b", chunked_session_streams(ss, 2.0), custom_data={"dpos.x": "1"})
    assert [(t, m) for t, m, _ in counts] == [(s.topic, s.msgtype) for s in whole]
    assert [c for _, _, c in counts] == [len(s) for s in whole] and n == sum(len(s) for s in whole)
    raw = bag.read_raw(tmp_path / "b")
    for s in whole:
        assert np.array_equal(np.array(raw[s.topic][1], dtype=np.int64), s.t_ns), s.topic
    assert bag.custom_data(tmp_path / "b")["dpos.x"] == "1"


def test_windowed_bag_is_a_session(tmp_path: Path) -> None:
    assert sim_cli.main(["--scenario", "paper_su", "--aircraft", "paper_su_pair", "--duration", "5", "--window", "2",
                         "--out", str(tmp_path / "s")]) == 0
    sess = read_session(tmp_path / "s")
    assert set(sess.sub_imus) == {s.name for s in load_scenario("paper_su", aircraft="paper_su_pair").aircraft.sub_imus}
    assert sess.end_s is not None and not sess.warnings


def test_batches_must_keep_their_topics(tmp_path: Path) -> None:
    t = np.array([1], dtype=np.int64)
    one = [TopicStream("/a", "std_msgs/msg/Header", t, rows=np.zeros((1, 16), dtype=np.uint8))]
    other = [TopicStream("/b", "std_msgs/msg/Header", t + 1, rows=np.zeros((1, 16), dtype=np.uint8))]
    with pytest.raises(ValueError):
        bag.write_stream_batches(tmp_path / "x", iter([one, other]))
