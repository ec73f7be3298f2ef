"""No tracebacks: every bad option, parameter file, output or spill a probe
tried, and more of the same classes, ends in one line ``prog: error: ...`` and exit status 2,
before anything is allocated or written.  The options are checked by the shared argparse types
(dpos_ros.cli.options) and the commands' own checks; what escapes them as a DposError, an
OSError (a full disk) or a MemoryError is turned into one line by ``one_line_errors``.
dpos-graph's cases: test/dpos_ros/runtime/test_graph_trust.py; dpos-play's (ROS):
test_play_cli_errors.py."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest
from repo_paths import REPO

from dpos_core.errors import BagError
from dpos_ros.cli import evaluate, import_, play, process, record, sar, sim
from dpos_ros.cli.options import one_line_errors
from dpos_ros.io import spill as S
from ifa_node import offline as ifa

WALK = REPO / "data" / "real" / "walk_0827"
SAMPLE = REPO / "bags" / "paper_su_pair_seed1_45s"


def _run(main, argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse's usage errors
        return int(e.code or 0)


def _one_line(capsys: pytest.CaptureFixture[str], prog: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("usage:") and not ln.startswith(" ")]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), err
    return lines[0]


IMPORT = ["--imu", str(WALK / "imu_1730.csv"), "--tag", str(WALK / "imu_1730.csv.tag")]
# (command, its arguments, a word of the one line): the cases first, then ours
OPTION_CASES = [
    ("dpos-import", [*IMPORT, "--start", "nan"], "--start"),
    ("dpos-import", [*IMPORT, "--end", "inf"], "--end"),
    ("dpos-import", [*IMPORT, "--start", "-inf"], "--start"),
    ("dpos-import", [*IMPORT, "--skip-header", "-1"], "--skip-header"),
    ("dpos-import", [*IMPORT, "--accel-cols", "0,1,99999999"], "--accel-cols"),
    ("dpos-process", [str(SAMPLE), "--filter-rate", "1e9"], "--filter-rate"),
    ("dpos-process", [str(SAMPLE), "--particles", "1e9"], "--particles"),
    ("dpos-process", [str(SAMPLE), "--particles", "1000000000"], "--particles"),
    ("dpos-process", [str(SAMPLE), "--output-rate", "inf"], "--output-rate"),
    ("dpos-process", [str(SAMPLE), "--workers", "100000"], "--workers"),
    ("dpos-ifa", [str(SAMPLE), "--estimate-time-offset", "0:1e12:1"], "--estimate-time-offset"),
    ("dpos-ifa", [str(SAMPLE), "--estimate-time-offset", "0:nan:1"], "--estimate-time-offset"),
    ("dpos-ifa", [str(SAMPLE), "--gnss-time-offset", "1e300"], "--gnss-time-offset"),
    ("dpos-ifa", [str(SAMPLE), "--outage", "0:inf"], "--outage"),
    ("dpos-ifa", [str(SAMPLE), "--min-course-speed", "-1"], "--min-course-speed"),
    ("dpos-sim", ["--scenario", "paper_su", "--duration", "inf"], "--duration"),
    ("dpos-sim", ["--scenario", "paper_su", "--window", "nan"], "--window"),
    ("dpos-sar", [str(SAMPLE), "--method", "pf", "--particles", "1000000000"], "--particles"),
    ("dpos-sar", [str(SAMPLE), "--filter-rate", "1e9"], "--filter-rate"),
    ("dpos-eval", ["--scenario", "paper_su", "--particles", "1000000000"], "--particles"),
    ("dpos-play", [str(SAMPLE), "--rate", "inf"], "--rate"),
    ("dpos-play", [str(SAMPLE), "--wait-subscribers", "nan"], "--wait-subscribers"),
    ("dpos-play", [str(SAMPLE), "--flow-window", "0"], "--flow-window"),
    ("dpos-record", ["--all", "--duration", "inf"], "--duration"),
]
MAINS = {"dpos-import": import_.main, "dpos-process": process.main, "dpos-ifa": ifa.main, "dpos-sim": sim.main,
         "dpos-sar": sar.main, "dpos-eval": evaluate.main, "dpos-play": play.main, "dpos-record": record.main}


@pytest.mark.parametrize("prog, argv, word", OPTION_CASES, ids=[f"{c[0]} {' '.join(c[1][-2:])}" for c in OPTION_CASES])
def test_bad_option_is_one_line_and_exit_2(prog: str, argv: list[str], word: str, tmp_path: Path, capsys) -> None:
    extra = ["--params-file", str(WALK / "ifa_node.yaml")] if prog == "dpos-ifa" else []
    out = [] if prog == "dpos-play" else ["--out", str(tmp_path / "out")]
    assert _run(MAINS[prog], [*argv, *extra, *out]) == 2
    assert word in _one_line(capsys, prog)
    assert not (tmp_path / "out").exists()


PARAMS = (WALK / "ifa_node.yaml").read_text().replace("data/real/walk_0827/handheld.yaml", str(WALK / "handheld.yaml"))
# (a line added to ifa_node's parameter file, a word of the one line): the issue's, then ours
PARAM_CASES = [
    ('    window: "ten"', "'window' = 'ten'"),
    ("    method: true", "'method' = True"),
    ("    level_sigma_deg: .nan", "level_sigma_deg"),
    ("    gnss_pos_sigma_m: {e: 1}", "gnss_pos_sigma_m"),
    ("    method: dd3", "'method' = 'dd3'"),
]


@pytest.mark.parametrize("line, word", PARAM_CASES, ids=[c[0].strip() for c in PARAM_CASES])
def test_bad_ifa_parameter_file_is_one_line_and_exit_2(line: str, word: str, tmp_path: Path, capsys) -> None:
    p = tmp_path / "ifa_node.yaml"
    p.write_text(PARAMS.replace("    level_sigma_deg: 3.0\n", "") + line + "\n")
    assert _run(ifa.main, [str(SAMPLE), "--params-file", str(p), "--out", str(tmp_path / "out")]) == 2
    assert word in _one_line(capsys, "dpos-ifa")


def test_ifa_out_naming_a_file(tmp_path: Path, capsys) -> None:
    f = tmp_path / "report.txt"
    f.write_text("x")
    assert _run(ifa.main, [str(SAMPLE), "--params-file", str(WALK / "ifa_node.yaml"), "--out", str(f)]) == 2
    assert "is a file" in _one_line(capsys, "dpos-ifa")
    assert f.read_text() == "x"


def _spill(tmp_path: Path, edit) -> Path:
    d = tmp_path / "spill"
    w = S.SpillWriter(d, "s1")
    w.write("/master/nav", "nav_msgs/msg/Odometry", 1, b"abcd")
    w.close()
    meta = json.loads((d / "spill.json").read_text())
    edit(meta)
    (d / "spill.json").write_text(json.dumps(meta))
    return d


@pytest.mark.parametrize("edit, word", [
    (lambda m: m.pop("topics"), "'topics' is missing"),
    (lambda m: m["topics"]["/master/nav"].pop("file"), "needs a 'msgtype' and a 'file'"),
    (lambda m: m["topics"]["/master/nav"].update(file="../../../etc/shadow"), "not a file name in the spill"),
    (lambda m: m.update(topics={"/master/nav": "nav_msgs/msg/Odometry"}), "needs a 'msgtype' and a 'file'"),
], ids=["no topics", "no file", "file outside", "topic not a mapping"])
def test_bad_spill_json_is_one_line_and_exit_2(edit, word: str, tmp_path: Path, capsys) -> None:
    d = _spill(tmp_path, edit)
    assert _run(process.main, [str(d), "--workers", "1", "--out", str(tmp_path / "out")]) == 2
    assert word in _one_line(capsys, "dpos-process")


@pytest.mark.parametrize("exc, word", [
    (OSError(errno.ENOSPC, "No space left on device", "/x/nav.csv"), "/x/nav.csv: No space left on device (ENOSPC)"),
    (OSError(errno.ENOSPC, "No space left on device"), "No space left on device (ENOSPC)"),
    (MemoryError("Unable to allocate 8 GiB"), "out of memory"),
    (BagError("b: cannot read bag\nsecond line"), "b: cannot read bag second line"),
])
def test_one_line_errors_turns_expected_failures_into_one_line(exc: BaseException, word: str, capsys) -> None:
    @one_line_errors("dpos-x")
    def main() -> int:
        raise exc

    assert main() == 2
    assert word in _one_line(capsys, "dpos-x")


def test_one_line_errors_keeps_the_traceback_of_a_bug() -> None:
    @one_line_errors("dpos-x")
    def main() -> int:
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        main()
