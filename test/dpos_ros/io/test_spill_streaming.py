"""read_session of a transfer_align_node spill: each topic's log read a block of
records at a time gives read_session's session of the same spill - the same series bit for bit, the
same warnings, metadata and end - with and without its late messages, with a last record cut
short by a crash, with bad messages (another frame, stamp 0, NaN, duplicates, out of order), and
reading one sub-IMU's log alone."""

from __future__ import annotations

from pathlib import Path

import pytest
from repo_paths import REPO
from same_session import same_session

from dpos_ros.contract import topics as T
from dpos_ros.io import bag, spill
from dpos_ros.io.session import MASTER_SOURCE_KEY, SessionError, read_session
from dpos_ros.io.session import _read_whole as read_whole  # the reference: every message in memory at once

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"
SUB_R, SUB_L = T.sub_imu("sub_r"), T.sub_imu("sub_l")


@pytest.fixture(scope="module")
def raw() -> dict:
    return bag.read_raw(SAMPLE)


def _write(d: Path, raw: dict, topics=None, custom: dict[str, str] | None = None, late_after_s: float | None = None,
           edit=None) -> Path:
    """A spill of the sample bag's ``topics`` (all by default) written as transfer_align_node writes
    it (the datum first, each topic's messages in their order); with ``late_after_s`` the sub-IMUs' messages
    after that many seconds go to ``late/``; ``edit(topic, blobs) -> blobs`` alters a topic's messages."""
    w = spill.SpillWriter(d, "sess", {"dpos.session_id": "sess", **(custom or {})})
    late = spill.SpillWriter(d / spill.LATE_DIR, "sess") if late_after_s is not None else None
    t_first = raw[T.MASTER_NAV][1][0]
    rows = []
    for topic, (mt, _times, blobs) in raw.items():
        if topics is not None and topic not in topics:
            continue
        blobs = [bytes(b) for b in blobs]
        if edit is not None:
            blobs = edit(topic, blobs)
        rows += [(0 if topic == T.DATUM else i + 1, topic, mt, int.from_bytes(b[4:8], "little", signed=True) * 10**9
                  + int.from_bytes(b[8:12], "little"), b) for i, b in enumerate(blobs)]
    rows.sort(key=lambda r: r[0] > 0)  # the datum first, each topic's messages in their order (each its own log)
    for _, topic, mt, t, b in rows:
        if late is not None and topic.startswith("/sub_imu/") and t - t_first > late_after_s * 1e9:
            late.write(topic, mt, t, b)
        else:
            w.write(topic, mt, t, b)
    w.close()
    if late is not None:
        late.close()
    return d


@pytest.mark.parametrize("batch_bytes", [20_000, 2**24])
def test_spill_read_in_blocks_is_read_session(tmp_path: Path, raw, batch_bytes: int) -> None:
    d = _write(tmp_path / "s", raw, custom={MASTER_SOURCE_KEY: "mechanized", "dpos.start_time_s": "1700000000.0"})
    a = read_whole(d)
    b = read_session(d, batch_bytes=batch_bytes)
    same_session(a, b)
    assert b.master_mechanized and b.custom[MASTER_SOURCE_KEY] == "mechanized" and set(b.sub_imus) == {"sub_r", "sub_l"}
    assert b.truth  # (the sample bag has truth)


@pytest.mark.parametrize("include_late", [True, False])
def test_late_messages_merged_or_left_out_as_read_session(tmp_path: Path, raw, include_late: bool) -> None:
    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R, SUB_L}, late_after_s=30.0)
    a = read_whole(d, include_late=include_late)
    b = read_session(d, batch_bytes=30_000, include_late=include_late)
    same_session(a, b)
    n_all = len(raw[SUB_R][1])
    assert (b.sub_imus["sub_r"].t_s.size == n_all) == include_late
    assert any("arrived after the session was closed" in w for w in b.warnings) == include_late


def test_one_sub_imu_log_alone(tmp_path: Path, raw) -> None:
    d = _write(tmp_path / "s", raw, late_after_s=40.0)
    keep = lambda t: t == SUB_L  # noqa: E731
    a = read_whole(d, include_late=False, keep=keep)
    b = read_session(d, keep=keep, batch_bytes=50_000, include_late=False)
    same_session(a, b)
    assert list(b.sub_imus) == ["sub_l"] and not b.truth


