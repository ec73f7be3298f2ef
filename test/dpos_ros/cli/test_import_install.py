"""dpos-import --nav: a simulated installation (a navigation-solution CSV in UTC date-times and a
sub-IMU counter log at a known clock offset and mounting) -> one recording, read back; the errors
a user meets (no manoeuvre: exit 2, one line naming the log)."""

from __future__ import annotations

import datetime as dt
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from dpos_core.attitude import dcm_to_rotvec, quat_to_dcm
from dpos_core.frames import hpr_from_C_nb
from dpos_core.imports.mounting import MountingEstimate
from dpos_core.imports.timescales import utc_to_gpst_ns
from dpos_core.units import DEG
from dpos_ros.cli import import_
from dpos_ros.cli import import_install as install
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.session import read_session
from dpos_ros.io.streams import TopicStream

_spec = importlib.util.spec_from_file_location("install_sim", Path(__file__).parents[2] / "dpos_core" / "imports" / "install_sim.py")
assert _spec is not None and _spec.loader is not None
sim = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sim)

NS = 1_000_000_000
MOUNT = (1.5, -2.0, 30.0)
OFFSET_S = 12.3456  # the sub-IMU's first sample, after the first solution
START_UTC = dt.datetime(2016, 12, 20, 10, 0, 0, tzinfo=dt.UTC)  # GPS - UTC = 17 s then
LLH0 = (np.deg2rad(48.1), np.deg2rad(11.5), 520.0)


def _write_nav(path: Path, manoeuvre: bool = True, duration_s: float = 80.0) -> np.ndarray:
    """time (UTC date-time), lat, lon [deg], h, vN, vE, vD, roll, pitch, heading [deg]; returns t [s]."""
    t = np.arange(0.0, duration_s, 0.1)
    a = sim.hpr(t, manoeuvre)
    lines = ["time,lat,lon,h,vn,ve,vd,roll,pitch,heading"]
    for i, ti in enumerate(t):
        stamp = (START_UTC + dt.timedelta(seconds=float(ti))).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
        lat = np.rad2deg(LLH0[0]) + 1e-6 * ti
        lines.append(f"{stamp},{lat:.9f},{np.rad2deg(LLH0[1]):.9f},{LLH0[2]:.3f},10.0,0.0,0.0,"
                     f"{a[i, 2] / DEG:.6f},{a[i, 1] / DEG:.6f},{np.mod(a[i, 0] / DEG, 360):.6f}")
    lines.insert(5, "2016-12-20 10:00:00.3,cut")
    path.write_text("\n".join(lines) + "\n")
    return t


def _write_sub(path: Path, manoeuvre: bool = True, duration_s: float = 50.0) -> None:
    """counter [us], gyro x, y, z [deg/s], accel x, y, z [m/s^2] at 100 Hz, from OFFSET_S into the solution."""
    dt_s = 0.01
    t_dev = np.arange(0.0, duration_s, dt_s)
    w = sim.sub_rates(OFFSET_S + t_dev, dt_s, MOUNT, manoeuvre, bias_dps=(0.4, 0.0, -0.2), noise_dps=0.3)
    cnt = 5_000_000 + np.round(t_dev * 1e6).astype(np.int64)
    rows = ["counter,gx,gy,gz,ax,ay,az"] + [f"{cnt[i]},{w[i, 0] / DEG:.5f},{w[i, 1] / DEG:.5f},{w[i, 2] / DEG:.5f},0.1,0.2,9.8"
                                            for i in range(t_dev.size)]
    path.write_text("\n".join(rows) + "\n")


def _argv(nav: Path, sub: Path, out: Path, *extra: str) -> list[str]:
    return ["--nav", str(nav), "--nav-time-form", "datetime", "--nav-time-scale", "utc",
            "--nav-llh-cols", "1,2,3", "--nav-vel-cols", "4,5,6", "--nav-att-cols", "7,8,9",
            "--sub", f"left={sub}", "--sub-options", "left=--counter-col 0 --counter-unit-s 1e-6 --gyro-cols 1,2,3 --accel-cols 4,5,6 "
            "--accel-unit mps2", "--out", str(out), *extra]


