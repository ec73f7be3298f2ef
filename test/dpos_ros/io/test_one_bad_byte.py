"""One bad byte costs one record, not the rest: a corrupt MCAP chunk is skipped and said (the
rest read), an MCAP cut mid-chunk is recovered (with or without its metadata.yaml), a header
declaring a huge chunk allocates nothing of that size, and a spill log with one corrupt record
size resynchronizes on the next valid record."""

from __future__ import annotations

import shutil
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Channel, ChunkIndex
from mcap.stream_reader import StreamReader
from repo_paths import REPO

from dpos_ros.io import _mcap, bag, spill
from dpos_ros.io.play import open_bag
from dpos_ros.io.session import read_session
from dpos_ros.io.streams import TopicStream

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


@pytest.fixture(scope="module")
def src(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sample bag rewritten by dpos (its chunks carry their CRC-32, as dpos-record's and dpos-sim's)."""
    streams = [TopicStream(topic, mt, np.array(times, dtype=np.int64), blobs=tuple(blobs))
               for topic, (mt, times, blobs) in bag.read_raw(SAMPLE).items()]
    out = tmp_path_factory.mktemp("src") / "b"
    bag.write_streams(out, streams, custom_data={"dpos.session_id": "s1"})
    return out


@pytest.fixture(scope="module")
def full(src: Path) -> dict[str, bag.RawTopic]:
    return bag.read_raw(src)


@pytest.fixture(scope="module")
def index(src: Path) -> list[ChunkIndex]:
    """The chunk indexes (in file order)."""
    with (src / "b.mcap").open("rb") as f:
        out = [r for r in StreamReader(f, skip_magic=False).records if isinstance(r, ChunkIndex)]
    assert len(out) > 3
    return sorted(out, key=lambda c: c.chunk_start_offset)


def _copy(src: Path, tmp_path: Path, name: str, metadata: bool = True) -> tuple[Path, Path]:
    b = tmp_path / name
    shutil.copytree(src, b)
    if not metadata:
        (b / "metadata.yaml").unlink()
    return b, b / "b.mcap"


def _messages_of(chunk: ChunkIndex, mcap: Path) -> dict[str, int]:
    """Messages per topic in one chunk (from its message indexes)."""
    topics = {t: v.topic for t, v in _channels(mcap).items()}
    out: dict[str, int] = {}
    with mcap.open("rb") as f:
        for off in chunk.message_index_offsets.values():
            f.seek(off)
            head = f.read(15)
            _, _, c, m = struct.unpack_from("<BQHI", head)
            out[topics[c]] = m // 16
    return out


def _channels(mcap: Path) -> dict:
    with mcap.open("rb") as f:
        return {r.id: r for r in StreamReader(f, skip_magic=False).records if isinstance(r, Channel)}


def _without(full: dict[str, bag.RawTopic], lost: dict[str, int]) -> dict[str, int]:
    """Messages per topic expected after losing ``lost`` (per topic)."""
    return {t: len(v.times) - lost.get(t, 0) for t, v in full.items()}


def _count(raw: dict[str, bag.RawTopic]) -> dict[str, int]:
    return {t: len(v.times) for t, v in raw.items()}


def test_a_flipped_byte_costs_its_chunk_only(src: Path, tmp_path: Path, full, index) -> None:
    """A byte flipped inside the second chunk: that chunk is skipped and said (its byte, log
    time range, the messages lost per topic); every other message is read, by dpos-process's
    reader and by dpos-play's (a recovery without the bad chunk)."""
    b, mcap = _copy(src, tmp_path, "flip")
    ch = index[1]
    lost = _messages_of(ch, mcap)
    raw = bytearray(mcap.read_bytes())
    raw[ch.chunk_start_offset + ch.chunk_length // 2] ^= 0x10
    mcap.write_bytes(bytes(raw))
    notes: list[str] = []
    got = bag.read_raw(b, notes=notes)
    assert _count(got) == _without(full, lost)
    for topic, v in got.items():  # the others byte for byte
        keep = [(t, m) for t, m in zip(full[topic].times, full[topic].blobs)
                if not ch.message_start_time <= t <= ch.message_end_time]
        assert [(t, m) for t, m in zip(v.times, v.blobs) if not ch.message_start_time <= t <= ch.message_end_time] == keep
    n = sum(lost.values())
    assert len(notes) == 1 and f"the chunk at byte {ch.chunk_start_offset}" in notes[0]
    assert f"lost {n} message(s)" in notes[0] and "/master/nav" in notes[0] and "the other chunks are read" in notes[0]
    assert f"{ch.message_start_time * 1e-9:.3f}" in notes[0]
    sess = read_session(b)  # dpos-process
    assert any(f"the chunk at byte {ch.chunk_start_offset}" in w for w in sess.warnings)
    said: list[str] = []
    reader = open_bag(b, said.append)  # dpos-play: rosbags checks no CRC, so a recovery is read
    try:
        assert sum(1 for _ in reader.messages()) == sum(len(v.times) for v in full.values()) - n
    finally:
        reader.close()
    assert said and "is damaged" in said[0] and f"{n} message(s) lost in skipped chunks" in said[0]


@pytest.mark.parametrize("metadata", [True, False])
def test_a_file_cut_mid_chunk_is_recovered(src: Path, tmp_path: Path, full, index, metadata: bool) -> None:
    """A crash in the middle of the 4th chunk, with or without metadata.yaml: the intact chunks
    are read, the note says the file ends in an incomplete record and what is lost."""
    b, mcap = _copy(src, tmp_path, f"cut{int(metadata)}", metadata)
    ch = index[3]
    with mcap.open("r+b") as f:
        f.truncate(ch.chunk_start_offset + ch.chunk_length // 2)
    notes: list[str] = []
    got = bag.read_raw(b, notes=notes)
    before = {t: sum(1 for x in v.times if x < ch.message_start_time) for t, v in full.items()}
    for topic, v in got.items():  # what the first 3 chunks hold (at least), each topic's first messages byte for byte
        assert len(v.times) >= before[topic] and v.times == full[topic].times[: len(v.times)]
        assert list(v.blobs) == list(full[topic].blobs[: len(v.times)])
    assert sum(before.values()) > 0 and len(notes) == 1
    assert f"incomplete record at byte {ch.chunk_start_offset}" in notes[0] and "is lost" in notes[0]
    assert ("no footer" in notes[0]) == metadata
    if metadata:  # the recovery keeps the recording's own metadata (its session id)
        assert bag.custom_data(b.with_name(b.name + bag.RECOVERED_SUFFIX)).items() >= bag.custom_data(src).items()
    sess = read_session(b)  # dpos-process
    assert sess.master.t_s.size > 0 and any("recovered" in w for w in sess.warnings)


def test_a_header_declaring_8_gib_allocates_nothing_of_it(src: Path, tmp_path: Path, full, index) -> None:
    """The first chunk's index and record declare 8 GiB: the chunk is refused before any large
    allocation (peak of Python's allocations and the process' RSS growth well under 100s of MB),
    the other chunks read."""
    big = 8 * 2**30
    # (1) the summary's chunk index declares 8 GiB of records: skipped, said
    b, mcap = _copy(src, tmp_path, "big_index")
    raw = bytearray(mcap.read_bytes())
    ch = index[2]
    usize = struct.pack("<Q", ch.uncompressed_size)
    at = raw.rfind(struct.pack("<Q", ch.chunk_start_offset) + struct.pack("<Q", ch.chunk_length))
    k = raw.index(b"zstd" + struct.pack("<Q", ch.compressed_size) + usize, at)
    raw[k + 12 : k + 20] = struct.pack("<Q", big)
    rec = ch.chunk_start_offset + 9 + 16  # and the chunk record's own uncompressed size
    assert raw[rec : rec + 8] == usize
    raw[rec : rec + 8] = struct.pack("<Q", big)
    mcap.write_bytes(bytes(raw))
    lost = sum(_messages_of(ch, mcap).values())
    tracemalloc.start()
    notes: list[str] = []
    got = bag.read_raw(b, notes=notes)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 200 * 2**20, peak
    assert sum(_count(got).values()) == sum(_count(full).values()) - lost
    assert len(notes) == 1 and f"declares {big} bytes" in notes[0] and "nothing allocated" in notes[0]
    # (2) no summary (a recording without metadata), the first chunk record's length is 8 GiB: its bytes
    # are skipped up to the next chunk, every later chunk read
    b, mcap = _copy(src, tmp_path, "big_record", metadata=False)
    raw = bytearray(mcap.read_bytes())
    first = index[0]
    raw[first.chunk_start_offset + 1 : first.chunk_start_offset + 9] = struct.pack("<Q", big)
    mcap.write_bytes(bytes(raw))
    tracemalloc.start()
    notes = []
    got = bag.read_raw(b, notes=notes)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 300 * 2**20, peak
    later = {t: sum(1 for x in v.times if x > first.message_end_time) for t, v in full.items()}
    assert all(sum(1 for x in got[t].times if x > first.message_end_time) == n for t, n in later.items() if n)
    assert "past the end of the file" in notes[0] and f"bytes skipped at byte {first.chunk_start_offset}" in notes[0]


def _spill(tmp_path: Path, n: int = 2000) -> tuple[Path, list[tuple[int, bytes]]]:
    w = spill.SpillWriter(tmp_path / "sp", "s1")
    rng = np.random.default_rng(1)
    cdr = b"\x00\x01\x00\x00"  # (a serialized message's encapsulation header, as every spilled message has)
    recs = [(1_700_000_000_000_000_000 + k * 5_000_000, cdr + rng.integers(0, 256, 296, dtype=np.uint8).tobytes()) for k in range(n)]
    for t, d in recs:
        w.write("/sub_imu/a/imu", "sensor_msgs/msg/Imu", t, d)
    w.close()
    return tmp_path / "sp", recs


@pytest.mark.parametrize("bad_size", [0xFFFFFFFF, 301, 100_000, 0])
def test_one_corrupt_record_size_in_a_spill_costs_one_record(tmp_path: Path, bad_size: int) -> None:
    """Record 40 of 2000 gets a wrong size (huge, one byte more, past the end, zero): that record is
    skipped and said with the bytes skipped, the other 1999 are read (before: 40 kept, the rest
    reported as "cut short (crash)"), whole and block by block."""
    d, recs = _spill(tmp_path)
    log = d / "0.log"
    raw = bytearray(log.read_bytes())
    step = 12 + 300
    raw[40 * step + 8 : 40 * step + 12] = struct.pack("<I", bad_size)
    log.write_bytes(bytes(raw))
    got, _, _, warns = spill.read_spill(d)
    want = recs[:40] + recs[41:]
    t = got["/sub_imu/a/imu"].times
    assert t == [r[0] for r in want] and list(got["/sub_imu/a/imu"].blobs) == [r[1] for r in want]
    assert len(warns) == 1 and f"{step} corrupt byte(s) of 0.log skipped ({step} at byte {40 * step}" in warns[0]
    assert "cut short" not in warns[0]
    blocks = spill.LogBlocks(log, block_bytes=4096)
    t_b = np.concatenate([b[0] for b in blocks]).tolist()
    assert t_b == t and blocks.skipped == [(40 * step, step)] and blocks.cut_short == 0


def test_a_spill_cut_short_is_still_cut_short(tmp_path: Path) -> None:
    """A crash while writing the last record is not mistaken for a corrupt size: dropped, said as before."""
    d, recs = _spill(tmp_path, 50)
    log = d / "0.log"
    with log.open("r+b") as f:
        f.truncate(log.stat().st_size - 100)
    got, _, _, warns = spill.read_spill(d)
    assert got["/sub_imu/a/imu"].times == [r[0] for r in recs[:49]]
    assert len(warns) == 1 and "cut short (212 bytes" in warns[0]


def test_damage_is_told_from_the_footer_and_summary(src: Path, tmp_path: Path) -> None:
    assert _mcap.damage(src / "b.mcap") is None
    b, mcap = _copy(src, tmp_path, "d")
    with mcap.open("r+b") as f:
        f.truncate(mcap.stat().st_size - 10)
    assert "no footer" in (_mcap.damage(mcap) or "")


def test_status_counts_what_was_lost(src: Path, tmp_path: Path, index) -> None:
    """dpos-process's session counts the messages of a skipped chunk once (status.json ``data_lost``),
    however often the chunk is read, and so does a recovery; a spill's skipped bytes too."""
    from dpos_ros.products.write import status_doc

    b, mcap = _copy(src, tmp_path, "flip")
    ch = index[2]
    n = sum(_messages_of(ch, mcap).values())
    raw = bytearray(mcap.read_bytes())
    raw[ch.chunk_start_offset + ch.chunk_length // 2] ^= 0x10
    mcap.write_bytes(bytes(raw))
    sess = read_session(b)
    assert sess.data_lost == {"messages": n}
    assert sum(f"the chunk at byte {ch.chunk_start_offset}" in w for w in sess.warnings) == 1
    assert status_doc(sess, {}, "ta", {}, set())["data_lost"] == {"messages": n}
    (b / "metadata.yaml").unlink()  # the same without its metadata: recovered, the count kept
    assert read_session(b).data_lost == {"messages": n}
    assert read_session(src).data_lost == {}
