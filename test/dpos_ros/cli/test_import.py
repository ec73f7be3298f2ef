"""dpos-import: the real walk_0827 recording into a bag shaped like real drivers' output, read back
with rosbags and compared with the log files themselves; the errors a user meets."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from repo_paths import REPO

from dpos_ros.cli import import_
from dpos_ros.contract import cdr
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.devices import relay
from dpos_ros.io import bag

WALK = REPO / "data" / "real" / "walk_0827"
IMU_CSV, TAG, POS = WALK / "imu_1730.csv", WALK / "imu_1730.csv.tag", WALK / "gnss_1730_sf.pos"
EXE = Path(sys.executable).parent / "dpos-import"
NS = 1_000_000_000
G0_MPS2 = 9.80665
OUTAGE_S = (60.0, 75.0)


def _argv(out: Path, *extra: str) -> list[str]:
    return ["--imu", str(IMU_CSV), "--tag", str(TAG), "--pos", str(POS), "--out", str(out), *extra]


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The console script on walk_0827 at 1 Hz with a 15 s outage: (bag directory, stdout)."""
    out = tmp_path_factory.mktemp("import") / "walk_0827_1hz"
    r = subprocess.run([str(EXE), *_argv(out, "--gnss-rate", "1", "--outage", f"{OUTAGE_S[0]:g}:{OUTAGE_S[1]:g}")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out, r.stdout


@pytest.fixture(scope="module")
def raw(imported: tuple[Path, str]) -> dict[str, tuple[str, list[int], list[bytes]]]:
    return bag.read_raw(imported[0])


@pytest.fixture(scope="module")
def csv_rows() -> np.ndarray:
    """The IMU CSV parsed here, independently of the reader: (N, 7) of the complete lines."""
    rows = [line.split(",") for line in IMU_CSV.read_text().splitlines()]
    return np.array([[float(x) for x in r] for r in rows if len(r) == 7])


@pytest.fixture(scope="module")
def pos_rows() -> dict[int, list[float]]:
    """The .pos solution lines parsed here: {GPST ns: the 22 numeric columns}."""
    import calendar

    out = {}
    for line in POS.read_text().splitlines():
        if line.startswith("%") or not line.strip():
            continue
        date, clock, *vals = line.split()
        y, mo, d = (int(x) for x in date.split("/"))
        hh, mm, ss = clock.split(":")
        sec, ms = ss.split(".")
        t_ns = calendar.timegm((y, mo, d, int(hh), int(mm), int(sec), 0, 0, 0)) * NS + int(ms) * 1_000_000
        out[t_ns] = [float(v) for v in vals]
    return out


def _report(out: Path) -> dict:
    return json.loads((out / import_.REPORT_NAME).read_text())


# ----------------------------------------------------------------------------- the bag


def test_bag_topics_counts_and_stamps(imported: tuple[Path, str], raw: dict) -> None:
    out, _ = imported
    assert {k: (v[0], len(v[1])) for k, v in raw.items()} == {
        "/imu/data": (T.IMU, 20455), "/fix": (T.NAVSATFIX, 134 - 15), "/vel": (T.TWIST_COV, 134 - 15)}
    assert (out / "metadata.yaml").is_file() and (out / f"{out.name}.mcap").is_file()
    assert "storage_identifier: mcap" in (out / "metadata.yaml").read_text()
    for topic, (_, t_log, blobs) in raw.items():
        t_hdr = np.array([cv.raw_stamp_ns(b) for b in blobs])
        np.testing.assert_array_equal(np.array(t_log), t_hdr, err_msg=f"{topic}: log time = header stamp")
        assert np.all(np.diff(t_hdr) > 0), topic
    assert not list(out.parent.glob(".*partial"))  # the temporary directory is gone


def test_imu_messages_equal_the_csv(raw: dict, csv_rows: np.ndarray) -> None:
    t_ns, vals = cdr.decode(cdr.layout("imu", "imu_link"), bag.rows(raw["/imu/data"][2]))
    blk = cv.imu_from_values(t_ns, vals)
    assert csv_rows.shape == (20455, 7)
    np.testing.assert_allclose(blk.f_mps2, csv_rows[:, 0:3] * G0_MPS2, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(blk.omega_radps, np.deg2rad(csv_rows[:, 3:6]), rtol=1e-14, atol=1e-18)
    # no orientation; the sensor covariances unknown (0)
    np.testing.assert_array_equal(vals[:, 4], -1.0)
    assert not np.any(vals[:, 5:13]) and not np.any(blk.gyro_var) and not np.any(blk.accel_var)
    # stamps: the counter [ms] scaled onto the tag, from the tag's start (GPST 2025-08-28 17:30:40.961)
    tag = TAG.read_bytes()
    start_ns = int.from_bytes(tag[64:68], "little") * NS + round(np.frombuffer(tag[68:76], "<f8")[0] * 1e9)
    assert t_ns[0] == start_ns == 1756402240961000000
    last_tick_ms = int.from_bytes(tag[-8:-4], "little")
    counter_s = (csv_rows[:, 6] - csv_rows[0, 6]) * 1e-3
    scale = last_tick_ms * 1e-3 / counter_s[-1]
    assert abs(scale - 1.0) < 1e-3
    np.testing.assert_allclose((t_ns - start_ns) * 1e-9, counter_s * scale, rtol=0, atol=1e-9)


def test_fixes_on_whole_gps_seconds_and_none_in_the_outage(raw: dict, pos_rows: dict[int, list[float]]) -> None:
    ts = bag.typestore()
    fixes = [ts.deserialize_cdr(b, T.NAVSATFIX) for b in raw["/fix"][2]]
    t_ns = np.array([f.header.stamp.sec * NS + f.header.stamp.nanosec for f in fixes])
    phase_ns = np.mod(t_ns, NS)
    assert np.all(np.minimum(phase_ns, NS - phase_ns) <= 1_000_000)  # the receiver's epochs are at x.999
    assert set(np.diff(t_ns)) == {NS, 16 * NS}  # one per second, one 16 s step over the outage
    t0_imu = raw["/imu/data"][1][0]
    rel_s = (t_ns - t0_imu) * 1e-9
    assert not np.any((rel_s >= OUTAGE_S[0]) & (rel_s < OUTAGE_S[1]))
    assert np.count_nonzero(rel_s < OUTAGE_S[0]) == 61 and np.count_nonzero(rel_s >= OUTAGE_S[1]) == 58  # -0.962 .. 59.038, 75.038 .. 132.038
    for f, t in zip(fixes, t_ns):
        lat, lon, h, q, _ns, sdn, sde, sdu = pos_rows[int(t)][:8]
        assert (f.latitude, f.longitude, f.altitude) == pytest.approx((lat, lon, h), abs=1e-9)
        assert f.header.frame_id == "gps"
        assert f.status.status == 2 and q in (1, 2)  # GBAS_FIX for RTK fix / float
        assert f.status.service == 1  # SERVICE_GPS
        assert f.position_covariance_type == 3  # COVARIANCE_TYPE_KNOWN
        cov = np.asarray(f.position_covariance).reshape(3, 3)
        np.testing.assert_allclose(np.diag(cov), [sde**2, sdn**2, sdu**2], rtol=1e-12)  # ENU order
        np.testing.assert_allclose(cov, cov.T)
    assert sorted({int(pos_rows[int(t)][3]) for t in t_ns}) == [1, 2]


def test_velocities_are_enu_with_their_covariance(raw: dict, pos_rows: dict[int, list[float]]) -> None:
    ts = bag.typestore()
    vels = [ts.deserialize_cdr(b, T.TWIST_COV) for b in raw["/vel"][2]]
    assert [v.header.stamp.sec * NS + v.header.stamp.nanosec for v in vels] == list(raw["/fix"][1])
    for v in vels:
        vals = pos_rows[v.header.stamp.sec * NS + v.header.stamp.nanosec]
        vn, ve, vu, sdvn, sdve, sdvu = vals[13:19]
        lin = v.twist.twist.linear
        assert (lin.x, lin.y, lin.z) == (pytest.approx(ve), pytest.approx(vn), pytest.approx(vu))
        cov = np.asarray(v.twist.covariance).reshape(6, 6)
        np.testing.assert_allclose(np.diag(cov)[:3], [sdve**2, sdvn**2, sdvu**2], rtol=1e-12)
        np.testing.assert_array_equal(np.diag(cov)[3:], -1.0)  # angular part unknown, as GNSS drivers publish
        assert v.header.frame_id == "gps"


def test_every_message_passes_the_device_relay_checks(raw: dict) -> None:
    """What pos_master_node ``device: ros`` (imu_in, fix_in, vel_in) would reject: nothing."""
    from geometry_msgs.msg import TwistWithCovarianceStamped
    from sensor_msgs.msg import Imu, NavSatFix

    for topic, kind, cls, step in (("/imu/data", "imu", Imu, 97), ("/fix", "fix", NavSatFix, 1), ("/vel", "vel", TwistWithCovarianceStamped, 1)):
        blobs = raw[topic][2]
        for b in blobs[::step] + blobs[-1:]:
            msg = deserialize_message(b, cls)
            assert relay._CHECKS[kind](msg) is None, (topic, msg)


def test_summary_and_report(imported: tuple[Path, str]) -> None:
    out, stdout = imported
    for text in ("20455 samples written to /imu/data", "lines skipped: 2", "line 1: 6 field(s), 7 needed (cut line)",
                 "line 20457: 6 field(s), 7 needed (cut line)", "repeated samples (all six values equal the previous; kept): 6958",
                 "clock scale 1.000142", "intervals: median 6.001 ms, min 6.001 ms, max 9.001 ms",
                 "GPST 2025-08-28 17:30:40.961 .. 2025-08-28 17:32:55.232 (134.271 s",
                 "536 fixes read (0 lines skipped): Q1 (fix) 349, Q2 (float) 187", "--gnss-rate 1 Hz: 134 kept, 402 removed",
                 "15 by outage ([60, 75) s)", "119 fixes written", "first fix - first IMU sample: -0.962 s"):
        assert text in stdout, f"{text!r} not in:\n{stdout}"
    rep = _report(out)
    assert rep["imu"]["samples_written"] == 20455 and rep["imu"]["repeated_samples"] == 6958
    assert rep["imu"]["lines_skipped"]["count"] == 2 and [e["line"] for e in rep["imu"]["lines_skipped"]["first"]] == [1, 20457]
    assert abs(rep["imu"]["clock_scale"] - 1.0) < 1e-3
    g = rep["gnss"]
    assert (g["fixes_read"], g["kept_after_rate"], g["removed_by_outage"], g["removed_by_quality"], g["removed_by_crop"], g["fixes_written"]) \
        == (536, 134, 15, 0, 0, 119)
    assert g["q_histogram_read"] == {"1": 349, "2": 187}
    assert sum(g["q_histogram_written"].values()) == 119
    assert g["grid_offset_ms"] == {"min": -1.0, "max": -1.0}
    assert rep["first_imu_to_first_fix_s"] == pytest.approx(-0.962)
    assert rep["topics"]["/fix"] == {"type": T.NAVSATFIX, "messages": 119}


# ----------------------------------------------------------------------------- options


def test_quality_crop_topics_and_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "float_cut"
    rc = import_.main(_argv(out, "--min-quality", "1", "--start", "10", "--end", "70.5", "--imu-topic", "/vn100/imu",
                            "--fix-topic", "/ublox/fix", "--vel-topic", "/ublox/fix_velocity", "--imu-frame", "vn100", "--gnss-frame", "antenna",
                            "--gyro-sigma-radps", "0.001", "--accel-sigma-mps2", "0.02"))
    assert rc == 0, capsys.readouterr().err
    raw = bag.read_raw(out)
    assert set(raw) == {"/vn100/imu", "/ublox/fix", "/ublox/fix_velocity"}
    t_imu = np.array(raw["/vn100/imu"][1])
    rep = _report(out)
    origin = 1756402240961000000  # the crop's origin: the first IMU sample of the log
    assert origin + 10 * NS <= t_imu[0] < origin + 10_010_000_000 and origin + 70_490_000_000 < t_imu[-1] <= origin + 70_500_000_000
    assert rep["imu"]["span"]["first_ns"] == t_imu[0]
    assert rep["imu"]["removed_by_crop"] == 20455 - len(t_imu) > 0
    _, vals = cdr.decode(cdr.layout("imu", "vn100"), bag.rows(raw["/vn100/imu"][2]))
    np.testing.assert_allclose(vals[:, [16, 20, 24]], 1e-6)
    np.testing.assert_allclose(vals[:, [28, 32, 36]], 4e-4)
    ts = bag.typestore()
    fixes = [ts.deserialize_cdr(b, T.NAVSATFIX) for b in raw["/ublox/fix"][2]]
    assert {f.header.frame_id for f in fixes} == {"antenna"}
    g = rep["gnss"]
    assert g["removed_by_quality"] > 0 and g["removed_by_crop"] > 0 and g["q_histogram_written"].keys() == {"1"}
    assert g["fixes_written"] == len(fixes) == 536 - g["removed_by_quality"] - g["removed_by_crop"]
    t_fix = np.array(raw["/ublox/fix"][1])
    assert t_fix[0] >= origin + 10 * NS and t_fix[-1] <= origin + 70_500_000_000


def test_imu_only_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "imu_only"
    assert import_.main(["--imu", str(IMU_CSV), "--tag", str(TAG), "--out", str(out)]) == 0
    assert "GNSS  none (no --pos)" in capsys.readouterr().out
    raw = bag.read_raw(out)
    assert list(raw) == ["/imu/data"] and len(raw["/imu/data"][1]) == 20455


# ----------------------------------------------------------------------------- errors


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run main; expect status 2 and exactly one stderr line, returned."""
    try:
        rc = import_.main(argv)
    except SystemExit as e:  # argparse's own errors
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dpos-import: error: "), err
    return lines[0]


def test_bad_options_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x"
    assert "--outage: '5:3': END must be after START" in _error(capsys, _argv(out, "--outage", "5:3"))
    assert "--outage: expected START:END" in _error(capsys, _argv(out, "--outage", "60"))
    assert "--accel-unit: invalid choice: 'ft_s2'" in _error(capsys, _argv(out, "--accel-unit", "ft_s2"))
    assert "--gyro-cols: expected three column indices" in _error(capsys, _argv(out, "--gyro-cols", "3,4"))
    assert "--end 5 must be after --start 10" in _error(capsys, _argv(out, "--start", "10", "--end", "5"))
    assert "--gnss-rate need --pos" in _error(capsys, ["--imu", str(IMU_CSV), "--tag", str(TAG), "--gnss-rate", "1", "--out", str(out)])
    assert "give --tag (RTKLIB time tag of the log) or --time-col" in _error(capsys, ["--imu", str(IMU_CSV), "--out", str(out)])
    assert "IMU columns must be distinct" in _error(capsys, _argv(out, "--gyro-cols", "2,3,4"))
    assert not out.exists()


def test_unreadable_logs_are_one_line_errors_and_leave_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x"
    assert _error(capsys, _argv(out)[:4] + ["--pos", str(tmp_path / "none.pos"), "--out", str(out)]).endswith(f"--pos {tmp_path / 'none.pos'}: no such file")
    ecef = tmp_path / "ecef.pos"
    ecef.write_text("%  GPST   x-ecef(m)   y-ecef(m)   z-ecef(m)   Q  ns\n")
    assert f"{ecef}: ECEF / baseline solutions are not supported" in _error(capsys, _argv(out)[:4] + ["--pos", str(ecef), "--out", str(out)])
    assert f"{POS}: not an RTKLIB time tag" in _error(capsys, ["--imu", str(IMU_CSV), "--tag", str(POS), "--out", str(out)])
    msg = _error(capsys, _argv(out, "--counter-unit-s", "0.002"))
    assert f"{IMU_CSV}: the IMU counter spans 268.504 s but the tag 134.271 s" in msg
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["ecef.pos"]


def test_existing_out_needs_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bag"
    imu_only = ["--imu", str(IMU_CSV), "--tag", str(TAG), "--out", str(out)]
    assert import_.main(imu_only) == 0
    first = (out / "metadata.yaml").read_text()
    assert f"--out {out} exists (pass --overwrite to replace it)" in _error(capsys, imu_only)
    assert (out / "metadata.yaml").read_text() == first
    assert import_.main(_argv(out, "--gnss-rate", "1", "--overwrite")) == 0
    assert set(bag.read_raw(out)) == {"/imu/data", "/fix", "/vel"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    # --overwrite replaces a bag, never another directory
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert "is not a rosbag2 directory: not replacing it" in _error(capsys, imu_only[:-1] + [str(other), "--overwrite"])
    assert (other / "keep.txt").read_text() == "mine"


def test_a_failed_write_leaves_nothing_behind(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    def write_then_fail(path: Path, streams: list, **kw: object) -> int:
        """bag.write_streams that writes part of the bag, then fails as a full disk does."""
        bag.write_streams(path, streams[:1], **kw)
        raise OSError(28, "No space left on device", str(path / "x.mcap"))

    monkeypatch.setattr(import_, "write_streams", write_then_fail)
    out = tmp_path / "full"
    assert "x.mcap: No space left on device" in _error(capsys, _argv(out))
    assert list(tmp_path.iterdir()) == []


def test_console_script_error_has_no_traceback(tmp_path: Path) -> None:
    r = subprocess.run([str(EXE), "--imu", str(tmp_path / "missing.csv"), "--tag", str(TAG), "--out", str(tmp_path / "x")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr == f"dpos-import: error: --imu {tmp_path / 'missing.csv'}: no such file\n"
    assert "usage:" in subprocess.run([str(EXE), "--help"], capture_output=True, text=True, timeout=60).stdout
