"""The fast MCAP path of dpos_ros.io.bag (issues #12 / #17): the writer lays out the file as
rosbags' writer does and the reader returns what rosbags' AnyReader returns, message by message
and in the same order (out-of-order and duplicate log times across chunks included); a corrupt
chunk is an error naming it; bags the fast path does not read go through rosbags; the spill reader
gives the same messages record by record; :class:`Messages` behaves as a list of bytes."""

from __future__ import annotations

import re
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import zstandard
from mcap.records import Chunk, ChunkIndex, Footer, Header, MessageIndex, MetadataIndex, SummaryOffset
from mcap.stream_reader import StreamReader
from repo_paths import REPO
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from dpos_ros.contract import cdr
from dpos_ros.io import bag, spill
from dpos_ros.io.messages import Messages, RawTopic
from dpos_ros.io.session import SessionError, read_session, session_from_raw
from dpos_ros.io.streams import TopicStream

SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


@pytest.fixture(scope="module")
def streams() -> list[TopicStream]:
    """The sample bag's topics as the products write them: the high-rate ones as rows, the others as blobs."""
    out = []
    for topic, (mt, times, blobs) in bag.read_raw_rosbags(SAMPLE).items():
        sizes = {len(b) for b in blobs}
        t = np.array(times, dtype=np.int64)
        if len(sizes) == 1 and len(blobs) > 1000:
            out.append(TopicStream(topic, mt, t, rows=bag.rows(blobs)))
        else:
            out.append(TopicStream(topic, mt, t, blobs=tuple(blobs)))
    assert any(s.blobs is not None for s in out) and any(s.rows is not None for s in out)
    return out


