"""dpos-eval on the SINS/SAR scenario (paper_sar, [Yan2016]): Table 2 report, ESS and sweep outputs."""

from __future__ import annotations

import json

import pytest

from dpos_ros.cli.evaluate import main


def test_sar_eval_writes_table2_ess_and_sweep(tmp_path) -> None:
    out = tmp_path / "sar"
    rc = main(["--scenario", "paper_sar", "--methods", "ekf,oracle,pf,mcmc_rpf", "--particles", "40", "--runs", "1",
               "--duration", "160", "--particle-sweep", "20,40", "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["methods"]) == {"ekf", "oracle", "pf", "mcmc_rpf"}
    ekf = m["methods"]["ekf"]
    assert ekf["lat"]["mae"] < 5.0 and ekf["yaw"]["mae"] < 1.0  # metres and sub-arcminute over 100-160 s
    assert set(m["particle_sweep"]) == {"20", "40"}
    rep = (out / "report.md").read_text()
    assert "| mcmc_rpf | [Yan2016] |" in rep and "| oracle |" in rep
    head = (out / "ess.csv").read_text().splitlines()[0]
    assert head == "t_s,pf_ess,pf_distinct,mcmc_rpf_ess,mcmc_rpf_distinct"
    assert (out / "ess.png").stat().st_size > 0 and (out / "particles.png").stat().st_size > 0


def test_sar_eval_names_bad_input(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--scenario", "paper_sar", "--methods", "ekf,bpf", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "unknown SINS/SAR method(s) ['bpf']" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--scenario", "paper_sar", "--particle-sweep", "10,x", "--out", str(tmp_path)])
    assert "--particle-sweep" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--scenario", "paper_sar", "--duration", "50", "--out", str(tmp_path)])
    assert "100 s the statistics start at" in capsys.readouterr().err
