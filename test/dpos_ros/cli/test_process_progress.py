"""dpos-process's progress (stages, a line per sub-IMU and per antenna, tqdm bars on stderr: only
on a terminal, not with --quiet) and --geoid (the antenna CSV's height above a geoid grid, its
first line naming the model or saying there is none; a grid that is not one, or does not cover
the track, refused in one line)."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from terminal import on_pty  # test/support/terminal.py

from dpos_ros.cli import process as process_cli
from dpos_ros.cli import sim as sim_cli
from dpos_ros.products.write import GEOID_COLUMN, NO_GEOID_TEXT

EXE = Path(sys.executable).parent
#: the undulation of the constant test grid: Offset + Scale * sample [m]
N_CONST = -30.0 + 0.01 * 4321


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("progress")
    assert sim_cli.main(["--scenario", "paper_su", "--aircraft", "paper_su_pair", "--duration", "20", "--out", str(d / "bag")]) == 0
    return d / "bag"


def _const_pgm(path: Path) -> Path:
    """A GeographicLib geoid PGM (3 x 4 nodes) whose every sample gives N = :data:`N_CONST`."""
    path.write_bytes(b"P5\n# Offset -30\n# Scale 0.01\n4 3\n65535\n" + np.full((3, 4), 4321, dtype=">u2").tobytes())
    return path


def _far_gtx(path: Path) -> Path:
    """A regional .gtx grid over Antarctica (-80..-70 deg, 0..10 deg): no recording's track here."""
    path.write_bytes(struct.pack(">4d2i", -80.0, 0.0, 5.0, 5.0, 3, 3) + np.zeros(9, dtype=">f4").tobytes())
    return path


def _csv(path: Path) -> tuple[str, list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    return lines[0], lines[1].split(","), np.loadtxt(path, delimiter=",", skiprows=2)


def test_progress_on_a_terminal_and_the_height_above_the_geoid(bag: Path, tmp_path: Path) -> None:
    geoid = _const_pgm(tmp_path / "const-test.pgm")
    rc, out, term = on_pty([str(EXE / "dpos-process"), str(bag), "--method", "urtss", "--workers", "1",
                            "--geoid", str(geoid), "--out", str(tmp_path / "o")])
    assert rc == 0, term
    for line in ("reading the main POS", "aligning 2 sub-IMU(s) with urtss", "sub-IMU sub_r: estimated", "sub-IMU sub_l: estimated",
                 "writing the products of 2 antenna(s)", "antenna ant_r: done", "antenna ant_l: done", "] done"):
        assert line in term, term
    assert "antenna bag: 100%|" in term and "\r" in term  # tqdm's bars, redrawn in place
    assert "products in" in out and "sub-IMU sub_r:" not in out  # the results on stdout, the progress not
    first, names, rows = _csv(tmp_path / "o" / "paper_su_seed1" / "ant_r.csv")
    assert first.startswith("# ") and "geoid model const-test.pgm" in first and NO_GEOID_TEXT not in first
    assert names[-1] == GEOID_COLUMN and len(names) == rows.shape[1]
    np.testing.assert_allclose(rows[:, -1], rows[:, names.index("h_m")] - N_CONST, rtol=0, atol=2e-4)


def test_no_progress_off_a_terminal_and_no_geoid_said(bag: Path, tmp_path: Path) -> None:
    r = subprocess.run([str(EXE / "dpos-process"), str(bag), "--method", "urtss", "--workers", "1", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    for mark in ("\r", "%|", "sub-IMU sub_r:", "reading the main POS", "antenna ant_r:"):
        assert mark not in r.stderr and mark not in r.stdout
    first, names, rows = _csv(tmp_path / "o" / "paper_su_seed1" / "ant_r.csv")
    assert NO_GEOID_TEXT in first and GEOID_COLUMN not in names and len(names) == rows.shape[1]


def test_quiet_and_a_grid_that_does_not_cover_the_track(bag: Path, tmp_path: Path) -> None:
    """Refused (exit 2, one line) after the main POS is read; --quiet: that line only on the terminal."""
    far = _far_gtx(tmp_path / "antarctica.gtx")
    argv = [str(EXE / "dpos-process"), str(bag), "--geoid", str(far), "--out", str(tmp_path / "o")]
    rc, _, term = on_pty(argv)
    assert rc == 2 and "reading the main POS" in term and "does not cover the track" in term
    rc, _, term = on_pty([*argv, "--quiet"])
    lines = [ln for ln in term.replace("\r", "").splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and "antarctica.gtx" in lines[0] and "does not cover the track" in lines[0], term
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_a_file_that_is_not_a_geoid_grid_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "geoid.gtx"
    bad.write_text("not a grid\n")
    assert process_cli.main([str(tmp_path / "no_bag"), "--geoid", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--geoid" in err and "geoid.gtx" in err
