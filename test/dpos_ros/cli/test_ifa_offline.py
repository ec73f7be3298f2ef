"""dpos-ifa: the in-flight alignment of a recording offline, with ifa_node's parameter file, on the
real walk_0827 imported by dpos-import (data it did not generate); the errors a user meets."""

from __future__ import annotations

import json
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core.imports.logs import read_pos
from dpos_core.units import DEG, G0_MPS2
from dpos_ros.cli import import_
from ifa_node import offline as ifa

WALK = REPO / "data" / "real" / "walk_0827"


@pytest.fixture(scope="module")
def walk_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("walk") / "walk_0827_1hz"
    rc = import_.main(["--imu", str(WALK / "imu_1730.csv"), "--tag", str(WALK / "imu_1730.csv.tag"), "--pos",
                       str(WALK / "gnss_1730_sf.pos"), "--gnss-rate", "1", "--outage", "60:75", "--out", str(out)])
    assert rc == 0
    return out


@pytest.fixture(scope="module")
def report(walk_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("ifa")
    rc = ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--min-course-speed", "0", "--reference",
                   str(WALK / "gnss_1730_sf.pos"), "--outage", "60:75", "--smooth", "--out", str(out)])
    assert rc == 0
    return out, json.loads((out / "report.json").read_text())


def test_aligns_on_the_real_recording_and_covers_its_error(report):
    _, r = report
    assert r["aligned_t_s"] is not None and r["aligned_t_s"] < 60.0
    assert r["diverged_epochs"] == 0 and r["restarts"] == 0 and r["rejected_fixes"] == 0
    e = r["horizontal_error_m"]
    assert e["before"]["rms"] < 0.15 and e["after"]["rms"] < 0.15 and e["during"]["max"] < 5.0
    assert r["inside_3sigma"]["E"] >= 0.98 and r["inside_3sigma"]["N"] >= 0.98
    assert r["processing_s"] < r["data_s"]


def test_writes_the_navigation_report_and_plot(report):
    out, r = report
    nav = np.loadtxt(out / "nav.csv", delimiter=",", skiprows=1)
    assert nav.shape[1] == 20 and nav.shape[0] > 20000
    assert np.all(np.diff(nav[:, 0]) > 0) and np.all(np.isfinite(nav[:, 2:]))
    assert (out / "ifa.png").stat().st_size > 10_000
    assert "aligned at" in (out / "report.md").read_text()


def test_smooth_writes_the_smoothed_navigation_scored_beside_the_forward_one(report):
    """--smooth: nav_smoothed.csv (nav.csv's columns under a title line saying it is smoothed) and
    nav_smoothed.pos (RTKLIB columns, read back by dpos-import's reader: the same rows), scored in
    report.json / report.md as the forward run.  The walk with the protocol of the peer rows
    (docs/ifa.md): measured before rms 0.026 m, during mean / max 0.091 / 0.173 m, after rms 0.020 /
    max 0.066 m, all inside 3 sigma; the peer's post-processed runs (GNSS_IMU forward + velocity
    matching 0.140, 0.147 / 0.25, 0.024 / 0.08 m; forward + backward combined 0.384, 0.43 / 0.79,
    0.371 / 0.53 m) are the bounds."""
    out, r = report
    s, f = r["smoothed"], r["horizontal_error_m"]
    e = s["horizontal_error_m"]
    assert e["before"]["rms"] < 0.140 and e["during"]["mean"] < 0.147 and e["during"]["max"] < 0.25
    assert e["after"]["rms"] < 0.024 and e["after"]["max"] < 0.08
    assert all(e[k]["max"] < f[k]["max"] for k in ("before", "during", "after"))
    assert all(s["inside_3sigma"][k] >= 0.95 for k in ("E", "N", "U", "all"))
    text = (out / "nav_smoothed.csv").read_text().splitlines()
    assert text[0].startswith("# dpos-ifa --smooth") and text[1] == (out / "nav.csv").read_text().splitlines()[0]
    nav = np.loadtxt(out / "nav_smoothed.csv", delimiter=",", skiprows=2)
    fwd = np.loadtxt(out / "nav.csv", delimiter=",", skiprows=1)
    assert nav.shape == fwd.shape and np.array_equal(nav[:, 0], fwd[:, 0]) and np.all(np.isfinite(nav))
    pos = read_pos(out / "nav_smoothed.pos")
    assert not pos.skipped and len(pos) == nav.shape[0]
    assert np.all(np.abs(pos.t_ns - nav[:, 0].astype(np.int64)) <= 1000)
    np.testing.assert_allclose(np.degrees(pos.llh[:, :2]), nav[:, 2:4], atol=1e-8, rtol=0)
    np.testing.assert_allclose(np.sqrt(np.diagonal(pos.pos_cov_enu_m2, axis1=1, axis2=2)), nav[:, 11:14], atol=1e-4, rtol=0)
    np.testing.assert_allclose(pos.vel_n_mps, nav[:, 5:8], atol=1e-5, rtol=0)
    # Q 5 (bridged by the IMU alone) inside the outage, Q 1 well before and after it
    t = nav[:, 1]
    assert np.all(pos.quality[(t > 61.0) & (t < 74.0)] == 5) and np.all(pos.quality[(t > 20.0) & (t < 58.0)] == 1)
    assert "smoothed horizontal error during" in (out / "report.md").read_text()


