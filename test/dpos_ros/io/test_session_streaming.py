"""read_session: the recording decoded a part at a time gives the series of
read_session, bit for bit; one sub-IMU's topic can be read alone."""

from __future__ import annotations

import numpy as np
import pytest
from repo_paths import REPO
from same_session import same_series, same_session

from dpos_ros.io import _mcap, bag
from dpos_ros.io.session import _read_whole as read_whole  # the reference: every message in memory at once
from dpos_ros.io.session import read_session

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


@pytest.mark.parametrize("batch_bytes", [150_000, 2**26])
def test_streaming_reader_gives_read_sessions_series(batch_bytes) -> None:
    same_session(read_whole(SAMPLE), read_session(SAMPLE, batch_bytes=batch_bytes))


def test_one_sub_imu_alone() -> None:
    name = sorted(read_whole(SAMPLE).sub_imus)[0]
    s = read_session(SAMPLE, keep=lambda t: t == f"/sub_imu/{name}/imu", batch_bytes=100_000)
    assert list(s.sub_imus) == [name] and not s.truth
    same_series(s.sub_imus[name], read_whole(SAMPLE).sub_imus[name])


def test_read_batches_hold_read_s_messages() -> None:
    file = bag._single_mcap(SAMPLE)
    assert file is not None
    whole = _mcap.read(file, None)
    parts = list(_mcap.read_batches(file, None, batch_bytes=100_000))
    assert whole is not None and len(parts) > 2
    for topic, (_mt, times, blobs) in whole.items():
        assert [t for p in parts for t in p[topic][1]] == times
        assert [bytes(m) for p in parts for m in p[topic][2]] == [bytes(m) for m in blobs]


@pytest.mark.parametrize("counts", [{}, "small"])
def test_series_grow_beyond_the_metadatas_message_counts(monkeypatch, counts) -> None:
    """The reader fills arrays of the metadata's message count per topic; without one (or with too
    small a count) they grow: the same series."""
    from dpos_ros.io import session

    real = session.message_counts(SAMPLE)
    assert real and all(v > 0 for v in real.values())
    monkeypatch.setattr(session, "message_counts", lambda p: {} if counts == {} else {k: v // 7 for k, v in real.items()})
    same_session(read_whole(SAMPLE), read_session(SAMPLE, batch_bytes=150_000))


def test_clean_groups_is_clean_of_the_columns_side_by_side() -> None:
    from dpos_ros.io.session import _clean, _clean_groups

    rng = np.random.default_rng(1)
    t = np.array([0, 10, 20, 20, 15, 30, 40, 40, 50, 60, 200], dtype=np.int64)  # out of order, duplicates, a gap
    v = rng.normal(size=(t.size, 5))
    v[7] = v[6]  # an identical duplicate
    v[5, 3] = np.nan  # a NaN row
    w1: list[str] = []
    w2: list[str] = []
    ta, va = _clean("/x", t, v, w1)
    tb, gb = _clean_groups("/x", t, [v[:, :2], v[:, 2:4], v[:, 4:]], w2)
    assert np.array_equal(ta, tb) and np.array_equal(va, np.hstack(gb)) and w1 == w2
    assert len(w1) == 4 and ta.size == t.size - 3  # sorted; 2 duplicates and a NaN row removed; a gap
