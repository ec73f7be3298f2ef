"""dpos-sar: the SINS/SAR navigation of a dpos-sim paper_sar recording (the recording carries /sar/fix
and /baro/pressure), every method selectable; a recording without those topics is exit 2 naming them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dpos_ros.cli.sar import main

pytestmark = pytest.mark.slow
DURATION_S = 120.0


def _sim(out: Path, scenario: str, duration: float) -> Path:
    exe = Path(sys.executable).parent / "dpos-sim"
    r = subprocess.run([str(exe), "--scenario", scenario, "--seed", "1", "--duration", str(duration), "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def sar_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _sim(tmp_path_factory.mktemp("sar") / "paper_sar", "paper_sar", DURATION_S)


def test_ekf_on_a_recording_reaches_the_fixes_accuracy(sar_bag: Path, tmp_path: Path, capsys) -> None:
    """The recording's /master/nav starts from the reference navigation (truth + 1 m, 0.01 deg); the
    EKF over 120 s: a few metres (docs/sar.md: EKF ranges within +-10 m, MAE about 2 m over 100-1000 s),
    a fraction of an arcminute in heading."""
    assert main([str(sar_bag), "--method", "ekf", "--out", str(tmp_path / "ekf")]) == 0
    rep = json.loads((tmp_path / "ekf" / "report.json").read_text())
    assert rep["method"] == "ekf" and rep["epochs"] == 121 and rep["epochs_with_fix"] == 120 and rep["fixes_off_grid"] == 0
    mae = rep["truth"]["mae"]
    print(mae)
    assert mae["east_m"] < 6.0 and mae["north_m"] < 6.0 and mae["up_m"] < 1.0
    assert mae["yaw_arcmin"] < 1.0 and mae["pitch_arcmin"] < 1.0 and mae["roll_arcmin"] < 1.0
    nav = np.loadtxt(tmp_path / "ekf" / "nav.csv", delimiter=",", skiprows=1)
    assert nav.shape == (121, 20)
    assert "MAE against /truth/master" in capsys.readouterr().out


def test_a_particle_filter_on_a_recording_runs_and_reports_its_ess(sar_bag: Path, tmp_path: Path) -> None:
    assert main([str(sar_bag), "--method", "rpf", "--particles", "50", "--seed", "2", "--bandwidth-scale", "0.5",
                 "--out", str(tmp_path / "rpf")]) == 0
    rep = json.loads((tmp_path / "rpf" / "report.json").read_text())
    assert rep["method"] == "rpf" and rep["particles"] == 50 and rep["bandwidth_scale"] == 0.5 and rep["seed"] == 2
    assert 0 < rep["mean_ess"] <= 50 and 0 < rep["final_ess"] <= 50


def test_a_recording_without_the_sar_topics_is_refused_naming_them(tmp_path: Path, capsys) -> None:
    bag = _sim(tmp_path / "paper_su", "paper_su", 3.0)
    assert main([str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "/sar/fix" in err and "/baro/pressure" in err and "/master/imu" not in err.split("(the recording has")[0]
    assert not (tmp_path / "out").exists()


def test_bad_options(sar_bag: Path, tmp_path: Path, capsys) -> None:
    assert main([str(sar_bag), "--method", "pf", "--particles", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--particles must be >= 2" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main([str(sar_bag), "--method", "kalman", "--out", str(tmp_path / "x")])
    assert e.value.code == 2
