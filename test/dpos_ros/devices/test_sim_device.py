"""The live simulated devices (dpos_ros.devices.sim_device, pos_master_node / pos_sub_node ``device: sim``).

What they publish must equal, byte for byte and without loss, the streams of dpos_ros.devices.sim_streams
(and so a bag of ``dpos-sim``) for the same scenario, aircraft, seed, duration and datum.
Every wait is bounded; nothing sleeps for a fixed time.
"""

from __future__ import annotations

import math
import re
import signal
import time
from collections import defaultdict
from typing import Any

import numpy as np
import pytest
from node_process import START_TIMEOUT_S, STOP_TIMEOUT_S  # test/support/node_process.py
from rclpy.parameter import Parameter

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.contract.qos import qos_profile
from dpos_ros.contract.topics import message_class
from dpos_ros.devices.sim_streams import TopicStream, device_streams, session_streams

pytestmark = pytest.mark.ros

IN_PROCESS_TIMEOUT_S = 60.0
GRAPH_TIMEOUT_S = 60.0


def _session(duration_s: float, aircraft: str | None = None, scenario: str = "paper_su", seed: int = 1):
    return SimulatedSession(load_scenario(scenario, aircraft=aircraft), seed, duration_s)


class Recorder:
    """Raw subscriptions to every topic of ``streams`` (the QoS the devices publish with).

    ``/dpos/datum`` is left out unless ``datum=True``; add it later with :meth:`subscribe`.
    """

    def __init__(self, node: Any, streams: list[TopicStream], datum: bool = True) -> None:
        self.node = node
        self.expected = {s.topic: s for s in streams}
        self.received: dict[str, list[bytes]] = defaultdict(list)
        self.subscriptions = []
        for s in streams:
            if s.qos != "datum" or datum:
                self.subscribe(s)

    def subscribe(self, stream: TopicStream) -> None:
        def callback(raw: bytes, topic: str = stream.topic) -> None:
            self.received[topic].append(raw)

        self.subscriptions.append(
            self.node.create_subscription(message_class(stream.msgtype), stream.topic, callback, qos_profile(stream.qos), raw=True)
        )

    def complete(self, topics=None) -> bool:
        topics = self.expected if topics is None else topics
        return all(len(self.received[t]) >= len(self.expected[t]) for t in topics)

    def counts(self) -> dict[str, tuple[int, int]]:
        return {t: (len(self.received[t]), len(s)) for t, s in self.expected.items()}


