"""dpos-play on something that is not a bag: one line naming it, exit 2, no traceback.
A bag's .mcap without metadata.yaml is still recovered (dpos_ros.io.bag.readable_bag)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from node_process import CLI_TIMEOUT_S  # test/support/node_process.py

pytestmark = pytest.mark.ros

PLAY = str(Path(sys.executable).parent / "dpos-play")


def _play(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([PLAY, *args, "--rate", "0"], capture_output=True, text=True, timeout=CLI_TIMEOUT_S, cwd=cwd)


def _one_error_line(r: subprocess.CompletedProcess, *needles: str) -> str:
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("dpos-play: error: "), r.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def test_text_file(tmp_path: Path) -> None:
    f = tmp_path / "notes.txt"
    f.write_text("not a bag\n")
    _one_error_line(_play(str(f)), str(f), "not a rosbag2")


def test_empty_folder(tmp_path: Path) -> None:
    d = tmp_path / "empty"
    d.mkdir()
    _one_error_line(_play(str(d)), str(d), "not a rosbag2 directory", "empty")


def test_folder_without_bag_files(tmp_path: Path) -> None:
    d = tmp_path / "other"
    d.mkdir()
    (d / "readme.txt").write_text("x")
    _one_error_line(_play(str(d)), str(d), "no metadata.yaml and no .mcap or .db3")


def test_garbage_mcap_in_the_working_directory(tmp_path: Path) -> None:
    (tmp_path / "junk.mcap").write_bytes(b"garbage\n")
    _one_error_line(_play("junk.mcap", cwd=tmp_path), "junk.mcap", "not an MCAP file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.mcap"]  # nothing written beside it


@pytest.mark.parametrize("bad", ["/gnss fix", "/gnss/1ix", "/gnss//ix"])
def test_bag_with_an_invalid_topic_name(tmp_path: Path, bad: str) -> None:
    """A recording whose topic rcl refuses (a space, a token starting with a digit, an empty
    token): one line naming the topic, nothing published (the probe's case, then ours)."""
    from repo_paths import REPO

    d = tmp_path / "bag"
    d.mkdir()
    for f in (REPO / "bags" / "paper_su_pair_seed1_45s").iterdir():  # the same length: the MCAP's offsets hold
        (d / f.name).write_bytes(f.read_bytes().replace(b"/gnss/fix", bad.encode()))
    _one_error_line(_play(str(d)), repr(bad), "not a valid ROS topic name")
