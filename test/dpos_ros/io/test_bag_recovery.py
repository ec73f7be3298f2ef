"""A recording that was never closed (a killed dpos-record leaves an MCAP without
metadata.yaml and without its summary): every reading tool recovers the complete messages into
``<bag>.recovered``, says so, and leaves the original untouched."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from dpos_ros.io.bag import RECOVERED_SUFFIX, read_raw, readable_bag
from dpos_ros.io.play import BagError, open_bag
from dpos_ros.io.session import read_session

REPO = Path(__file__).resolve().parents[3]
SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


def _killed(tmp_path: Path, fraction: float) -> Path:
    """The sample bag as a killed recorder leaves it: no metadata.yaml, the MCAP cut short."""
    bag = tmp_path / "killed"
    shutil.copytree(SAMPLE, bag)
    (bag / "metadata.yaml").unlink()
    mcap = next(bag.glob("*.mcap"))
    with mcap.open("r+b") as f:
        f.truncate(int(mcap.stat().st_size * fraction))
    return bag


def test_complete_messages_are_recovered_in_order_and_said(tmp_path: Path):
    bag = _killed(tmp_path, 0.6)
    before = {p.name: p.stat().st_size for p in bag.iterdir()}
    notes: list[str] = []
    raw = read_raw(bag, notes=notes)
    full = read_raw(SAMPLE)
    n, n_full = sum(len(v[2]) for v in raw.values()), sum(len(v[2]) for v in full.values())
    assert 0.45 * n_full < n < 0.65 * n_full  # what was in complete chunks, nothing invented
    for topic, (mt, t, data) in raw.items():  # each topic's messages are the first ones of the original, byte for byte
        assert mt == full[topic][0]
        assert t == full[topic][1][: len(t)] and data == full[topic][2][: len(data)]
    assert len(notes) == 1 and f"recovered {n} messages" in notes[0] and "no metadata.yaml" in notes[0]
    assert "incomplete record" in notes[0]
    out = bag.with_name(bag.name + RECOVERED_SUFFIX)
    assert (out / "metadata.yaml").is_file()
    assert {p.name: p.stat().st_size for p in bag.iterdir()} == before  # the original is not touched
    again: list[str] = []
    assert sum(len(v[2]) for v in read_raw(bag, notes=again).values()) == n and "made earlier" in again[0]


def test_play_and_process_read_a_recording_that_was_not_closed(tmp_path: Path):
    bag = _killed(tmp_path, 0.8)
    said: list[str] = []
    reader = open_bag(bag, said.append)
    try:
        assert {c.topic for c in reader.connections} >= {"/master/imu", "/master/nav", "/gnss/fix"}
        assert sum(1 for _ in reader.messages()) > 0
    finally:
        reader.close()
    assert said and "recovered" in said[0]
    sess = read_session(bag)  # what dpos-process reads
    assert any("no metadata.yaml" in w for w in sess.warnings)


def test_nothing_to_recover_is_an_error_naming_the_file(tmp_path: Path):
    bag = tmp_path / "junk"
    bag.mkdir()
    (bag / "junk.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 10)
    with pytest.raises(ValueError, match="no complete message"):
        readable_bag(bag)
    with pytest.raises(BagError, match="junk.mcap"):
        open_bag(bag)
    assert readable_bag(SAMPLE) == (SAMPLE, None)  # a closed bag is read as it is