def test_last_record_cut_short_is_dropped_with_a_warning(tmp_path: Path, raw) -> None:
    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R}, late_after_s=40.0)
    topics, _, _ = spill.spill_meta(d)
    late_topics, _, _ = spill.spill_meta(d / spill.LATE_DIR)
    for f, cut in ((topics[SUB_R][1], 100), (late_topics[SUB_R][1], 5), (topics[T.MASTER_NAV][1], 13)):
        with f.open("r+b") as fh:  # a crash in the middle of a record
            fh.truncate(f.stat().st_size - cut)
    a = read_whole(d)
    b = read_session(d, batch_bytes=10_000)
    same_session(a, b)
    cut_notes = [w for w in b.warnings if "cut short" in w]
    assert len(cut_notes) == 3 and cut_notes[2].startswith(f"{spill.LATE_DIR}/{SUB_R}"), cut_notes
    assert b.sub_imus["sub_r"].t_s.size == len(raw[SUB_R][1]) - 2  # the two cut records only


@pytest.mark.parametrize("bad", [2**31, 8, 100_000])
def test_one_corrupt_record_size_costs_one_sample_and_is_counted(tmp_path: Path, raw, bad: int) -> None:
    """The sub-IMU log's record 500 gets a wrong size (2**31, 8 bytes more, 100 kB): that sample is
    lost alone (before: the rest of the topic, reported as cut short), said with the bytes skipped
    and counted in ``data_lost``, the same read whole and block by block."""
    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R})
    f = spill.spill_meta(d)[0][SUB_R][1]
    buf = bytearray(f.read_bytes())
    o = 0
    for _ in range(500):
        o += 12 + int.from_bytes(buf[o + 8 : o + 12], "little")
    size = int.from_bytes(buf[o + 8 : o + 12], "little")
    buf[o + 8 : o + 12] = (bad if bad != 8 else size + 8).to_bytes(4, "little")
    f.write_bytes(bytes(buf))
    a = read_whole(d)
    b = read_session(d, batch_bytes=10_000)
    same_session(a, b)
    assert b.sub_imus["sub_r"].t_s.size == len(raw[SUB_R][1]) - 1
    assert b.data_lost == {"spill_bytes_skipped": 12 + size}
    assert a.data_lost == b.data_lost  # (read whole too: status.json says it either way)
    assert any(f"{12 + size} corrupt byte(s) of {f.name} skipped" in w for w in b.warnings)
    assert not any("cut short" in w for w in b.warnings)


def _corrupt_size(f: Path, record: int) -> int:
    """Record ``record`` of the log ``f`` gets a size 2**31; the bytes it held with its head."""
    buf = bytearray(f.read_bytes())
    o = 0
    for _ in range(record):
        o += 12 + int.from_bytes(buf[o + 8 : o + 12], "little")
    size = int.from_bytes(buf[o + 8 : o + 12], "little")
    buf[o + 8 : o + 12] = (2**31).to_bytes(4, "little")
    f.write_bytes(bytes(buf))
    return 12 + size


@pytest.mark.parametrize("include_late", [True, False])
def test_corrupt_records_counted_in_data_lost_whole_and_streamed(tmp_path: Path, raw, include_late: bool) -> None:
    """A corrupt record size in a sub-IMU's log and one in its late log: both readings (whole, as the
    recordings the part-at-a-time reader does not read; and block by block) count the bytes skipped in
    ``data_lost`` (status.json), the late log's only when the late messages are read; an intact spill
    counts nothing."""
    from dpos_ros.products.write import status_doc

    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R}, late_after_s=30.0)
    assert read_whole(d).data_lost == {} and read_session(d).data_lost == {}
    n_main = _corrupt_size(spill.spill_meta(d)[0][SUB_R][1], 300)
    n_late = _corrupt_size(spill.spill_meta(d / spill.LATE_DIR)[0][SUB_R][1], 200)
    want = {"spill_bytes_skipped": n_main + (n_late if include_late else 0)}
    a = read_whole(d, include_late=include_late)
    b = read_session(d, batch_bytes=20_000, include_late=include_late)
    same_session(a, b)
    assert a.data_lost == want and b.data_lost == want
    assert status_doc(a, {}, "ta", {}, set())["data_lost"] == want
    skipped: dict[str, int] = {}
    spill.read_spill(d, include_late, skipped=skipped)
    assert skipped == ({SUB_R: n_main, f"{spill.LATE_DIR}/{SUB_R}": n_late} if include_late else {SUB_R: n_main})