@pytest.fixture(scope="module")
def installation(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    d = tmp_path_factory.mktemp("install")
    _write_nav(d / "nav.csv")
    _write_sub(d / "left.csv")
    (d / "aircraft.yaml").write_text(yaml.safe_dump({
        "name": "test_wing", "gnss_lever_arm_m": [0, 0, 1.0], "flexure": {"tau_s": [5, 2, 2], "variance_deg2": [0.01, 0.01, 0.01]},
        "sub_imus": [{"name": "left", "span_m": -3.0, "lever_arm_m": [0.0, 3.0, 0.0], "mount_rpy_deg": "estimate"}],
        "antennas": [{"name": "left", "span_m": -3.0, "sub_imu": "left", "lever_arm_m": [0, 0, 0]}]}))
    return d / "nav.csv", d / "left.csv", d / "aircraft.yaml"


def test_installation_recording(installation: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nav, sub, aircraft = installation
    out = tmp_path / "flight"
    assert import_.main(_argv(nav, sub, out, "--aircraft", str(aircraft))) == 0
    text = capsys.readouterr().out
    assert "clock: counter only: offset estimated from the angular rates" in text
    assert "position sigma: option --nav-pos-sigma-m 0.1 (not in the file)" in text
    rep = json.loads((out / "import_report.json").read_text())
    # the cut line is named
    assert rep["nav"]["lines_skipped"] == 2 and rep["nav"]["skipped_first"][1]["line"] == 6
    c = rep["subs"]["left"]["clock"]
    assert abs(c["offset_s"] - OFFSET_S) < max(3e-3 * c["offset_sigma_ms"], 2e-3), c  # GPST - device time, relative to the first solution
    m = rep["subs"]["left"]["mounting"]
    err = np.asarray(m["rpy_deg"]) - MOUNT
    assert np.all(np.abs(err) < 3 * np.asarray(m["rpy_sigma_deg"]) + 0.02), m
    assert rep["aircraft"]["mountings_from_estimate"] == ["left"]
    # its sigma beside it: the estimate's and the solution's attitude sigma (--nav-att-sigma-deg 0.1) root sum square
    ms = rep["aircraft"]["mount_sigma_deg"]["left"]
    assert np.hypot(max(m["rpy_sigma_deg"]), 0.1) - 2e-3 < ms < np.hypot(2 * max(m["rpy_sigma_deg"]), 0.1) + 2e-3, (ms, m)
    assert f"left (mount_sigma_deg {ms:g})" in text
    # the recording, as dpos-process reads it
    sess = read_session(out)
    assert sess.custom["dpos.master_source"] == "solution"  # dpos-process: "an imported navigation solution"
    ac = yaml.safe_load(sess.custom["dpos.aircraft_yaml"])
    np.testing.assert_allclose(ac["sub_imus"][0]["mount_rpy_deg"], m["rpy_deg"], atol=1e-3)
    assert ac["sub_imus"][0]["lever_arm_m"] == [0.0, 3.0, 0.0]
    assert ac["sub_imus"][0]["mount_sigma_deg"] == ms
    assert set(sess.sub_imus) == {"left"}
    # the sub-IMU on GPS time: its first sample OFFSET_S after the first solution (to the clock's sigma)
    first_sub_s = sess.sub_imus["left"].t_s[0] - sess.master.t_s[0]
    assert abs(first_sub_s - OFFSET_S) < max(3e-3 * c["offset_sigma_ms"], 2e-3)
    # /master/nav: stamps GPST = UTC + 17 s (December 2016: the table, not today's 18 s)
    t0_gpst = int(utc_to_gpst_ns(np.int64(int(START_UTC.timestamp()) * NS)))
    assert t0_gpst - int(START_UTC.timestamp()) * NS == 17 * NS
    assert sess.t0_ns == t0_gpst
    assert rep["nav"]["first_ns"] == t0_gpst


def test_no_manoeuvre_exit_2_one_line(installation: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nav = tmp_path / "level.csv"
    sub = tmp_path / "still.csv"
    _write_nav(nav, manoeuvre=False)
    _write_sub(sub, manoeuvre=False)
    out = tmp_path / "flight"
    assert import_.main(_argv(nav, sub, out)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"dpos-import: error: --sub left ({sub}): clock offset not observable: no manoeuvre")
    assert not out.exists()


def test_option_errors(installation: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    nav, sub, _ = installation
    for argv, msg in [
        (["--nav", str(nav), "--out", str(tmp_path / "o")], "--nav needs at least one --sub"),
        (["--nav", str(nav), "--imu", str(sub), "--sub", f"a={sub}", "--out", str(tmp_path / "o")], "give --imu"),
        (["--nav", str(nav), "--sub", f"a={sub}", "--sub-options", "b=--skip-header 1", "--out", str(tmp_path / "o")], "--sub-options 'b=--skip-header 1'"),
        (["--nav", str(nav), "--sub", f"a={sub}", "--sub-options", "a=--nav-time-col 3", "--out", str(tmp_path / "o")], "not an IMU CSV layout option"),
        (["--nav", str(nav), "--sub", f"a-b={sub}", "--out", str(tmp_path / "o")], "NAME must be letters"),
    ]:
        with pytest.raises(SystemExit) as e:
            import_.main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and msg in err, (argv, err)


def test_datum_and_master_nav_messages(installation: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """/dpos/datum is the first solution point; /master/nav decodes back to the file's attitude,
    velocity and the option sigmas; its body rate is the attitude's."""
    nav, sub, _ = installation
    out = tmp_path / "flight"
    assert import_.main(_argv(nav, sub, out, "--nav-att-sigma-deg", "0.2")) == 0
    sess = read_session(out)
    np.testing.assert_allclose(sess.datum_llh[:2], LLH0[:2], atol=1e-9)
    m = sess.master
    np.testing.assert_allclose(m.vel_n_mps[:, 1], 10.0, atol=1e-6)  # north
    np.testing.assert_allclose(m.vel_n_mps[:, [0, 2]], 0.0, atol=1e-6)
    a = sim.hpr(m.t_s - m.t_s[0])
    hpr = hpr_from_C_nb(quat_to_dcm(m.q_nb))
    np.testing.assert_allclose(np.unwrap(hpr[:, 0]), np.unwrap(np.mod(a[:, 0], 2 * np.pi)), atol=1e-6)
    np.testing.assert_allclose(hpr[:, 1:], a[:, 1:], atol=1e-6)
    assert m.att_cov is not None
    np.testing.assert_allclose(np.trace(m.att_cov, axis1=1, axis2=2), 3 * (0.2 * DEG) ** 2, rtol=1e-6)
    assert m.omega_eb_b_radps is not None
    i = 100
    w_true = dcm_to_rotvec(quat_to_dcm(m.q_nb[i - 1]).T @ quat_to_dcm(m.q_nb[i + 1])) / (m.t_s[i + 1] - m.t_s[i - 1])
    np.testing.assert_allclose(m.omega_eb_b_radps[i], w_true, atol=2e-3)


def test_datum_bytes_equal_the_contract_message() -> None:
    """The import's /dpos/datum (rosbags, no rclpy) is byte for byte conversions.datum_msg's."""
    from rclpy.serialization import serialize_message

    llh = np.array([np.deg2rad(32.8256345), np.deg2rad(34.955858), 12.494])
    t = 1_657_181_443_100_000_000
    mine = TopicStream(T.DATUM, T.NAVSATFIX, np.array([t]), blobs=(cv.datum_blob(t, llh),))
    ref = TopicStream(T.DATUM, T.NAVSATFIX, np.array([t]), blobs=(serialize_message(cv.datum_msg(t, llh)),))
    assert mine.message(0) == ref.message(0)


def test_aircraft_estimate_needs_the_import(installation: tuple[Path, Path, Path]) -> None:
    """'mount_rpy_deg: estimate' read directly (dpos-process --aircraft) says where it is resolved."""
    from dpos_core.config import ConfigError, load_aircraft

    _, _, aircraft = installation
    with pytest.raises(ConfigError, match="'estimate' is resolved by dpos-import --nav --aircraft"):
        load_aircraft(aircraft)


def test_imu_time_column_in_utc_of_2016(tmp_path: Path) -> None:
    """--imu with a UTC time column (--time-scale utc): GPST = UTC + 17 s in 2016 (the table)."""
    t0 = int(START_UTC.timestamp())
    csv = tmp_path / "imu.csv"
    csv.write_text("".join(f"0,0,1,0.1,0.2,0.3,{t0 + 0.01 * k:.2f}\n" for k in range(50)))
    out = tmp_path / "bag"
    assert import_.main(["--imu", str(csv), "--time-col", "6", "--time-scale", "utc", "--out", str(out)]) == 0
    rep = json.loads((out / "import_report.json").read_text())
    assert rep["imu"]["span"]["first_ns"] == (t0 + 17) * NS


def test_progress_on_a_terminal_only(installation: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """On a terminal: the stages, a line per sub-IMU (its clock and mounting), the bag's bar; --quiet: nothing."""
    import sys

    from terminal import on_pty  # test/support/terminal.py

    nav, sub, aircraft = installation
    exe = str(Path(sys.executable).parent / "dpos-import")
    rc, out, term = on_pty([exe, *_argv(nav, sub, tmp_path / "a", "--aircraft", str(aircraft))])
    assert rc == 0, term
    for line in ("dpos-import: [", "reading the main navigation solution", "1 sub-IMU log(s)", "sub-IMU left: ",
                 "clock counter only", "mounting ", "writing "):
        assert line in term, term
    assert "%|" in term and "wrote " in out and "sub-IMU left: " not in out
    rc, out, term = on_pty([exe, *_argv(nav, sub, tmp_path / "b", "--aircraft", str(aircraft), "--quiet")])
    assert rc == 0 and term.strip() == "" and "wrote " in out


def _mounting(sigma_deg: tuple[float, float, float]) -> MountingEstimate:
    """An estimate of the identity mounting whose rotation error has these 1 sigmas about x, y, z."""
    cov = np.diag(np.square(np.asarray(sigma_deg) * DEG))
    return MountingEstimate(np.zeros(3), np.asarray(sigma_deg), np.eye(3), cov, np.zeros(3), 0.1, 100, 1.0)


def test_mount_sigma_is_the_estimates_largest_with_the_solutions_attitude() -> None:
    """mount_sigma_deg: the estimate's largest 1 sigma (rotation covariance) and the main
    solution's attitude sigma (a constant attitude error the rates do not see) root sum square."""
    assert install.mount_prior_sigma_deg(_mounting((0.3, 0.2, 0.1)), 0.1) == pytest.approx(np.hypot(0.3, 0.1), abs=1e-3)
    assert install.mount_prior_sigma_deg(_mounting((0.01, 0.02, 0.03)), 0.1) == pytest.approx(np.hypot(0.03, 0.1), abs=1e-3)
    assert install.mount_prior_sigma_deg(_mounting((1e-4, 1e-4, 1e-4)), 0.0) == install.MOUNT_SIGMA_MIN_DEG


def test_aircraft_text_writes_the_sigma_beside_the_estimate(tmp_path: Path) -> None:
    """Beside every estimated mounting (a generated file and 'estimate' in --aircraft); a sigma the
    --aircraft file states is kept; a given mounting gets none."""
    mounts = {"a": _mounting((0.3, 0.2, 0.1)), "b": _mounting((0.3, 0.2, 0.1))}
    text, replaced = install.aircraft_text(None, ["a", "b"], mounts, mount_sigmas={"a": 0.316, "b": 0.5})
    assert replaced == ["a", "b"]
    assert [s["mount_sigma_deg"] for s in yaml.safe_load(text)["sub_imus"]] == [0.316, 0.5]
    p = tmp_path / "ac.yaml"
    p.write_text(yaml.safe_dump({"name": "t", "flexure": {"tau_s": [5, 2, 2], "variance_deg2": [0.01, 0.01, 0.01]}, "sub_imus": [
        {"name": "a", "span_m": 0.0, "lever_arm_m": [0, 0, 0], "mount_rpy_deg": "estimate"},
        {"name": "b", "span_m": 0.0, "lever_arm_m": [0, 0, 0], "mount_rpy_deg": "estimate", "mount_sigma_deg": 2.0},
        {"name": "c", "span_m": 0.0, "lever_arm_m": [0, 0, 0], "mount_rpy_deg": [0, 0, 90]}]}))
    text, replaced = install.aircraft_text(p, ["a", "b"], mounts, mount_sigmas={"a": 0.316, "b": 0.5, "c": 0.4})
    subs = {s["name"]: s for s in yaml.safe_load(text)["sub_imus"]}
    assert replaced == ["a", "b"]
    assert subs["a"]["mount_sigma_deg"] == 0.316 and subs["b"]["mount_sigma_deg"] == 2.0 and "mount_sigma_deg" not in subs["c"]
