"""A live paper_sar main system recorded with dpos-record carries /sar/fix and /baro/pressure byte for
byte as the simulator makes them, and dpos-sar navigates that recording (processes, real DDS)."""

from __future__ import annotations

import json
import signal

import pytest
from node_process import START_TIMEOUT_S, STOP_TIMEOUT_S  # test/support/node_process.py

from dpos_ros.cli.sar import main as dpos_sar
from dpos_ros.contract import topics as T
from dpos_ros.devices.sim_session import load_sim_session
from dpos_ros.devices.sim_streams import device_streams
from dpos_ros.io.bag import read_raw

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DURATION_S = 30.0
TOPICS = [T.DATUM, T.MASTER_IMU, T.GNSS_FIX, T.GNSS_VEL, T.SAR_FIX, T.BARO_PRESSURE, T.MASTER_NAV, T.TRUTH_MASTER, T.SESSION_END]


def test_recording_of_a_live_paper_sar_session(start_node, tmp_path) -> None:
    out = tmp_path / "rec"
    recorder = start_node("dpos-record", "--out", str(out), "--until-session-end", *TOPICS)
    recorder.wait_for_line("dpos-record: recording", START_TIMEOUT_S)
    master = start_node("pos_master_node", "--ros-args", "-p", "scenario:=paper_sar", "-p", f"duration:={DURATION_S}",
                        "-p", "rate_factor:=0.0", "-p", "alignment:=reference", "-p", "min_subscribers:=1", "-p", "wait_subscribers_s:=30.0")
    try:
        assert recorder.wait(120.0) == 0, recorder.output
    finally:
        master.send_signal(signal.SIGINT)
    assert master.wait(STOP_TIMEOUT_S) == 0, master.output
    got = read_raw(out)
    expected = {s.topic: s for s in device_streams(load_sim_session("paper_sar", "", 1, DURATION_S), "master")}
    for topic in (T.SAR_FIX, T.BARO_PRESSURE):
        msgtype, _, raws = got[topic]
        assert msgtype == expected[topic].msgtype
        assert [bytes(r) for r in raws] == [expected[topic].message(i) for i in range(len(expected[topic]))], topic
    assert len(got[T.SAR_FIX][2]) == 30 and len(got[T.BARO_PRESSURE][2]) == 300
    assert dpos_sar([str(out), "--method", "ukf", "--out", str(tmp_path / "ukf")]) == 0
    rep = json.loads((tmp_path / "ukf" / "report.json").read_text())
    assert rep["epochs"] == 31 and rep["epochs_with_fix"] == 30 and rep["truth"]["epochs"] == 31
    assert rep["truth"]["mae"]["east_m"] < 10.0 and rep["truth"]["mae"]["north_m"] < 10.0
