"""dpos-eval and the oracle."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

EXE = Path(sys.executable).parent


def test_eval_writes_metrics_and_the_oracle_bounds_urtss(tmp_path: Path) -> None:
    """Two 450 s runs of paper_su (segment AB partly inside): the smoother's RMSE is within 30 %
    of the oracle's (the model linearized about the truth with the true noise statistics) on
    every row, and the oracle is not worse than URTSS by more than Monte Carlo scatter."""
    r = subprocess.run([str(EXE / "dpos-eval"), "--scenario", "paper_su", "--methods", "urtss,oracle", "--runs", "2",
                        "--duration", "450", "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["runs"] == 2 and m["segments"] == ["AB"] and set(m["methods"]) == {"urtss", "oracle"}
    u, o = m["methods"]["urtss"]["mean"]["rmse"], m["methods"]["oracle"]["mean"]["rmse"]
    for k in u:
        assert u[k] < 1.3 * o[k], (k, u[k], o[k])
    assert set(m["methods"]["urtss"]["antennas"]) == {"ant_r"}
    rep = (tmp_path / "report.md").read_text()
    assert "Ratio of RMSE to the oracle" in rep and "paper UPS RMSE" in rep


def test_eval_rejects_unknown_methods(tmp_path: Path) -> None:
    r = subprocess.run([str(EXE / "dpos-eval"), "--scenario", "paper_su", "--methods", "kalman9", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "unknown transfer-alignment method" in r.stderr
