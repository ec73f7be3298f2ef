"""dpos-eval --mismatch (docs/mismatch.md): an unknown case is a usage error naming it and listing
the valid ones; a case's recording carries the nominal aircraft file while its truth is the
perturbed one; a short suite writes the mismatch table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.config import config_text
from dpos_core.config.aircraft import load_aircraft
from dpos_core.evaluation import mismatch as MM
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli import evaluate as cli
from dpos_ros.cli import mismatch as PM


def test_unknown_case_is_a_usage_error(tmp_path: Path, capsys) -> None:
    out = tmp_path / "eval"
    with pytest.raises(SystemExit) as ex:  # in process: the entry point is this main (test_methods_entry_points)
        cli.main(["--scenario", "paper_su", "--mismatch", "lever_arm_1cm,no_such_case", "--out", str(out)])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert last.startswith("dpos-eval: error: ") and "no_such_case" in last and "lever_arm_1cm" in last and "time_offset_20ms" in last
    assert err.startswith("usage: dpos-eval") and not out.exists()


def test_recording_carries_the_nominal_aircraft() -> None:
    su = load_scenario("paper_su")
    text = config_text("aircraft", "paper_su")
    ss, sess = PM.recording(MM.CASES["lever_arm_1cm"], su, 1, text, duration_s=3.0)
    assert sess.custom["dpos.mismatch"] == "lever_arm_1cm"
    filt = load_aircraft("paper_su", text=sess.custom["dpos.aircraft_yaml"])
    assert filt.sub_imu("sub_r").lever_arm_m == (0.1, -5.0, 0.1)  # what the filter reads: as surveyed
    true = ss.scenario.aircraft.sub_imu("sub_r").lever_arm_m
    assert abs(np.linalg.norm(np.subtract(true, filt.sub_imu("sub_r").lever_arm_m)) - 0.01) < 1e-9
    # the recorded truth of the antenna is the perturbed installation's
    tr = sess.truth["antenna/ant_r"]
    nom = SimulatedSession(su, 1, 3.0).truth("antenna/ant_r", tr.t_s)
    d = np.linalg.norm(earth.dllh_to_enu(tr.llh - nom.llh, nom.llh), axis=1)
    assert np.all(np.abs(d - 0.01) < 5e-4)


def test_short_suite_writes_the_table(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mm"
    rc = cli.main(["--scenario", "paper_su", "--mismatch", "time_offset_20ms", "--methods", "urtss", "--runs", "1",
                   "--duration", "30", "--out", str(out)])
    assert rc == 0
    doc = json.loads((out / "metrics.json").read_text())
    c = doc["cases"]["time_offset_20ms"]
    assert set(c["methods"]) == {"urtss", "oracle"}  # the oracle is always added
    assert c["ratio_to_oracle"]["oracle"]["heading_deg"] == 1.0
    cons = c["methods"]["urtss"]["consistency"]
    assert set(cons["within_2sigma"]) == set(cons["nees"]) == {"rot_e", "rot_n", "rot_u", "vel_e", "vel_n", "vel_u", "pos_e", "pos_n", "pos_u"}
    assert len(c["nees_bounds"]) == 2 and set(c["goal"]["urtss"]) == {"heading", "baseline", "ratio", "met"}
    # one run: its ANEES is the pooled one, judged against chi^2(1)'s bounds
    assert all(cons["nees_per_run"][k] == [pytest.approx(cons["nees"][k])] for k in cons["nees"])
    lo, hi = c["nees_bounds"]
    assert cons["nees_in_bounds"] == {k: lo <= v <= hi for k, v in cons["nees"].items()}
    report = (out / "report.md").read_text()
    assert "| time_offset_20ms | urtss |" in report and "## time_offset_20ms" in report
    # the worst ANEES is starred where it is outside the bounds
    worst = max(cons["nees"], key=cons["nees"].get)
    row = next(line for line in report.splitlines() if line.startswith("| time_offset_20ms | urtss |"))
    assert f"({worst}){'' if cons['nees_in_bounds'][worst] else ' *'} |" in row
