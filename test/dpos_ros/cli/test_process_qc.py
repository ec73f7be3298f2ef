"""dpos-process's quality-control products: qc.md, qc/<antenna>_qc.png and the
status.json qc block, made without the truth (the same with the truth removed from the recording)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from dpos_core.ta import flags as F

from .test_process import EXE, _sim_bag


def _no_truth(streams):
    return [s for s in streams if not s.topic.startswith("/truth/")]


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("qc")
    return _sim_bag(d / "truth", 20.0), _sim_bag(d / "no_truth", 20.0, _no_truth)


def test_dpos_process_writes_the_qc_report_without_truth(bags, tmp_path: Path) -> None:
    _, no_truth = bags
    r = subprocess.run([str(EXE / "dpos-process"), str(no_truth), "--method", "urtss", "--figures", "on", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "o" / "paper_su_seed2"
    assert not (out / "metrics.json").exists() and not (out / "errors_ant_r.png").exists()
    assert (out / "qc" / "ant_r_qc.png").stat().st_size > 10_000
    md = (out / "qc.md").read_text()
    assert "| ant_r | sub_r | ok |" in md and "## Innovations (NIS)" in md and "## Forward/backward separation" in md
    q = json.loads((out / "status.json").read_text())["qc"]
    a = q["antennas"]["ant_r"]
    assert q["window_s"] == 60.0 and a["verdict"] == "ok" and a["nis"]["dof"] == 9 and a["nis"]["epochs"] == 21
    assert a["nis"]["windowed_above_fraction"] == 0.0 and 0.2 < a["nis"]["mean_per_dof"] < 2.0
    assert set(a["separation"]) == {"attitude", "velocity", "position"} and a["separation"]["attitude"]["unit"] == "deg"
    assert a["sigma"]["heading_deg"]["p50"] > 0 and a["flags"] == {}


def test_the_qc_products_do_not_depend_on_the_truth(bags, tmp_path: Path) -> None:
    """solve() + write() in process (what dpos-process and transfer_align_node run) on the same
    recording with and without its /truth topics: the same qc.md, qc block and figure."""
    from dpos_core.config import load_aircraft
    from dpos_core.ta.pipeline import TASettings
    from dpos_ros.io.session import read_session
    from dpos_ros.products.evaluate import evaluate
    from dpos_ros.products.solve import solve
    from dpos_ros.products.write import WriteOptions, write

    dirs = []
    for b, name in zip(bags, ("t", "n"), strict=True):
        sess = read_session(b)
        ants, timing = solve(sess, load_aircraft("paper_su"), TASettings(method="ukf"))
        dirs.append(write(tmp_path / name, sess, ants, "ukf", timing, evaluate(sess, ants) or None, options=WriteOptions(figures=True)))
    with_truth, without = dirs
    assert (with_truth / "metrics.json").exists() and not (without / "metrics.json").exists()
    assert (with_truth / "qc.md").read_text() == (without / "qc.md").read_text()
    qa, qb = (json.loads((d / "status.json").read_text())["qc"] for d in dirs)
    assert qa == qb and qa["antennas"]["ant_r"]["separation"] is None  # ukf: forward only
    assert (with_truth / "qc" / "ant_r_qc.png").read_bytes() == (without / "qc" / "ant_r_qc.png").read_bytes()


def test_figures_off_leaves_out_the_pngs_only(bags, tmp_path: Path) -> None:
    """``WriteOptions(figures=False)`` (``--figures off``, ``DPOS_FIGURES=off``): the same products
    without qc/<antenna>_qc.png and errors_<antenna>.png."""
    from dpos_core.config import load_aircraft
    from dpos_core.ta.pipeline import TASettings
    from dpos_ros.io.session import read_session
    from dpos_ros.products.evaluate import evaluate
    from dpos_ros.products.solve import solve
    from dpos_ros.products.write import WriteOptions, write

    sess = read_session(bags[0])
    ants, timing = solve(sess, load_aircraft("paper_su"), TASettings(method="ukf"))
    ev = evaluate(sess, ants) or None
    on, off = (write(tmp_path / n, sess, ants, "ukf", timing, ev, options=WriteOptions(figures=f)) for n, f in (("on", True), ("off", False)))
    listing = {p.relative_to(on).as_posix() for p in on.rglob("*") if p.is_file()}
    assert {"qc/ant_r_qc.png", "errors_ant_r.png"} <= listing
    assert {p.relative_to(off).as_posix() for p in off.rglob("*") if p.is_file()} == listing - {"qc/ant_r_qc.png", "errors_ant_r.png"}
    for f in ("ant_r.csv", "qc.md", "metrics.json", "report.md"):
        assert (on / f).read_bytes() == (off / f).read_bytes(), f


def test_figures_default_comes_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    from dpos_ros.products.write import WriteOptions, figures_switch

    assert [figures_switch(v) for v in ("on", "ON", "1", "true", "yes", "off", "0", "False", " no ")] == [True] * 5 + [False] * 4
    with pytest.raises(ValueError, match="DPOS_FIGURES='maybe': expected on or off"):
        figures_switch("maybe")
    monkeypatch.delenv("DPOS_FIGURES", raising=False)
    assert WriteOptions().figures is True
    monkeypatch.setenv("DPOS_FIGURES", "off")
    assert WriteOptions().figures is False
    monkeypatch.setenv("DPOS_FIGURES", "of")  # a typo: said, and the figures are written (never fewer products)
    with pytest.warns(UserWarning, match="DPOS_FIGURES='of': expected on or off; the figures are written"):
        assert WriteOptions().figures is True


def test_qc_flags_are_documented() -> None:
    """Every flag bit has a name and is in design.md's "Session products" and docs/qc.md."""
    root = Path(__file__).resolve().parents[3]
    design, qc_doc = (root / "docs" / "design.md").read_text(), (root / "docs" / "qc.md").read_text()
    assert len(F.NAMES) == 7 and set(F.NAMES) == {1 << i for i in range(7)}
    for bit, name in F.NAMES.items():
        assert f"`{name}`" in qc_doc, name
        assert f"{bit} = " in design, bit
    assert "qc.md" in design and "`qc`" in design


