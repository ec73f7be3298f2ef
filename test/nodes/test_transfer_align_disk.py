"""transfer_align_node on a real filesystem that fills up or is read-only (a small tmpfs; real
processes: the node, dpos-play of the sample bag).

* output_dir on a read-only filesystem: the node refuses to start (exit 2) naming output_dir;
* a 1 MB disk under a 45 s, 6.6 MB session: the node holds what the disk refuses in memory,
  reports it, finalize waits; once the filesystem is grown the spill is completed and the
  products are written; the spill holds every message of the bag, byte for byte.

Mounting needs root (CAP_SYS_ADMIN), which the project's machines and CI have; elsewhere these
tests skip, and test_transfer_align_faults.py covers the same logic with an injected failing writer.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from node_process import NodeProcess
from repo_paths import REPO

from dpos_ros.io import bag, spill

pytestmark = [pytest.mark.ros, pytest.mark.slow]

EXE = Path(sys.executable).parent
BAG = REPO / "bags" / "paper_su_pair_seed1_45s"
TOPICS = ["/dpos/datum", "/master/nav", "/sub_imu/sub_r/imu", "/sub_imu/sub_l/imu"]


def _mount(path: Path, *opts: str) -> subprocess.CompletedProcess:
    return subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(opts), "tmpfs", str(path)], capture_output=True, text=True)


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Path]:
    d = tmp_path / "disk"
    d.mkdir()
    r = _mount(d, "size=1m")
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {r.stderr.strip()}")
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def _ta(out: Path) -> NodeProcess:
    return NodeProcess("transfer_align_node", ["--ros-args", "-p", "method:=urtss", "-p", "aircraft_config:=paper_su_pair",
                                               "-p", f"output_dir:={out}", "-p", "finalize_timeout_s:=5.0", "-p", "output_rate_hz:=1.0"])


def test_read_only_output_dir_is_refused_at_start(tmpfs: Path) -> None:
    (tmpfs / "out").mkdir()
    subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)], check=True)
    ta = _ta(tmpfs / "out")
    assert ta.wait(60) == 2
    ta.wait_for_line("not writable", 10)
    assert any("output_dir" in line and "Read-only file system" in line for line in ta.lines), ta.lines


def test_full_disk_holds_in_memory_and_completes_when_space_returns(tmpfs: Path) -> None:
    out = tmpfs / "out"
    ta = _ta(out)
    try:
        ta.wait_for_line("finalize on /session/end", 60)
        play = subprocess.run([str(EXE / "dpos-play"), str(BAG), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30",
                               "--topics", *TOPICS, "/session/end"], capture_output=True, text=True, timeout=300)
        assert play.returncode == 0, play.stdout + play.stderr
        line = ta.wait_for_line("finalize waits for the disk", 120)
        assert "held in memory (No space left on device" in line, line
        assert not list(out.glob("*/status.json"))
        subprocess.run(["mount", "-o", "remount,size=64m", str(tmpfs)], check=True)
        ta.wait_for_line("the disk took the held messages", 30)
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and not list(out.glob("paper_su_seed1/status.json")):
            time.sleep(0.2)
        st = json.loads((out / "paper_su_seed1" / "status.json").read_text())
    finally:
        if ta.proc.poll() is None:
            os.kill(ta.proc.pid, signal.SIGINT)
        code = ta.wait(60)
    assert code == 0, ta.lines[-20:]
    assert st["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}, st
    raw = bag.read_raw(BAG, TOPICS)
    got, _, _, warns = spill.read_spill(next((out / "spill").iterdir()))
    assert not warns
    for t in TOPICS:
        assert got[t][2] == raw[t][2], t  # nothing lost, nothing cut, in order


def test_stop_while_the_disk_stays_full_exits_and_says_what_is_lost(tmpfs: Path) -> None:
    ta = _ta(tmpfs / "out")
    try:
        ta.wait_for_line("finalize on /session/end", 60)
        play = subprocess.run([str(EXE / "dpos-play"), str(BAG), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30",
                               "--topics", *TOPICS, "/session/end"], capture_output=True, text=True, timeout=300)
        assert play.returncode == 0, play.stdout + play.stderr
        ta.wait_for_line("finalize waits for the disk", 120)
    finally:
        if ta.proc.poll() is None:
            os.kill(ta.proc.pid, signal.SIGINT)
        code = ta.wait(60)  # bounded: finalize_timeout_s (5 s) after the stop
    assert code == 0, ta.lines[-20:]
    assert any("are lost with the process" in line and "held in memory" in line for line in ta.lines), ta.lines[-20:]
