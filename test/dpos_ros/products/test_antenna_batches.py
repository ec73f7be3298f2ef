"""The products' antenna bag is written a time window at a time: the batches hold the
messages of the whole-session streams, in the same order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from repo_paths import REPO

from dpos_core.config import load_aircraft
from dpos_core.ta.pipeline import TASettings
from dpos_ros.io import bag
from dpos_ros.io.session import read_session
from dpos_ros.io.streams import merged_order
from dpos_ros.products.solve import solve
from dpos_ros.products.write import antenna_stream, antenna_stream_batches

BAG = REPO / "bags" / "paper_su_pair_seed1_45s"


def test_batches_hold_the_whole_streams_messages(tmp_path: Path) -> None:
    sess = read_session(BAG)
    ants, _ = solve(sess, load_aircraft("paper_su_pair"), TASettings(method="ukf", initial_attitude_error_deg=1.0))
    est = {name: a for name, a in ants.items() if a.rows is not None}
    whole = [antenna_stream(sess, name, a.block()) for name, a in est.items()]
    batches = list(antenna_stream_batches(sess, est, batch_s=7.3))
    assert len(batches) > 3 and all(len(b) == len(whole) for b in batches)
    for i, st in enumerate(whole):
        parts = [b[i] for b in batches]
        assert {p.topic for p in parts} == {st.topic}
        assert np.array_equal(np.concatenate([p.t_ns for p in parts]), st.t_ns)
        assert np.array_equal(np.concatenate([p.rows for p in parts]), st.rows)
    # written batch by batch, the bag reads as the streams in their merged order
    bag.write_stream_batches(tmp_path / "a", iter(batches))
    raw = bag.read_raw(tmp_path / "a")
    t, si, mi = merged_order(whole)
    for k, st in enumerate(whole):
        got = raw[st.topic]
        assert got[1] == st.t_ns.tolist()
        assert [bytes(x) for x in got[2]] == [st.message(j) for j in mi[si == k]]