@pytest.fixture(scope="module")
def written(streams: list[TopicStream], tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The streams written by the fast writer and by rosbags' Writer (bags of the same name)."""
    d = tmp_path_factory.mktemp("w")
    custom = {"dpos.session_id": "s1", "dpos.note": "a: b\nc"}
    assert bag.write_streams(d / "fast" / "b", streams, custom_data=custom) == sum(len(s) for s in streams)
    bag.write_streams_rosbags(d / "ref" / "b", streams, custom_data=custom)
    return d / "fast" / "b", d / "ref" / "b"


def _layout(mcap: Path) -> list[object]:
    """The file's records with what does not depend on the zstd build: chunks decompressed,
    offsets that follow compressed sizes left out."""
    out: list[object] = []
    with mcap.open("rb") as f:
        for r in StreamReader(f, skip_magic=False, emit_chunks=True).records:
            if isinstance(r, Chunk):  # (dpos writes the records' CRC-32, rosbags 0: checked in the test below)
                out.append(("chunk", r.message_start_time, r.message_end_time, r.uncompressed_size,
                            r.compression, zstandard.ZstdDecompressor().decompress(r.data, max_output_size=r.uncompressed_size)))
            elif isinstance(r, ChunkIndex):
                out.append(("chunk index", r.message_start_time, r.message_end_time, list(r.message_index_offsets),
                            r.compression, r.uncompressed_size))
            elif isinstance(r, SummaryOffset | Footer):
                out.append(type(r).__name__)
            elif isinstance(r, MessageIndex):
                out.append(("message index", r.channel_id, r.records))
            elif isinstance(r, MetadataIndex):  # (its offset follows the compressed sizes)
                out.append(("metadata index", r.length - len(_distro(mcap.parent)), r.name))
            elif isinstance(r, Header):  # the writer's name is its own
                out.append(("header", r.profile))
            elif hasattr(r, "metadata") and isinstance(r.metadata, dict) and "serialized_metadata" in r.metadata:
                out.append(("rosbag2 metadata", r.metadata["serialized_metadata"].replace(f"ros_distro: {_distro(mcap.parent)}", "ros_distro: X")))
            else:
                out.append(r)
    return out


def _distro(bag_dir: Path) -> str:
    """The metadata's ``ros_distro``: ``jazzy`` from dpos' writer, ``rosbags`` from rosbags'."""
    return "jazzy" if bag_dir.parent.name == "fast" else "rosbags"


def test_fast_writer_lays_out_the_bag_as_rosbags(written: tuple[Path, Path]) -> None:
    fast, ref = written
    assert (fast / "metadata.yaml").read_text().replace("ros_distro: jazzy", "ros_distro: X") == \
        (ref / "metadata.yaml").read_text().replace("ros_distro: rosbags", "ros_distro: X")
    got, want = _layout(fast / "b.mcap"), _layout(ref / "b.mcap")
    assert sum(1 for r in want if isinstance(r, tuple) and r[0] == "chunk") > 2  # the test covers chunk boundaries
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        assert g == w, f"record {i}: {str(g)[:200]} != {str(w)[:200]}"


def test_the_bag_names_its_writer_and_stores_the_design_qos(written: tuple[Path, Path]) -> None:
    """The MCAP header names dpos as the writer; every topic's offered QoS is the design's (the
    datum latched: TRANSIENT_LOCAL, depth 1; the streams VOLATILE), in metadata.yaml and in the
    channel records, as rosbag2 and ``ros2 bag play`` read them."""
    from importlib.metadata import version

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability

    fast, _ = written
    with (fast / "b.mcap").open("rb") as f:
        header = next(r for r in StreamReader(f, skip_magic=False).records if isinstance(r, Header))
    assert header.library == f"dpos_ros-{version('dpos_ros')}" and header.profile == "ros2"
    with AnyReader([fast]) as r:
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    assert qos["/dpos/datum"][0].durability == QosDurability.TRANSIENT_LOCAL and qos["/dpos/datum"][0].depth == 1
    assert all(q[0].durability == QosDurability.VOLATILE and q[0].depth == 5000 for t, q in qos.items() if t != "/dpos/datum")
    with (fast / "b.mcap").open("rb") as f:
        channels = [r for r in StreamReader(f, skip_magic=False).records if type(r).__name__ == "Channel"]
    datum = next(c for c in channels if c.topic == "/dpos/datum")
    assert "durability: transient_local" in datum.metadata["offered_qos_profiles"]


def test_chunks_carry_their_crc_and_a_flipped_byte_skips_the_chunk_naming_it(written: tuple[Path, Path], tmp_path: Path) -> None:
    """Every chunk's uncompressed CRC-32 is written (the mcap library validates it); a byte flipped
    inside a chunk's compressed records is found by the reader, not read as data: the chunk is
    skipped and named (test_one_bad_byte.py: the rest is read)."""
    import zlib

    fast, _ = written
    with (fast / "b.mcap").open("rb") as f:
        chunks = [r for r in StreamReader(f, skip_magic=False, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) > 2
    for c in chunks:
        assert c.uncompressed_crc == zlib.crc32(zstandard.ZstdDecompressor().decompress(c.data, max_output_size=c.uncompressed_size))
    bad = tmp_path / "b"
    shutil.copytree(fast, bad)
    raw = bytearray((bad / "b.mcap").read_bytes())
    # a byte in the middle of the second chunk's compressed data; zstd frames carry no checksum here
    start = raw.find(bytes(chunks[1].data[:64]))
    assert start > 0
    raw[start + len(chunks[1].data) // 2] ^= 0x01
    (bad / "b.mcap").write_bytes(bytes(raw))
    notes: list[str] = []
    bag.read_raw(bad, notes=notes)
    assert len(notes) == 1 and re.search(r"chunk at byte \d+ .* is skipped: CRC mismatch", notes[0])


def test_fast_and_rosbags_read_the_same_messages(streams: list[TopicStream], written: tuple[Path, Path]) -> None:
    for b in written:
        fast, ref = bag.read_raw(b), bag.read_raw_rosbags(b)
        assert list(fast) == list(ref) == [s.topic for s in streams]
        for s in streams:
            mt, times, blobs = fast[s.topic]
            assert isinstance(blobs, Messages)
            assert (mt, times) == (ref[s.topic].msgtype, ref[s.topic].times) == (s.msgtype, s.t_ns.tolist())
            assert blobs == ref[s.topic].blobs == [s.message(i) for i in range(len(s))], s.topic
    only = bag.read_raw(written[0], ["/master/nav", "/no/such"])
    assert list(only) == ["/master/nav"] and only["/master/nav"] == bag.read_raw_rosbags(written[0], "/master/nav".__eq__)["/master/nav"]


def _unordered_bag(path: Path) -> list[tuple[str, int, bytes]]:
    """A bag as a recorder may write it: log times out of order and repeated, within and across
    chunks (messages of 200 kB: about 5 per chunk); returns what was written, in file order."""
    rng = np.random.default_rng(3)
    ts = bag.typestore()
    written = []
    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    w.open()
    conns = {t: w.add_connection(t, "std_msgs/msg/String", typestore=ts) for t in ("/a", "/b")}
    times = [5, 3, 3, 9, 1, 7, 3, 2, 2, 8, 5, 6, 4, 3, 1, 0, 9, 9, 5, 2, 7, 1, 3, 3]
    for k, t in enumerate(times):
        topic = "/a" if k % 3 else "/b"
        data = bytes([k]) * int(rng.integers(150_000, 250_000))
        w.write(conns[topic], t * 1_000_000, data)
        written.append((topic, t * 1_000_000, data))
    w.close()
    return written


def test_out_of_order_and_duplicate_log_times_come_in_rosbags_order(tmp_path: Path) -> None:
    written = _unordered_bag(tmp_path / "u")
    fast, ref = bag.read_raw(tmp_path / "u"), bag.read_raw_rosbags(tmp_path / "u")
    assert fast == ref
    for topic in ("/a", "/b"):
        mine = [(t, d) for tp, t, d in written if tp == topic]
        assert fast[topic].times == sorted(t for t, _ in mine)  # by log time ...
        assert list(fast[topic].blobs) == [d for _, d in sorted(mine, key=lambda m: m[0])]  # ... ties in file order


def test_a_corrupt_chunk_is_skipped_naming_it(written: tuple[Path, Path], tmp_path: Path) -> None:
    b = tmp_path / "corrupt"
    shutil.copytree(written[0], b)
    mcap = b / "b.mcap"
    with mcap.open("rb") as f:
        chunks = [(f.tell(), r) for r in StreamReader(f, skip_magic=False).records if isinstance(r, ChunkIndex)]
    start = chunks[0][1].chunk_start_offset
    buf = bytearray(mcap.read_bytes())
    data = start + 9 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8  # the chunk's compressed records
    assert buf[data : data + 4] == b"\x28\xb5\x2f\xfd"  # a zstd frame
    buf[data : data + 4] = b"\x00\x00\x00\x00"
    mcap.write_bytes(bytes(buf))
    notes: list[str] = []
    bag.read_raw(b, notes=notes)
    assert len(notes) == 1 and f"b.mcap: the chunk at byte {start} (" in notes[0] and "is skipped: cannot be decompressed" in notes[0]
    with pytest.raises(SessionError, match="no /dpos/datum"):  # (the first chunk holds the latched datum)
        read_session(b)


def test_bags_the_fast_path_does_not_read_go_through_rosbags(written: tuple[Path, Path], tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    ref = bag.read_raw_rosbags(written[1])
    # a SQLite3 bag
    db = tmp_path / "db"
    w = Writer(db, version=9, storage_plugin=StoragePlugin.SQLITE3)
    w.open()
    ts = bag.typestore()
    conns = {t: w.add_connection(t, mt, typestore=ts) for t, (mt, _, _) in ref.items()}
    for t, (_, times, blobs) in ref.items():
        for tt, d in zip(times, blobs):
            w.write(conns[t], tt, d)
    w.close()
    calls: list[Path] = []
    monkeypatch.setattr(bag, "read_raw_rosbags", lambda p, wanted=None: calls.append(p) or ref)
    assert bag.read_raw(db) is ref and calls == [db]
    # an MCAP without its summary (footer cut off) but with metadata.yaml: recovered from its start, not rosbags'
    cut = tmp_path / "cut"
    shutil.copytree(written[0], cut)
    with (cut / "b.mcap").open("r+b") as f:
        f.truncate((cut / "b.mcap").stat().st_size - 20)
    notes: list[str] = []
    assert bag.read_raw(cut, notes=notes) == ref and calls == [db]
    assert "is damaged: b.mcap: no footer at its end" in notes[0]


def test_spill_records_are_read_back_as_written(tmp_path: Path) -> None:
    w = spill.SpillWriter(tmp_path / "s", "sess", {"k": "v"})
    fixed = [bytes([i]) * 40 for i in range(50)]
    mixed = [bytes([i]) * (10 + i % 7) for i in range(50)]
    for i in range(50):
        w.write("/fixed", "sensor_msgs/msg/Imu", 1000 + i, fixed[i])
        w.write("/mixed", "std_msgs/msg/String", 2000 - i, mixed[i])
    w.close()
    late = spill.SpillWriter(tmp_path / "s" / spill.LATE_DIR, "sess")
    late.write("/fixed", "sensor_msgs/msg/Imu", 1010, b"late" * 10)  # a stamp the main log has: after it
    late.write("/fixed", "sensor_msgs/msg/Imu", 5, b"early" * 8)
    late.close()
    with (tmp_path / "s" / "0.log").open("ab") as f:
        f.write(struct.pack("<qI", 1050, 40) + b"cut")  # a record cut short by a crash
    raw, custom, sid, warns = spill.read_spill(tmp_path / "s", include_late=False)
    assert (custom, sid) == ({"k": "v"}, "sess")
    assert raw["/fixed"] == RawTopic("sensor_msgs/msg/Imu", list(range(1000, 1050)), Messages.from_list(fixed))
    assert raw["/mixed"].times == [2000 - i for i in range(50)] and raw["/mixed"].blobs == mixed
    assert len(warns) == 1 and "/fixed: the last record of 0.log is cut short (15 bytes" in warns[0]
    merged, _, _, warns = spill.read_spill(tmp_path / "s")
    assert merged["/fixed"].times == [5, *range(1000, 1011), 1010, *range(1011, 1050)]
    assert merged["/fixed"].blobs == [b"early" * 8, *fixed[:11], b"late" * 10, *fixed[11:]]
    assert any("/fixed: 2 message(s) arrived after the session was closed" in x for x in warns)


def test_stray_frame_names_are_rejected_by_the_session_decoder() -> None:
    """Messages of another device on a topic (other frame names: another size, or the same size)
    are counted and rejected; the others decode as without them (rows gathered around the strays)."""
    raw = bag.read_raw(SAMPLE)
    clean = session_from_raw(dict(raw), bag.custom_data(SAMPLE), SAMPLE)
    topic = "/sub_imu/sub_r/imu"
    mt, times, blobs = raw[topic]
    t, v = cdr.decode(cdr.layout("imu", "sub_imu_sub_r"), blobs.rows())
    strays = [bytes(cdr.encode(cdr.layout("imu", name), t[i : i + 1], v[i : i + 1])[0])
              for i, name in ((100, "stray_imu"), (200, "sub_imu_sub_x"), (300, "stray_imu"))]
    assert len(strays[0]) != len(blobs[0]) and len(strays[1]) == len(blobs[0])
    raw[topic] = RawTopic(mt, times[:250] + [times[250]] * 3 + times[250:], Messages.from_list([*blobs[:250], *strays, *blobs[250:]]))
    sess = session_from_raw(raw, bag.custom_data(SAMPLE), SAMPLE)
    assert [w for w in sess.warnings if w not in clean.warnings] == [
        f"{topic}: 3 message(s) with other frame names than 'sub_imu_sub_r' (or another type) rejected; the others kept"]
    got, want = sess.sub_imus["sub_r"], clean.sub_imus["sub_r"]
    assert np.array_equal(got.t_s, want.t_s) and np.array_equal(got.omega_radps, want.omega_radps) and np.array_equal(got.f_mps2, want.f_mps2)


def test_messages_behave_as_a_list_of_bytes() -> None:
    blobs = [b"abcd", b"efgh", b"ij", b"", b"klmnop"]
    m = Messages.from_list(blobs)
    assert len(m) == 5 and list(m) == blobs and m == blobs and blobs == m and m != blobs[:4]
    assert m[1] == b"efgh" and m[-1] == b"klmnop" and m[1:3] == blobs[1:3] and m[::2] == blobs[::2]
    assert m[::2] + m[-1:] == blobs[::2] + blobs[-1:] and m[:1] + [b"x"] == [b"abcd", b"x"]
    assert m.take(np.array([4, 0, 3])) == [b"klmnop", b"abcd", b""]
    with pytest.raises(IndexError):
        m[5]
    fixed = Messages.from_list(blobs[:2])
    rows = fixed.rows()
    assert rows.shape == (2, 4) and np.shares_memory(rows, fixed.data)  # back to back: a view
    assert m.rows(np.array([1, 0])).tolist() == [list(b"efgh"), list(b"abcd")]
    with pytest.raises(ValueError, match="different sizes"):
        m.rows()
    assert Messages.concat([m[:2], m[2:]]) == m and Messages.from_rows(rows) == blobs[:2]


def test_batches_encoded_elsewhere_give_the_same_file(streams: list[TopicStream], tmp_path: Path) -> None:
    """Batches laid out and compressed apart (``encode_streams``, a process pool's task) and
    appended in order (``Writer.add_encoded``) give the file that ``Writer.add`` writes, byte for
    byte; a batch out of place (the first without the writer's prefix) is refused."""
    edges = [int(np.quantile(np.concatenate([s.t_ns for s in streams]), q)) for q in (0.3, 0.7)]

    def batches() -> list[list[TopicStream]]:
        out = []
        for lo, hi in zip([None, *edges], [*edges, None], strict=True):
            part = []
            for s in streams:
                sel = np.ones(len(s), dtype=bool) if lo is None else s.t_ns >= lo
                if hi is not None:
                    sel &= s.t_ns < hi
                idx = np.flatnonzero(sel)
                part.append(TopicStream(s.topic, s.msgtype, s.t_ns[idx], rows=None if s.rows is None else s.rows[idx],
                                        blobs=None if s.blobs is None else tuple(s.blobs[i] for i in idx)))
            out.append(part)
        return out

    custom = {"dpos.session_id": "s1"}
    added, encoded = tmp_path / "added" / "b", tmp_path / "encoded" / "b"  # (the name is in the file)
    bag.write_stream_batches(added, batches(), custom_data=custom)
    w = bag.new_writer(encoded, [(s.topic, s.msgtype) for s in streams], custom)
    with pytest.raises(ValueError, match="prefix"):
        w.add_encoded(bag.encode_streams(batches()[0]))
    for k, part in enumerate(batches()):
        w.add_encoded(bag.encode_streams(part, w.prefix if k == 0 else b""))
    w.close()
    assert (encoded / "b.mcap").read_bytes() == (added / "b.mcap").read_bytes()
    assert (encoded / "metadata.yaml").read_text() == (added / "metadata.yaml").read_text()
    assert sum(len(v[2]) for v in bag.read_raw(encoded).values()) == sum(len(s) for s in streams)
