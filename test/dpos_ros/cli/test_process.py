"""dpos-process: the offline transfer alignment of a recording and its products."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dpos_core.config import config_text
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.devices.sim_streams import TopicStream, session_custom_data, session_streams
from dpos_ros.io import bag

EXE = Path(sys.executable).parent


def _sim_bag(path: Path, duration: float = 450.0, mutate=None) -> Path:
    ss = SimulatedSession(load_scenario("paper_su"), 2, duration)
    streams = session_streams(ss)
    if mutate is not None:
        streams = mutate(streams)
    bag.write_streams(path, streams, custom_data=session_custom_data(ss, config_text("aircraft", "paper_su")))
    return path


@pytest.fixture(scope="module")
def products(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("proc")
    b = _sim_bag(d / "bag")
    # the default method: [Gong2018]'s unscented particle smoother (100 particles)
    r = subprocess.run([str(EXE / "dpos-process"), str(b), "--initial-attitude-error", "40", "--figures", "on", "--out", str(d / "out")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return d / "out" / "paper_su_seed2"


def test_products_are_written(products: Path) -> None:
    for f in ("ant_r.csv", "metrics.json", "report.md", "status.json", "errors_ant_r.png"):
        assert (products / f).is_file(), f
    rows = list(csv.DictReader(ln for ln in (products / "ant_r.csv").open() if not ln.startswith('#')))
    assert len(rows) == 45000 and float(rows[1]["stamp_s"]) - float(rows[0]["stamp_s"]) == pytest.approx(0.01)
    assert 39.0 < float(rows[-1]["lat_deg"]) < 41.0 and float(rows[-1]["sigma_heading_deg"]) > 0.0
    raw = bag.read_raw(products / "antennas")
    assert set(raw) == {"/antenna/ant_r/odom", "/antenna/ant_r/fix", "/dpos/datum"} and len(raw["/antenna/ant_r/odom"][2]) == 45000


def test_antenna_bag_has_navsatfix_the_datum_and_its_qos_and_a_geojson_track(products: Path) -> None:
    """What a surveyor and a ROS user load directly: /antenna/<name>/fix (NavSatFix, WGS-84 degrees,
    ellipsoidal height, the CSV's sigmas as an ENU diagonal covariance) row for row with the CSV,
    the datum latched once (its stored QoS TRANSIENT_LOCAL, as ros2 bag play reads it), the MCAP
    header naming dpos, and tracks.geojson (RFC 7946) one point per second."""
    from importlib.metadata import version

    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability

    csv_rows = np.loadtxt(products / "ant_r.csv", delimiter=",", skiprows=2, max_rows=3000)
    header = (products / "ant_r.csv").read_text().splitlines()[1].split(",")
    col = {name: k for k, name in enumerate(header)}
    with AnyReader([products / "antennas"]) as r:
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in r.connections}
        fixes, datums = [], []
        for c, t, data in r.messages():
            if c.topic == "/antenna/ant_r/fix" and len(fixes) < 3000:
                fixes.append((t, r.deserialize(data, c.msgtype)))
            elif c.topic == "/dpos/datum":
                datums.append(r.deserialize(data, c.msgtype))
    assert qos["/dpos/datum"].durability == QosDurability.TRANSIENT_LOCAL and qos["/antenna/ant_r/fix"].durability == QosDurability.VOLATILE
    assert len(datums) == 1 and datums[0].header.frame_id == "enu"
    t_fix = np.array([t for t, _ in fixes]) * 1e-9
    lat = np.array([m.latitude for _, m in fixes])
    cov = np.array([m.position_covariance for _, m in fixes])
    np.testing.assert_allclose(t_fix, csv_rows[:, col["stamp_s"]], rtol=0, atol=1e-6)
    np.testing.assert_allclose(lat, csv_rows[:, col["lat_deg"]], rtol=0, atol=1e-9)  # (the CSV's 10 decimals)
    np.testing.assert_allclose(np.sqrt(cov[:, 4]), csv_rows[:, col["sigma_north_m"]], rtol=1e-4, atol=0)  # north (the CSV: 4 decimals of an exponent)
    np.testing.assert_allclose(np.sqrt(cov[:, 0]), csv_rows[:, col["sigma_east_m"]], rtol=1e-4, atol=0)  # east
    assert all(m.header.frame_id == "antenna_ant_r" and m.position_covariance_type == 2 for _, m in fixes[:10])
    # the CSV's time in a surveyor's scales: GPS week + seconds of week, UTC (the leap seconds of the date)
    from dpos_core.imports.timescales import GPS_EPOCH_UNIX_S, gps_minus_utc_s

    t = csv_rows[:, col["stamp_s"]]
    np.testing.assert_allclose(csv_rows[:, col["gps_week"]] * 604800 + csv_rows[:, col["gps_sow_s"]], t - GPS_EPOCH_UNIX_S, rtol=0, atol=1e-6)
    leap = int(gps_minus_utc_s(np.int64(int(t[0]) * 1_000_000_000)))
    assert 17 <= leap <= 18
    np.testing.assert_allclose(csv_rows[:, col["utc_unix_s"]], t - leap, rtol=0, atol=2e-6)
    with (products / "antennas" / "antennas.mcap").open("rb") as f:
        assert make_reader(f).get_header().library == f"dpos_ros-{version('dpos_ros')}"
    doc = json.loads((products / "tracks.geojson").read_text())
    (feat,) = doc["features"]
    assert feat["properties"]["antenna"] == "ant_r" and feat["geometry"]["type"] == "LineString"
    assert len(feat["geometry"]["coordinates"]) == 450  # 450 s, one point a second
    lon0, lat0, h0 = feat["geometry"]["coordinates"][0]
    assert lat0 == pytest.approx(csv_rows[0, col["lat_deg"]], abs=1e-9) and lon0 == pytest.approx(csv_rows[0, col["lon_deg"]], abs=1e-9)


def test_metrics_schema_and_accuracy(products: Path) -> None:
    """450 s of paper_su (its first 50 s of imaging segment AB) from 40 deg initial errors: the
    smoothed antenna is within 0.01 deg, 5 mm/s and 5 cm RMS on AB (the seed's UPS column
    reports 0.5 deg, 0.02 m/s and 1 m for its full flight)."""
    m = json.loads((products / "metrics.json").read_text())
    assert m["scenario"] == "paper_su" and m["runs"] == 1 and m["segments"] == ["AB"]
    mean = m["methods"]["ups"]["mean"]
    assert set(mean) == {"rmse", "std"} and set(mean["rmse"]) == {"heading_deg", "pitch_deg", "roll_deg", "vel_e_mps", "vel_n_mps", "vel_u_mps", "lat_m", "lon_m", "h_m", "baseline_m"}
    r = mean["rmse"]
    assert max(r["heading_deg"], r["pitch_deg"], r["roll_deg"]) < 0.01
    assert max(r["vel_e_mps"], r["vel_n_mps"], r["vel_u_mps"]) < 0.005
    assert max(r["lat_m"], r["lon_m"], r["h_m"], r["baseline_m"]) < 0.05
    t = m["methods"]["ups"]["timing"]
    assert t["data_s"] == pytest.approx(450.0, abs=0.1) and t["processing_s"] > 0
    assert "| Attitude error | Heading (°)" in (products / "report.md").read_text()


def test_bad_recordings(tmp_path: Path) -> None:
    def shuffle_and_break(streams: list[TopicStream]) -> list[TopicStream]:
        out = []
        for s in streams:
            if s.topic == "/sub_imu/sub_r/imu":
                rows = s.rows.copy()
                t = s.t_ns.copy()
                rows[[100, 101]] = rows[[101, 100]]  # recorded out of stamp order (log times stay ordered)
                t = np.insert(t, 500, t[500])  # duplicate
                rows = np.insert(rows, 500, rows[500], axis=0)
                # linear_acceleration.x of sample 900 (double 25 of 37) := NaN
                rows[900, rows.shape[1] - 8 * 12 : rows.shape[1] - 8 * 11] = np.frombuffer(np.array([np.nan]).tobytes(), dtype=np.uint8)
                s = TopicStream(s.topic, s.msgtype, t, rows=rows)
            out.append(s)
        return out

    b = _sim_bag(tmp_path / "bad", 60.0, shuffle_and_break)
    r = subprocess.run([str(EXE / "dpos-process"), str(b), "--method", "ukf", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "out of stamp order" in r.stderr and "duplicate stamp" in r.stderr and "NaN" in r.stderr
    assert json.loads((tmp_path / "o" / "paper_su_seed2" / "status.json").read_text())["antennas"]["ant_r"] == "estimated"
    b2 = _sim_bag(tmp_path / "nonav", 20.0, lambda st: [s for s in st if s.topic != "/master/nav"])
    r = subprocess.run([str(EXE / "dpos-process"), str(b2), "--out", str(tmp_path / "o2")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "no /master/nav" in r.stderr
    r = subprocess.run([str(EXE / "dpos-process"), str(tmp_path / "missing"), "--out", str(tmp_path / "o3")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "not a rosbag2 directory" in r.stderr and "nor a dpos spill" in r.stderr


def test_output_and_filter_rates(tmp_path: Path) -> None:
    b = _sim_bag(tmp_path / "bag", 30.0)
    r = subprocess.run([str(EXE / "dpos-process"), str(b), "--method", "ukf", "--filter-rate", "2", "--output-rate", "10",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rows = np.loadtxt(tmp_path / "o" / "paper_su_seed2" / "ant_r.csv", delimiter=",", skiprows=2)
    # the first pose (t = 0.01 s) opens the first 0.1 s interval, then one per interval up to 30 s
    assert rows.shape[0] == 301 and np.allclose(np.diff(rows[1:, 0]), 0.1, atol=1e-6)
