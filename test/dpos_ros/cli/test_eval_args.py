"""dpos-eval's numeric options: a bad value is an argparse error (usage, one
``dpos-eval: error: ...`` line naming the option, exit 2) before anything runs or is written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_inprocess import run_main  # test/support/cli_inprocess.py

from dpos_core.evaluation.ifa import RunResult
from dpos_ros.cli.evaluate import main

EXE = Path(sys.executable).parent / "dpos-eval"


@pytest.mark.parametrize(("scenario", "args", "needle"), [
    ("paper_su", ["--duration", "-5"], "--duration must be > 0"),
    ("paper_su", ["--duration", "0"], "--duration must be > 0"),
    ("paper_su", ["--duration", "nan"], "--duration must be > 0"),
    ("paper_su", ["--duration", "0.5"], "--duration must be >= 1 s for transfer alignment"),
    ("paper_su", ["--duration", "5000"], "--duration 5000 s exceeds the scenario paper_su's 1300 s"),
    ("paper_ifa", ["--duration", "-5"], "--duration must be > 0"),
    ("paper_ifa", ["--duration", "500"], "exceeds the scenario paper_ifa's 400 s"),
    ("paper_su", ["--runs", "0"], "--runs must be >= 1"),
    ("paper_ifa", ["--runs", "-2"], "--runs must be >= 1"),
    ("paper_su", ["--particles", "0"], "--particles must be >= 1"),
    ("paper_su", ["--seed", "-1"], "--seed must be >= 0"),
    ("paper_ifa", ["--seed", "-1"], "--seed must be >= 0"),
    ("paper_su", ["--initial-attitude-error", "inf"], "--initial-attitude-error must be a finite"),
    ("paper_ifa", ["--initial-heading-error", "nan"], "--initial-heading-error must be a finite"),
])
def test_bad_numbers_are_usage_errors(tmp_path: Path, scenario: str, args: list[str], needle: str) -> None:
    """Each checked in-process (dpos-eval's main); the console script in
    :func:`test_the_console_script_gives_the_usage_error`."""
    out = tmp_path / "eval"
    r = run_main(main, ["--scenario", scenario, "--out", str(out), *args])
    _is_usage_error(r.returncode, r.stderr, needle)
    assert not out.exists()


def test_the_console_script_gives_the_usage_error(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    r = subprocess.run([str(EXE), "--scenario", "paper_su", "--out", str(out), "--duration", "-5"], capture_output=True, text=True, timeout=120)
    _is_usage_error(r.returncode, r.stderr, "--duration must be > 0")
    assert not out.exists()


def _is_usage_error(returncode: int, stderr: str, needle: str) -> None:
    """Exit 2, the usage, and one last ``dpos-eval: error:`` line holding ``needle``; no traceback."""
    assert returncode == 2, stderr
    assert "Traceback" not in stderr and stderr.startswith("usage: dpos-eval"), stderr
    assert stderr.strip().splitlines()[-1].startswith("dpos-eval: error: ") and needle in stderr, stderr


def test_no_epoch_has_no_convergence_time() -> None:
    """An IFA run without any GNSS epoch (paper_sar: GNSS out all flight; a very short run) never
    converged: None, not an IndexError."""
    r = RunResult("add2", 1, 30.0, np.zeros(0), np.zeros((0, 3)), np.zeros(3), None, 0.1, 2.0)
    assert r.convergence_t_s() is None
