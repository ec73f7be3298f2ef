"""dpos-process --master-reference: the main POS re-aligned in flight from the
recording's /master/imu + /gnss/* (forward, or RTS-smoothed) as the transfer alignment's reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_core.config import config_text
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli import process as process_cli
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io import bag
from dpos_ros.io.session import read_session
from dpos_ros.products.master_reference import accuracy, ifa_references


def _bag(path: Path, duration_s: float, drop: tuple[str, ...] = ()) -> Path:
    ss = SimulatedSession(load_scenario("paper_su"), 3, duration_s)
    streams = [s for s in session_streams(ss) if not (drop and s.topic.startswith(drop))]
    bag.write_streams(path, streams, custom_data=session_custom_data(ss, config_text("aircraft", "paper_su")))
    return path


def test_a_recording_without_gnss_is_refused_naming_it(tmp_path: Path, capsys) -> None:
    b = _bag(tmp_path / "no_gnss", 10.0, ("/gnss/",))
    code = process_cli.main([str(b), "--method", "ukf", "--master-reference", "smoothed", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == process_cli.EXIT_ERROR
    assert "/gnss/fix" in err and "/gnss/vel" in err and "--master-reference smoothed" in err, err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _bag(tmp_path_factory.mktemp("master_ref") / "su", 120.0)


def test_smoothed_reference_replaces_the_recorded_one(flight: Path) -> None:
    """The smoothed and forward references cover the recording at the main IMU rate with every field the
    transfer alignment needs; the smoothed one is closer to the truth (60-110 s of 120 s, paper_su seed 3,
    measured RMSE heading / pitch / roll: forward 0.57 / 0.0023 / 0.0023 deg, smoothed 0.30 / 0.0014 /
    0.0026: the heading still converging, the roll at the level of the forward one)."""
    sess = read_session(flight)
    from dpos_core.config import load_aircraft

    ac = load_aircraft("recording", text=sess.custom["dpos.aircraft_yaml"])
    refs = ifa_references(sess, ac)
    sm, fw = refs["smoothed"], refs["forward"]
    for r in (sm, fw):
        assert r.nav.omega_eb_b_radps is not None and r.nav.att_cov is not None and r.nav.vel_cov is not None and r.nav.pos_cov is not None
        assert abs(r.nav.t_s[-1] - sess.master.t_s[-1]) < 0.02
    truth = sess.truth["master"]
    a_s = accuracy(sm.nav, truth, 60.0, 110.0)
    a_f = accuracy(fw.nav, truth, 60.0, 110.0)
    assert a_s["hpr_deg"][0] < 0.7 * a_f["hpr_deg"][0] and a_s["hpr_deg"][1] < a_f["hpr_deg"][1], (a_s, a_f)
    assert a_s["hpr_deg"][2] < 1.5 * a_f["hpr_deg"][2], (a_s, a_f)
    assert np.linalg.norm(a_s["vel_mps"]) < np.linalg.norm(a_f["vel_mps"]), (a_s, a_f)


def test_dpos_process_with_the_smoothed_reference(flight: Path, tmp_path: Path, capsys) -> None:
    code = process_cli.main([str(flight), "--method", "ukf", "--workers", "1", "--master-reference", "smoothed", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code in (process_cli.EXIT_OK, process_cli.EXIT_NOT_ESTIMATED)
    assert "RTS-smoothed" in out and "main POS (smoothed) against /truth/master" in out, out
