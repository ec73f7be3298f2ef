"""dpos_ros.cli.progress: the stage lines, item lines and bars appear on a terminal (also one that
says it has 0 x 0 cells, as under ``script``), and nothing at all is written off a terminal or
quietly."""

from __future__ import annotations

import io
import sys

import pytest
from terminal import on_pty  # test/support/terminal.py

from dpos_ros.cli.progress import Progress, Stages, on_terminal

SCRIPT = """
import sys
from dpos_ros.cli.progress import Progress, Stages
st = Stages("dpos-test", quiet="--quiet" in sys.argv)
st.stage("reading")
with st.items("sub-IMU", 2) as bar:
    bar.done("imu01", "estimated")
    bar.done("imu03", "not estimated: no data")
p = st.bar("writing")
for k in range(0, 41, 10):
    p(k, 40)
st.print("a result line")
"""


@pytest.mark.parametrize("size", [(120, 40), None])
def test_on_a_terminal_stages_items_and_bars(size: tuple[int, int] | None) -> None:
    rc, out, term = on_pty([sys.executable, "-c", SCRIPT], timeout=120, size=size)
    assert rc == 0, term
    assert "dpos-test: [0.0 s] reading" in term
    assert "  sub-IMU imu01: estimated" in term and "  sub-IMU imu03: not estimated: no data" in term
    assert "writing: 100%|" in term and "sub-IMU:  50%|" in term  # the bars, drawn with a width
    assert out == "a result line\n"


def test_quiet_on_a_terminal_writes_nothing() -> None:
    rc, out, term = on_pty([sys.executable, "-c", SCRIPT, "--quiet"], timeout=120)
    assert rc == 0 and term == "" and out == "a result line\n"


def test_off_a_terminal_nothing_is_written(capsys: pytest.CaptureFixture[str]) -> None:
    f = io.StringIO()
    assert not on_terminal(f) and not on_terminal(sys.stderr)  # (pytest's capture is no terminal)
    st = Stages("dpos-test", stream=f)
    st.stage("reading")
    with st.items("antenna", 3) as bar:
        for name in ("a", "b", "c"):
            bar.done(name)
    p = Progress("writing", stream=f)
    p(5, 10)
    p(10, 10)
    st.print("a result line")
    assert f.getvalue() == "" and capsys.readouterr() == ("a result line\n", "")