def _spin_until(executor: Any, condition, timeout: float, what) -> None:
    """Spin until ``condition()``; ``what`` (a string or a callable giving one) describes it on timeout."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what() if callable(what) else what}")
        executor.spin_once(timeout_sec=0.05)


def _output(proc: Any) -> str:
    """Everything a NodeProcess printed so far."""
    while not proc._queue.empty() and proc._drain(0.0):
        pass
    return proc.output


def _assert_same_messages(received: dict[str, list[bytes]], streams: list[TopicStream]) -> None:
    for s in streams:
        got = received.get(s.topic, [])
        assert len(got) == len(s), f"{s.topic}: received {len(got)} of {len(s)} messages"
        for i, raw in enumerate(got):
            assert raw == s.message(i), f"{s.topic}: message {i} differs"


def _same_cdr(live: bytes, stored: bytes) -> bool:
    """``live`` is ``stored``, up to the zero padding to a multiple of 4 bytes that DDS adds.

    Between processes Fast DDS carries a serialized payload padded to a 4-byte multiple, so a
    subscriber gets e.g. a 125-byte NavSatFix as 128 bytes (3 trailing zeros; the encapsulation
    header is unchanged). The content bytes must be identical. (In one process Fast DDS delivers
    the published buffer as is; the in-process tests compare strictly.)
    """
    if live == stored:
        return True
    pad = len(live) - len(stored)
    return 0 < pad < 4 and len(live) % 4 == 0 and live[: len(stored)] == stored and not any(live[len(stored):])


# ----------------------------------------------------------------------------- in process

def _run_master_in_process(ros_context, ros_executor, overrides: list[Parameter], expected: list[TopicStream]):
    """Start PosMasterNode with ``overrides`` next to a recorder; return (recorder, node) when done."""
    from rclpy.node import Node

    from pos_master_node.node import PosMasterNode

    sub_node = Node("sim_device_recorder", context=ros_context)
    recorder = Recorder(sub_node, expected, datum=False)
    ros_executor.add_node(sub_node)
    master = PosMasterNode(context=ros_context, parameter_overrides=overrides)
    ros_executor.add_node(master)
    others = [t for t in recorder.expected if t != "/dpos/datum"]
    _spin_until(
        ros_executor, lambda: master.device.finished.is_set() and recorder.complete(others),
        IN_PROCESS_TIMEOUT_S, lambda: f"the master streams (counts {recorder.counts()})",
    )
    assert master.device.error is None
    return recorder, master, sub_node


def _destroy(ros_executor, *nodes) -> None:
    for node in nodes:
        ros_executor.remove_node(node)
        node.destroy_node()


def test_master_in_process_publishes_the_device_streams_byte_for_byte(ros_context, ros_executor):
    expected = device_streams(_session(5.0), "master", truth=True)
    overrides = [
        Parameter("scenario", value="paper_su"), Parameter("duration", value=5.0),
        Parameter("rate_factor", value=0.0), Parameter("alignment", value="reference"),
        Parameter("min_subscribers", value=1), Parameter("wait_subscribers_s", value=20.0),
    ]
    recorder, master, sub_node = _run_master_in_process(ros_context, ros_executor, overrides, expected)
    try:
        assert {s.topic for s in master.device.streams} == {s.topic for s in expected}
        assert master.device.published == sum(len(s) for s in expected)
        # the latched datum reaches a TRANSIENT_LOCAL subscriber created after its publication
        datum = next(s for s in expected if s.topic == "/dpos/datum")
        recorder.subscribe(datum)
        _spin_until(ros_executor, lambda: recorder.received["/dpos/datum"], 10.0, "the latched /dpos/datum")
        _assert_same_messages(recorder.received, expected)
        assert recorder.received["/session/end"], "no /session/end"
    finally:
        _destroy(ros_executor, master, sub_node)


def test_master_in_process_given_datum_and_ifa_alignment(ros_context, ros_executor):
    """A given datum [deg] is the enu origin of the poses; alignment ifa publishes no /master/nav (yet)."""
    datum_deg = [40.01, 116.02, 450.0]
    datum_rad = np.array([math.radians(datum_deg[0]), math.radians(datum_deg[1]), datum_deg[2]])
    expected = [s for s in device_streams(_session(1.0), "master", truth=True, datum_llh=datum_rad) if s.topic != "/master/nav"]
    overrides = [
        Parameter("duration", value=1), Parameter("rate_factor", value=0), Parameter("alignment", value="ifa"),
        Parameter("datum", value=datum_deg), Parameter("min_subscribers", value=1),
        Parameter("wait_subscribers_s", value=20.0),
    ]
    recorder, master, sub_node = _run_master_in_process(ros_context, ros_executor, overrides, expected)
    try:
        assert "/master/nav" not in {s.topic for s in master.device.streams}
        recorder.subscribe(next(s for s in expected if s.topic == "/dpos/datum"))
        _spin_until(ros_executor, lambda: recorder.received["/dpos/datum"], 10.0, "the latched /dpos/datum")
        _assert_same_messages(recorder.received, expected)
    finally:
        _destroy(ros_executor, master, sub_node)


# ----------------------------------------------------------------------------- processes

def test_graph_of_processes_equals_the_bag(ros_context, ros_executor, start_node, tmp_path):
    """pos_master_node + two pos_sub_node processes at rate 0 == dpos-sim's bag, no message lost."""
    from rclpy.node import Node

    from dpos_ros.io.bag import read_raw, write_streams

    duration, aircraft, seed = 10.0, "paper_su_pair", 1
    streams = session_streams(_session(duration, aircraft=aircraft, seed=seed), truth=True)
    write_streams(tmp_path / "bag", streams)
    bag = read_raw(tmp_path / "bag")

    node = Node("graph_recorder", context=ros_context)
    recorder = Recorder(node, streams, datum=True)
    ros_executor.add_node(node)
    common = ["-p", "scenario:=paper_su", "-p", f"aircraft_config:={aircraft}", "-p", f"seed:={seed}",
              "-p", f"duration:={duration}", "-p", "rate_factor:=0", "-p", "min_subscribers:=1"]
    t0 = time.monotonic()
    procs = [start_node("pos_master_node", "--ros-args", "-p", "alignment:=reference", *common)]
    for name in ("sub_r", "sub_l"):
        procs.append(start_node("pos_sub_node", "--ros-args", "-r", f"__node:={name}", "-p", f"name:={name}", *common))
    try:
        sub_topics = [t for t in recorder.expected if t.startswith(("/sub_imu/", "/truth/sub_imu/", "/truth/antenna/ant_"))]
        _spin_until(
            ros_executor,
            lambda: recorder.received["/session/end"] and recorder.complete(sub_topics) and recorder.complete(),
            GRAPH_TIMEOUT_S,
            lambda: f"/session/end and every stream (counts {recorder.counts()}); outputs:\n"
            + "\n".join(_output(p) for p in procs),
        )
        wall_s = time.monotonic() - t0
        for proc in procs:
            proc.wait_for_line(" topics in ", START_TIMEOUT_S)
        print(f"graph of 3 device processes, {duration:g} s session: all received after {wall_s:.1f} s")
        # nothing more arrives (no duplicates)
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            ros_executor.spin_once(timeout_sec=0.05)
        assert set(recorder.received) == set(bag), (sorted(recorder.received), sorted(bag))
        for topic, (_msgtype, _times, raws) in bag.items():
            got = recorder.received[topic]
            assert len(got) == len(raws), f"{topic}: {len(got)} live vs {len(raws)} in the bag"
            for i, (live, stored) in enumerate(zip(got, raws)):
                assert _same_cdr(live, stored), f"{topic}: message {i} differs: live {live.hex()} bag {stored.hex()}"
    finally:
        ros_executor.remove_node(node)
        node.destroy_node()
        for proc in procs:
            if proc.proc.poll() is None:
                proc.send_signal(signal.SIGINT)
    for proc in procs:
        rc = proc.wait(STOP_TIMEOUT_S)
        assert rc == 0, f"{proc.argv}: exit status {rc}; output:\n{proc.output}"
        assert "Traceback" not in proc.output, proc.output