def test_a_main_pos_unaligned_mid_session_is_flagged(bags, tmp_path: Path) -> None:
    """The main POS reports a 0.5 deg attitude sigma over 12-15 s (after its alignment): those
    rows carry MASTER_UNALIGNED (32) in the CSV and the verdict says check."""
    import numpy as np

    from dpos_core.config import load_aircraft
    from dpos_core.ta.pipeline import TASettings
    from dpos_ros.io.session import read_session
    from dpos_ros.products.solve import solve
    from dpos_ros.products.write import write

    sess = read_session(bags[1])
    m = sess.master
    assert m.att_cov is not None
    bad = (m.t_s >= 12.0) & (m.t_s <= 15.0)
    m.att_cov[bad] = np.eye(3) * np.deg2rad(0.5) ** 2
    ants, timing = solve(sess, load_aircraft("paper_su"), TASettings(method="ukf"))
    out = write(tmp_path, sess, ants, "ukf", timing)
    rows = np.loadtxt(out / "ant_r.csv", delimiter=",", skiprows=2)
    flags_col = (out / "ant_r.csv").read_text().splitlines()[1].split(",").index("flags")
    t, fl = rows[:, 0] - sess.t0_ns * 1e-9, rows[:, flags_col].astype(int)
    hit = (fl & F.MASTER_UNALIGNED) != 0
    assert np.all(hit[(t > 12.01) & (t < 14.99)]) and not np.any(hit[(t < 11.9) | (t > 15.1)])
    a = json.loads((out / "status.json").read_text())["qc"]["antennas"]["ant_r"]
    assert a["verdict"].startswith("check: main POS unaligned 3 s") and a["flags"]["master_unaligned"]["time_s"] > 3.0