def test_errors_name_what_is_wrong(walk_bag: Path, tmp_path: Path, capsys):
    assert ifa.main([str(walk_bag), "--params-file", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert "not an ifa_node parameter file" in capsys.readouterr().err
    assert ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--imu-topic", "/nope",
                     "--out", str(tmp_path / "o")]) == 2
    assert "no topic ['/nope']" in capsys.readouterr().err
    assert ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert "no GNSS fix with a ground speed of 5.0 m/s" in capsys.readouterr().err  # a walk: lower --min-course-speed


def test_estimates_the_time_offset_on_request(walk_bag: Path, tmp_path: Path, capsys):
    """--estimate-time-offset: the candidates' innovation sums, the estimate with its sigma (or
    "not observable"), in report.md and report.json; a span of fewer than 3 candidates is refused."""
    out = tmp_path / "o"
    assert ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--min-course-speed", "0",
                     "--estimate-time-offset=-100:100:100", "--out", str(out)]) == 0
    t = json.loads((out / "report.json").read_text())["time_offset"]
    assert len(t["cost"]) == 3 and t["epochs_used"] > 50 and np.all(np.isfinite(t["cost"]))
    assert t["cost"][1] < min(t["cost"][0], t["cost"][2])  # the walk's minimum is near zero, not at +-100 ms
    assert abs(t["offset_s"]) < 0.1 and (t["observable"] == np.isfinite(t["sigma_s"]))
    assert "GNSS-IMU time offset" in (out / "report.md").read_text()
    assert t is not None and json.loads((out / "report.json").read_text())["smoothed"] is None
    assert not (out / "nav_smoothed.csv").exists()  # only with --smooth
    with pytest.raises(SystemExit) as e:
        ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--estimate-time-offset=0:10:10", "--out", str(out)])
    assert e.value.code == 2 and "at least 3 candidates" in capsys.readouterr().err


def test_gnss_time_offset_option_moves_fixes_start_and_reference_alike(walk_bag: Path, report, tmp_path: Path):
    """--gnss-time-offset MS (GNSS stamps minus IMU time, the parameter's and the estimate's sign): the
    start fix and the reference are taken onto the IMU's clock by the same offset as the fixes, so
    the run and its score stay on one clock (docs/ifa.md, "Time offset")."""
    _, base = report
    out = tmp_path / "o"
    assert ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--min-course-speed", "0", "--reference",
                     str(WALK / "gnss_1730_sf.pos"), "--outage", "60:75", "--gnss-time-offset", "100", "--out", str(out)]) == 0
    r = json.loads((out / "report.json").read_text())
    # the start is a fix 100 ms earlier on the IMU's clock (the first one now falls before the IMU data: the next, 1 s on)
    assert r["start_t_s"] == pytest.approx(base["start_t_s"] - 0.100 + 1.0, abs=1e-6)
    assert r["rejected_fixes"] == 0
    # scored on the IMU's clock the figures stay alike (measured: rms before the outage 0.071 m, 0.082 m
    # with 0); the reference left on the GNSS clock adds the 100 ms along the track (0.121 m)
    assert r["horizontal_error_m"]["before"]["rms"] < base["horizontal_error_m"]["before"]["rms"] + 0.02
    assert "gnss_time_offset_s +100.0 ms" in (out / "report.md").read_text()


@pytest.mark.parametrize(("edit", "says"), [
    (lambda imu, g: (dc_replace(imu, f_mps2=imu.f_mps2 * G0_MPS2), g), "looks like m/s^2 read as g"),
    (lambda imu, g: (dc_replace(imu, f_mps2=imu.f_mps2 / G0_MPS2), g), "looks like g read as m/s^2"),
    (lambda imu, g: (dc_replace(imu, omega_radps=imu.omega_radps / DEG), g), "looks like deg/s read as rad/s"),
    (lambda imu, g: (dc_replace(imu, omega_radps=imu.omega_radps * DEG), g), "looks like rad/s read as deg/s"),
    (lambda imu, g: (imu, dc_replace(g, pos_sigma_m=np.zeros_like(g.pos_sigma_m))), "zero (or invalid) position sigma"),
])
def test_recording_in_the_wrong_unit_is_refused_in_one_line(walk_bag: Path, tmp_path: Path, capsys, monkeypatch, edit, says):
    """dpos-ifa's input runs through dpos_core.plausibility (as dpos-import's and read_session's): the
    real walk_0827 recording (which passes: ``report``) read in the wrong unit, or with its fixes'
    covariance left at zero, exits 2 with one line naming the topic and the likely mistake."""
    from dpos_ros.cli import ifa as cli

    real = cli.read_recording

    def wrong(bag, topics, rotation):
        origin, imu, gnss, notes = real(bag, topics, rotation)
        return (origin, *edit(imu, gnss), notes)

    monkeypatch.setattr(cli, "read_recording", wrong)
    out = tmp_path / "o"
    assert ifa.main([str(walk_bag), "--params-file", str(WALK / "ifa_node.yaml"), "--min-course-speed", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"dpos-ifa: error: {walk_bag}: /") and says in err[0], err
    assert not out.exists()