def test_real_time_pacing_and_ifa_warning(start_node):
    """rate_factor 1: a 3 s session takes about 3 s (generous bounds); alignment ifa warns."""
    proc = start_node("pos_master_node", "--ros-args", "-p", "duration:=3", "-p", "rate_factor:=1.0",
                      "-p", "alignment:=ifa", "-p", "publish_truth:=false")
    warning = proc.wait_for_line("[WARN]", START_TIMEOUT_S)
    assert "/master/nav" in warning and "alignment" in warning, warning
    line = proc.wait_for_line(" topics in ", START_TIMEOUT_S)
    wall_s = float(re.search(r"published \d+ messages on \d+ topics in ([0-9.]+) s", line).group(1))
    assert 2.5 <= wall_s <= 6.0, line
    proc.wait_for_line("session paper_su_seed1 ended", 5.0)
    assert proc.proc.poll() is None, "the node must stay up after the session"
    proc.send_signal(signal.SIGINT)
    assert proc.wait(STOP_TIMEOUT_S) == 0, proc.output


@pytest.mark.parametrize(
    ("script", "args", "expected"),
    [
        ("pos_sub_node", ["-p", "name:=sub_x", "-p", "aircraft_config:=paper_su_pair"], ["'name'", "sub_x", "sub_r, sub_l"]),
        ("pos_sub_node", ["-p", "name:=sub_l"], ["'name'", "sub_l", "sub_r"]),
        ("pos_master_node", ["-p", "duration:=-1.0"], ["'duration'", "-1.0", ">= 0"]),
        ("pos_master_node", ["-p", "duration:=2000.0"], ["'duration'", "2000.0", "1300"]),
        ("pos_sub_node", ["-p", "name:=sub_r", "-p", "duration:=2000.0"], ["'duration'", "longer than"]),
        ("pos_master_node", ["-p", "device:=ros", "-p", "alignment:=reference"], ["'alignment'", "reference", "simulation only"]),
        ("pos_sub_node", ["-p", "name:=sub_r", "-p", "device:=ros", "-p", "input_reliability:=sometimes"],
         ["'input_reliability'", "sometimes", "best_effort, reliable"]),
        ("pos_master_node", ["-p", "aircraft_config:=no_such_plane"], ["'aircraft_config'", "no_such_plane"]),
        ("pos_master_node", ["-p", "datum:=[40.0, 200.0, 0.0]"], ["'datum'", "longitude"]),
    ],
)
def test_bad_device_parameters_exit_nonzero_naming_the_problem(script, args, expected, start_node):
    proc = start_node(script, "--ros-args", *args)
    rc = proc.wait(START_TIMEOUT_S)
    assert rc != 0, proc.output
    error = proc.wait_for_line("[ERROR]", 1.0)
    for text in expected:
        assert text in error, error
    assert "Traceback" not in proc.output, proc.output
    assert "-> publishing" not in proc.output


def test_writer_depths_share_the_flow_window():
    """Writer depths: the window shared by message count, >= 1, <= the stream, divisors preferred."""
    from dpos_ros.io.flow import FLOW_WINDOW, writer_depths

    streams = device_streams(_session(10.0), "master", truth=True)
    depths = dict(zip((s.topic for s in streams), writer_depths(streams)))
    lengths = {s.topic: len(s) for s in streams}
    assert depths["/dpos/datum"] == 1  # DATUM_QOS
    assert depths["/session/end"] == 1
    for topic, d in depths.items():
        assert 1 <= d <= lengths[topic]
        if lengths[topic] >= 100:
            assert lengths[topic] % d == 0, (topic, d, lengths[topic])
    assert sum(d for t, d in depths.items() if t != "/dpos/datum") <= 1.5 * FLOW_WINDOW + len(depths)


def test_device_fastdds_profile_respects_the_users_configuration(tmp_path, monkeypatch):
    from dpos_ros.io.flow import HEARTBEAT_PERIOD_MS, use_device_fastdds_profile

    monkeypatch.chdir(tmp_path)
    env = {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    path = use_device_fastdds_profile(env)
    assert path and env["FASTRTPS_DEFAULT_PROFILES_FILE"] == path == env["FASTDDS_DEFAULT_PROFILES_FILE"]
    text = open(path).read()
    assert f"<nanosec>{HEARTBEAT_PERIOD_MS * 1_000_000}</nanosec>" in text and "heartbeatPeriod" in text
    assert use_device_fastdds_profile({"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"}) is None
    assert use_device_fastdds_profile({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}) is None
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert use_device_fastdds_profile({}) is None
