"""read_session_streaming (issue #17): the recording decoded a part at a time gives the series of
read_session, bit for bit; one sub-IMU's topic can be read alone."""

from __future__ import annotations

import pytest
from repo_paths import REPO
from same_session import same_series, same_session

from dpos_ros.io import _mcap, bag
from dpos_ros.io.session import read_session, read_session_streaming

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


@pytest.mark.parametrize("batch_bytes", [150_000, 2**26])
def test_streaming_reader_gives_read_sessions_series(batch_bytes) -> None:
    same_session(read_session(SAMPLE), read_session_streaming(SAMPLE, batch_bytes=batch_bytes))


def test_one_sub_imu_alone() -> None:
    name = sorted(read_session(SAMPLE).sub_imus)[0]
    s = read_session_streaming(SAMPLE, keep=lambda t: t == f"/sub_imu/{name}/imu", batch_bytes=100_000)
    assert list(s.sub_imus) == [name] and not s.truth
    same_series(s.sub_imus[name], read_session(SAMPLE).sub_imus[name])


def test_read_batches_hold_read_s_messages() -> None:
    file = bag._single_mcap(SAMPLE)
    assert file is not None
    whole = _mcap.read(file, None)
    parts = list(_mcap.read_batches(file, None, batch_bytes=100_000))
    assert whole is not None and len(parts) > 2
    for topic, (_mt, times, blobs) in whole.items():
        assert [t for p in parts for t in p[topic][1]] == times
        assert [bytes(m) for p in parts for m in p[topic][2]] == [bytes(m) for m in blobs]
