"""dpos-sim bags: every design topic, readable by rosbags and by the mcap reader, and they read
back to the simulated values."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_inprocess import run_main  # test/support/cli_inprocess.py
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import NavSatFix
from std_msgs.msg import Header

from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli.sim import main as sim_main
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.io import bag

DURATION_S = 20.0


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "paper_su_pair"
    exe = Path(sys.executable).parent / "dpos-sim"
    r = subprocess.run([str(exe), "--scenario", "paper_su", "--aircraft", "paper_su_pair", "--seed", "4",
                        "--duration", str(DURATION_S), "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "paper_su_seed4" in r.stdout
    return out


@pytest.fixture(scope="module")
def session() -> SimulatedSession:
    return SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 4, DURATION_S)


def test_bag_has_every_design_topic(sim_bag: Path) -> None:
    raw = bag.read_raw(sim_bag)
    expected = {
        "/dpos/datum": 1, "/master/imu": 2000, "/gnss/fix": 20, "/gnss/vel": 20, "/master/nav": 2001,
        "/session/end": 1, "/sub_imu/sub_r/imu": 2000, "/sub_imu/sub_l/imu": 2000,
        "/truth/master": 2001, "/truth/sub_imu/sub_r": 2001, "/truth/sub_imu/sub_l": 2001,
        "/truth/antenna/ant_r": 2001, "/truth/antenna/ant_l": 2001,
    }
    assert {k: len(v[1]) for k, v in raw.items()} == expected
    assert raw["/master/imu"][0] == "sensor_msgs/msg/Imu" and raw["/master/nav"][0] == "nav_msgs/msg/Odometry"
    # log time = header stamp, time-ordered
    t_log = np.array(raw["/master/imu"][1])
    t_hdr, _ = cdr.decode(cdr.layout("imu", "master_imu"), bag.rows(raw["/master/imu"][2]))
    np.testing.assert_array_equal(t_log, t_hdr)
    assert np.all(np.diff(t_log) == 10_000_000)


def test_bag_reads_back_to_the_simulated_values(sim_bag: Path, session: SimulatedSession) -> None:
    raw = bag.read_raw(sim_bag)
    t0_ns = int(round(session.scenario.start_time_s * 1e9))
    # sub-IMU samples
    imu = session.sub_imu("sub_l")
    t_ns, vals = cdr.decode(cdr.layout("imu", "sub_imu_sub_l"), bag.rows(raw["/sub_imu/sub_l/imu"][2]))
    blk = cv.imu_from_values(t_ns, vals)
    np.testing.assert_array_equal(blk.omega_radps, imu.omega_radps)
    np.testing.assert_array_equal(blk.f_mps2, imu.f_mps2)
    np.testing.assert_array_equal((t_ns - t0_ns), np.round(imu.t_s * 1e9).astype(np.int64))
    # antenna truth through the datum frame and back
    tr = session.truth("antenna/ant_r")
    t_ns, vals = cdr.decode(cdr.layout("odometry", "enu", "antenna_ant_r"), bag.rows(raw["/truth/antenna/ant_r"][2]))
    od = cv.odometry_from_values(t_ns, vals, session.datum_llh)
    np.testing.assert_allclose(od.llh[:, :2], tr.llh[:, :2], atol=1e-14)
    np.testing.assert_allclose(od.llh[:, 2], tr.llh[:, 2], atol=1e-7)
    np.testing.assert_allclose(od.vel_n_mps, tr.vel_n_mps, atol=1e-10)
    np.testing.assert_allclose(np.abs(np.sum(od.q_nb * tr.q_nb, axis=1)), 1.0, atol=1e-14)
    # GNSS, datum and the end of the session
    g = session.gnss()
    fixes = [deserialize_message(b, NavSatFix) for b in raw["/gnss/fix"][2]]
    np.testing.assert_allclose([f.latitude for f in fixes], np.rad2deg(g.llh[:, 0]), rtol=0, atol=1e-12)
    assert fixes[0].position_covariance[8] == pytest.approx(0.1**2)
    datum = deserialize_message(raw["/dpos/datum"][2][0], NavSatFix)
    np.testing.assert_allclose(cv.datum_from_msg(datum), session.datum_llh, atol=1e-15)
    end = deserialize_message(raw["/session/end"][2][0], Header)
    assert end.frame_id == "paper_su_seed4"
    assert end.stamp.sec * 10**9 + end.stamp.nanosec == max(max(v[1]) for v in raw.values())


def test_bag_is_readable_by_the_mcap_reader(sim_bag: Path) -> None:
    from mcap.reader import make_reader

    files = list(sim_bag.glob("*.mcap"))
    assert len(files) == 1
    with files[0].open("rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert {c.topic for c in summary.channels.values()} >= {"/master/imu", "/master/nav", "/sub_imu/sub_r/imu"}
        n = sum(1 for _ in r.iter_messages(topics=["/sub_imu/sub_r/imu"]))
    assert n == 2000


def test_dpos_sim_rejects_bad_arguments(tmp_path: Path) -> None:
    exe = str(Path(sys.executable).parent / "dpos-sim")
    r = subprocess.run([exe, "--scenario", "nope", "--out", str(tmp_path / "a")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "unknown scenario 'nope'" in r.stderr
    r = subprocess.run([exe, "--scenario", "paper_su", "--duration", "5000", "--out", str(tmp_path / "b")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "exceeds" in r.stderr
    (tmp_path / "c").mkdir()
    r = subprocess.run([exe, "--scenario", "paper_su", "--out", str(tmp_path / "c")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "exists" in r.stderr


@pytest.mark.parametrize(("args", "needle"), [
    (["--datum", "95", "200", "0"], "--datum: latitude must be in [-90, 90] deg, got 95"),
    (["--datum", "-91", "0", "0"], "--datum: latitude must be in [-90, 90] deg"),
    (["--datum", "40", "200", "0"], "--datum: longitude must be in [-180, 180] deg, got 200"),
    (["--datum", "40", "116", "nan"], "--datum: height must be a finite number of metres"),
    (["--datum", "40", "116", "inf"], "--datum: height must be a finite number of metres"),
    (["--duration", "0"], "--duration must be > 0"),
    (["--duration", "-5"], "--duration must be > 0"),
    (["--duration", "nan"], "--duration must be > 0"),
])
def test_dpos_sim_rejects_bad_datum_and_duration(tmp_path: Path, args: list[str], needle: str) -> None:
    """An impossible datum or duration is a usage error before anything is simulated (dpos-sim's
    main in-process; its console script's usage errors in test_dpos_sim_rejects_bad_arguments)."""
    out = tmp_path / "bag"
    r = run_main(sim_main, ["--scenario", "paper_su", *args, "--out", str(out)])
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not out.exists()
