"""dpos-eval on an in-flight-alignment scenario (paper_ifa): dispatch, metrics.json, report.md."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

EXE = Path(sys.executable).parent
KEYS = {"heading_deg", "pitch_deg", "roll_deg"}


def _eval(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE / "dpos-eval"), "--scenario", "paper_ifa", "--duration", "60", "--out", str(tmp_path), *extra],
                          capture_output=True, text=True, timeout=600)


def test_eval_ifa_writes_table3_and_experiments(tmp_path: Path) -> None:
    """One 60 s run (first turn 20-60 s): the IFA path, not the transfer-alignment one, with every
    experiment; the heading has converged from 90 deg after the first turn."""
    r = _eval(tmp_path, "--methods", "add2,dd2", "--runs", "1", "--seed", "2", "--initial-heading-error", "90",
              "--heading-sweep", "150", "--outage", "30,10", "--noise-jump", "40,10")
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["scenario"] == "paper_ifa" and m["runs"] == 1 and m["seeds"] == [2] and m["initial_heading_error_deg"] == 90.0
    assert set(m["methods"]) == {"add2", "dd2"}
    for d in m["methods"].values():
        assert set(d["mean"]) >= {"rmse", "std"} and set(d["mean"]["rmse"]) == KEYS and set(d["mean"]["std"]) == KEYS
        assert d["timing"]["data_s"] == 60.0 and d["timing"]["processing_s"] > 0
        assert d["mean"]["rmse"]["heading_deg"] < 0.5  # converged in the first turn
    assert [row["initial_heading_error_deg"] for row in m["heading_sweep"]["add2"]] == [-150.0, 150.0]
    out = m["outage"]["methods"]["add2"][0]
    assert out["epochs_in_outage"] == 0 and m["outage"]["t0_s"] == 30.0
    assert set(m["noise_jump"]["methods"]) == {"add2", "dd2"} and m["noise_jump"]["scale"] == 10.0
    rep = (tmp_path / "report.md").read_text()
    for s in ("| ADD2 (ours) |", "| ADD2 ([Fang2012]) | 0.014 | 0.0016 | 0.0018 | 6.8505 |", "| DD2 (ours) |",
              "Initial-heading sweep", "GNSS outage 30-40 s", "GNSS noise x10 from 40 s"):
        assert s in rep, s


def test_eval_ifa_rejects_bad_options(tmp_path: Path) -> None:
    r = _eval(tmp_path, "--methods", "ups")
    assert r.returncode == 2 and "unknown IFA method" in r.stderr
    r = _eval(tmp_path, "--outage", "30")
    assert r.returncode == 2 and "--outage takes two numbers" in r.stderr
    assert not (tmp_path / "metrics.json").exists()