def test_log_blocks_are_read_spills_records(tmp_path: Path, raw) -> None:
    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R})
    whole = spill.read_spill(d)[0]
    for topic, (_, f) in spill.spill_meta(d)[0].items():
        reader = spill.LogBlocks(f, 1000)  # smaller than a record of /master/nav: a block grows to hold one
        parts = list(reader)
        assert [t for p in parts for t in p[0].tolist()] == whole[topic][1]
        assert [bytes(m) for p in parts for m in p[1]] == [bytes(m) for m in whole[topic][2]]
        assert reader.count == len(whole[topic][1]) and reader.cut_short == 0
    with pytest.raises(ValueError, match="block_bytes"):
        spill.LogBlocks(d / "0.log", 0)


def _stray_frame(b: bytes) -> bytes:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu

    m = deserialize_message(b, Imu)
    m.header.frame_id = "stray_imu"
    return bytes(serialize_message(m))


def _edit(topic: str, blobs: list[bytes]) -> list[bytes]:
    """sub_r: strays spread over the log (another frame, stamp 0, covariance -1, NaN), a duplicate
    stamp with other numbers, an identical duplicate, two messages swapped."""
    if topic != SUB_R:
        return blobs
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu

    def change(b: bytes, f) -> bytes:
        m = deserialize_message(b, Imu)
        f(m)
        return bytes(serialize_message(m))

    out = list(blobs)
    for i in (100, 1500, 3000):
        out.insert(i, _stray_frame(out[i]))
        out.insert(i + 1, change(out[i + 1], lambda m: (setattr(m.header.stamp, "sec", 0), setattr(m.header.stamp, "nanosec", 0))))
    out.insert(2000, change(out[2000], lambda m: m.angular_velocity_covariance.__setitem__(0, -1.0)))
    out.insert(2500, change(out[2500], lambda m: setattr(m.linear_acceleration, "x", float("nan"))))
    out.insert(3500, change(out[3500], lambda m: setattr(m.linear_acceleration, "y", 1.0)))  # same stamp, other numbers
    out.insert(3600, out[3600])  # an identical message twice
    out[4000], out[4001] = out[4001], out[4000]
    return out


@pytest.mark.parametrize("late_after_s", [None, 20.0])
def test_bad_messages_same_checks_and_warnings(tmp_path: Path, raw, late_after_s) -> None:
    d = _write(tmp_path / "s", raw, topics={T.DATUM, T.MASTER_NAV, SUB_R}, late_after_s=late_after_s, edit=_edit)
    a = read_whole(d)
    b = read_session(d, batch_bytes=40_000)
    same_session(a, b)
    w = " | ".join(b.warnings)
    for text in ("3 message(s) with other frame names", "3 message(s) rejected (zero_stamp", "1 message(s) rejected (unavailable",
                 "NaN/inf removed", "3 duplicate stamp(s) (1 identical messages)"):
        assert text in w, (text, w)
    assert ("1 message(s) out of stamp order" in w) == (late_after_s is None)  # (read_spill sorts a topic with late messages)


def test_unusable_spills_are_session_errors(tmp_path: Path, raw) -> None:
    d = _write(tmp_path / "nodatum", raw, topics={T.MASTER_NAV, SUB_R})
    with pytest.raises(SessionError, match="no /dpos/datum"):
        read_session(d)
    d = _write(tmp_path / "nonav", raw, topics={T.DATUM, SUB_R})
    with pytest.raises(SessionError, match="no /master/nav"):
        read_session(d)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "spill.json").write_text('{"format": "other"}')
    with pytest.raises(SessionError, match="cannot read the spill"):
        read_session(tmp_path / "bad")
