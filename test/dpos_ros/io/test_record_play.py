"""dpos-record and dpos-play (dpos_ros.io.record / dpos_ros.io.play) as processes.

A dpos-sim bag played with ``dpos-play --rate 0`` into ``dpos-record --until-session-end`` comes back
with the same messages per topic, byte for byte and in order; ``--rate 10`` is paced and publishes
/clock; bad input gives an error naming the file (or the missing topic), never a hang.
Every wait is bounded; nothing sleeps for a fixed time.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from node_process import CLI_TIMEOUT_S, START_TIMEOUT_S  # test/support/node_process.py

from dpos_ros.io.bag import custom_data, read_raw

pytestmark = pytest.mark.ros

BIN_DIR = Path(sys.executable).parent

RUN_TIMEOUT_S = 90.0


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory) -> Path:
    """A 10 s paper_su session with both wings (9028 messages on 13 topics), written by dpos-sim."""
    out = tmp_path_factory.mktemp("record_play") / "sim10"
    r = subprocess.run([str(BIN_DIR / "dpos-sim"), "--scenario", "paper_su", "--aircraft", "paper_su_pair",
                        "--duration", "10", "--out", str(out)], capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def _same_cdr(live: bytes, stored: bytes) -> bool:
    """Equal, up to the zero padding to a multiple of 4 bytes that Fast DDS adds between processes."""
    if live == stored:
        return True
    pad = len(live) - len(stored)
    return 0 < pad < 4 and len(live) % 4 == 0 and live[: len(stored)] == stored and not any(live[len(stored):])


def _summary_seconds(line: str) -> float:
    m = re.search(r"of log time in ([0-9.]+) s", line)
    assert m, line
    return float(m.group(1))


def test_play_rate0_into_record_gives_the_same_bag(sim_bag, start_node, tmp_path):
    source = read_raw(sim_bag)
    topics = list(source)
    out = tmp_path / "rec"
    recorder = start_node("dpos-record", "--out", str(out), "--until-session-end", "--meta", "dpos.note=round trip",
                          "--meta", "operator=test", *topics)
    recorder.wait_for_line("dpos-record: recording", START_TIMEOUT_S)
    t0 = time.monotonic()
    player = start_node("dpos-play", str(sim_bag), "--rate", "0", "--min-subscribers", "1", "--wait-subscribers", "30")
    try:
        assert player.wait(RUN_TIMEOUT_S) == 0, player.output
        assert recorder.wait(RUN_TIMEOUT_S) == 0, recorder.output
    finally:
        for p in (player, recorder):
            if p.proc.poll() is None:
                p.send_signal(signal.SIGINT)
    wall_s = time.monotonic() - t0
    total = sum(len(v[2]) for v in source.values())
    line = player.wait_for_line("dpos-play: played:", 1.0)
    assert f"played: {total} of {total} messages on {len(topics)} topics" in line, line
    recorder.wait_for_line("/session/end received", 1.0)
    for p in (player, recorder):
        assert "Traceback" not in p.output, p.output
    print(f"round trip of {total} messages: {line.strip()}; {wall_s:.1f} s in all")

    got = read_raw(out)
    assert set(got) == set(source), (sorted(got), sorted(source))
    for topic, (msgtype, _times, raws) in source.items():
        mt, times, recorded = got[topic]
        assert mt == msgtype, topic
        assert len(recorded) == len(raws), f"{topic}: recorded {len(recorded)} of {len(raws)}"
        for i, (r, s) in enumerate(zip(recorded, raws)):
            assert _same_cdr(r, s), f"{topic}: message {i} differs"
        assert times == sorted(times), f"{topic}: log times (receive times) not in order"
        assert f"  {topic} " in recorder.output  # per-topic counts printed
    meta = custom_data(out)
    assert meta["dpos.note"] == "round trip" and meta["operator"] == "test", meta
    # the recorded bag is in turn playable (log time = receive time)
    assert (out / "metadata.yaml").is_file()


def test_play_rate10_is_paced_and_publishes_clock(sim_bag, ros_context, ros_executor, start_node):
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu

    from dpos_ros.contract.qos import SENSOR_QOS
    from dpos_ros.io.play import CLOCK_QOS

    _mt, imu_times, imu_raws = read_raw(sim_bag, ["/master/imu"])["/master/imu"]
    node = Node("record_play_clock", context=ros_context)
    clocks: list[int] = []
    imu: list[bytes] = []
    node.create_subscription(Clock, "/clock", lambda m: clocks.append(m.clock.sec * 1_000_000_000 + m.clock.nanosec), CLOCK_QOS)
    node.create_subscription(Imu, "/master/imu", lambda raw: imu.append(raw), SENSOR_QOS, raw=True)
    ros_executor.add_node(node)
    try:
        player = start_node("dpos-play", str(sim_bag), "--rate", "10", "--topics", "/master/imu",
                            "--min-subscribers", "1", "--wait-subscribers", "30")
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while player.proc.poll() is None or len(imu) < len(imu_raws):
            assert time.monotonic() < deadline, f"timed out: {len(imu)} of {len(imu_raws)} received; {player.output}"
            ros_executor.spin_once(timeout_sec=0.05)
            if player.proc.poll() is not None and len(imu) < len(imu_raws):
                # the process ended: take what is still queued, then stop looking
                end = time.monotonic() + 5.0
                while len(imu) < len(imu_raws) and time.monotonic() < end:
                    ros_executor.spin_once(timeout_sec=0.05)
                break
        assert player.wait(10.0) == 0, player.output
        line = player.wait_for_line("dpos-play: played:", 1.0)
        wall_s = _summary_seconds(line)
        print(f"--rate 10 of a 10 s bag: {line.strip()}")
        assert 0.6 <= wall_s <= 3.0, line
        assert len(imu) == len(imu_raws)
        assert all(_same_cdr(a, b) for a, b in zip(imu, imu_raws))
        end = time.monotonic() + 2.0
        while (not clocks or clocks[-1] < imu_times[-1]) and time.monotonic() < end:
            ros_executor.spin_once(timeout_sec=0.05)
        assert len(clocks) >= 20, f"only {len(clocks)} /clock messages"
        assert clocks == sorted(clocks), "/clock went backwards"
        assert imu_times[0] <= clocks[0] and clocks[-1] == imu_times[-1], (clocks[0], clocks[-1], imu_times[0], imu_times[-1])
    finally:
        ros_executor.remove_node(node)
        node.destroy_node()


def test_bad_input_is_reported_not_hung(sim_bag, start_node, tmp_path):
    play = str(BIN_DIR / "dpos-play")
    record = str(BIN_DIR / "dpos-record")

    # a bag that does not exist
    missing = tmp_path / "no_such_bag"
    r = subprocess.run([play, str(missing)], capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert r.returncode == 2 and str(missing) in r.stderr and "Traceback" not in r.stderr, r.stderr

    # a bag whose .mcap is cut in half: its intact chunks are recovered and played, with a warning naming the file
    cut = tmp_path / "cut"
    shutil.copytree(sim_bag, cut)
    (mcap,) = cut.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    r = subprocess.run([play, str(cut), "--rate", "0"], capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "Traceback" not in out, out
    assert f"{mcap.name}: no footer at its end (a file cut short): recovered" in out and "is lost" in out, out

    # a topic the bag does not have
    r = subprocess.run([play, str(sim_bag), "--topics", "/no/such/topic"], capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert r.returncode == 2 and "/no/such/topic" in r.stderr, r.stderr

    # recording a topic nobody publishes: reported as missing, the (empty) bag is still closed
    out = tmp_path / "rec_missing"
    r = subprocess.run([record, "--out", str(out), "--duration", "1.5", "--wait-topics", "0.5", "/no/such/topic"],
                       capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "missing /no/such/topic" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert read_raw(out) == {}

    # an existing output directory
    r = subprocess.run([record, "--out", str(sim_bag), "/master/imu"], capture_output=True, text=True, timeout=CLI_TIMEOUT_S)
    assert r.returncode == 2 and "exists" in r.stderr, r.stderr

    # Ctrl-C ends a recording cleanly
    out = tmp_path / "rec_sigint"
    proc = start_node("dpos-record", "--out", str(out), "--all")
    proc.wait_for_line("dpos-record: recording", START_TIMEOUT_S)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(START_TIMEOUT_S) == 0, proc.output
    assert "stopped (interrupted)" in proc.output and "Traceback" not in proc.output, proc.output
    assert (out / "metadata.yaml").is_file()
