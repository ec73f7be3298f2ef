"""dpos-process's exit status and output directory.

0 when every configured antenna is estimated, 1 when some or all are not (named, with why), 2 for
unusable input or output. Products go to OUT/<session id>/, which must be new unless --overwrite;
with --overwrite the new products replace the old ones only when complete. Disk faults are one
line, exit 2, and leave nothing partial (the earlier products are kept)."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bag_faults import fail_bag_writes_after

from dpos_core.config import config_text
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession
from dpos_ros.cli import process as process_cli
from dpos_ros.devices.sim_streams import session_custom_data, session_streams
from dpos_ros.io import bag, outdir

EXE = Path(sys.executable).parent / "dpos-process"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
SID = "paper_su_seed2"


def _bag(path: Path, drop: tuple[str, ...] = ()) -> Path:
    """20 s of paper_su with both wings (paper_su_pair), without the topics starting with ``drop``."""
    ss = SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 2, 20.0)
    streams = [s for s in session_streams(ss) if not s.topic.startswith(drop)] if drop else session_streams(ss)
    bag.write_streams(path, streams, custom_data=session_custom_data(ss, config_text("aircraft", "paper_su_pair")))
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("process_exit")
    return {"full": _bag(d / "full"), "no_sub": _bag(d / "no_sub", ("/sub_imu/",)),
            "no_sub_l": _bag(d / "no_sub_l", ("/sub_imu/sub_l/",))}


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE), *args, "--method", "ukf"], capture_output=True, text=True, timeout=300)


def _err_lines(r: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in r.stderr.splitlines() if ln.startswith("dpos-process:") and "warning" not in ln]


def test_every_antenna_estimated_is_0(bags, tmp_path):
    r = _run(str(bags["full"]), "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    status = json.loads((tmp_path / "o" / SID / "status.json").read_text())
    assert status["antennas"] == {"ant_r": "estimated", "ant_l": "estimated"}


def test_no_sub_imu_topic_is_1_saying_why(bags, tmp_path):
    r = _run(str(bags["no_sub"]), "--out", str(tmp_path / "o"))
    assert r.returncode == 1, r.stdout + r.stderr
    (line,) = _err_lines(r)
    assert "no antenna was estimated" in line and "ant_r" in line and "ant_l" in line, line
    assert "the recording has no /sub_imu/<name>/imu topic" in line and "Traceback" not in r.stderr
    status = json.loads((tmp_path / "o" / SID / "status.json").read_text())  # the record is still written
    assert all(s.startswith("not estimated") for s in status["antennas"].values())


def test_some_antennas_not_estimated_is_1_naming_them(bags, tmp_path):
    r = _run(str(bags["no_sub_l"]), "--out", str(tmp_path / "o"))
    assert r.returncode == 1, r.stdout + r.stderr
    (line,) = _err_lines(r)
    assert "1 of 2 antennas not estimated" in line and "ant_l" in line and "ant_r" not in line, line
    assert (tmp_path / "o" / SID / "ant_r.csv").is_file()


def test_existing_products_need_overwrite(bags, tmp_path):
    out = tmp_path / "o"
    assert _run(str(bags["no_sub_l"]), "--out", str(out)).returncode == 1
    sdir = out / SID
    before = {p.name: p.read_bytes() for p in sdir.iterdir() if p.is_file()}
    (sdir / "stale.txt").write_text("from an earlier run")

    r = _run(str(bags["full"]), "--out", str(out))
    assert r.returncode == 2, r.stdout + r.stderr
    (line,) = _err_lines(r)
    assert str(sdir) in line and "--overwrite" in line, line
    assert not (sdir / "ant_l.csv").exists() and (sdir / "stale.txt").is_file()  # untouched
    assert {p.name: p.read_bytes() for p in sdir.iterdir() if p.is_file() and p.name != "stale.txt"} == before

    r = _run(str(bags["full"]), "--out", str(out), "--overwrite")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == [SID]  # no temporary sibling left
    assert not (sdir / "stale.txt").exists() and (sdir / "ant_l.csv").is_file()  # replaced, not mixed
    assert json.loads((sdir / "status.json").read_text())["antennas"]["ant_l"] == "estimated"


def _main_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("dpos-process: error")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_write_fault_keeps_the_earlier_products(bags, tmp_path, monkeypatch, capsys, code):
    out = tmp_path / "o"
    assert process_cli.main([str(bags["no_sub_l"]), "--method", "ukf", "--out", str(out)]) == 1
    before = {p.name: p.read_bytes() for p in (out / SID).iterdir() if p.is_file()}
    capsys.readouterr()
    fail_bag_writes_after(monkeypatch, 100, code)
    assert process_cli.main([str(bags["full"]), "--method", "ukf", "--out", str(out), "--overwrite"]) == 2
    line = _main_error(capsys)
    assert os.strerror(code) in line and errno.errorcode[code] in line and str(out / SID) in line, line
    assert "earlier products" in line and "kept" in line
    assert sorted(p.name for p in out.iterdir()) == [SID]  # the temporary directory is gone
    assert {p.name: p.read_bytes() for p in (out / SID).iterdir() if p.is_file()} == before


def test_full_disk_on_a_new_out_leaves_nothing(bags, tmp_path, monkeypatch, capsys):
    keep = tmp_path / "existing"
    keep.mkdir()
    out = keep / "new" / "products"
    fail_bag_writes_after(monkeypatch, 100, errno.ENOSPC)
    assert process_cli.main([str(bags["full"]), "--method", "ukf", "--out", str(out)]) == 2
    line = _main_error(capsys)
    assert "No space left on device (ENOSPC)" in line and "partial products were removed" in line, line
    assert list(keep.iterdir()) == []  # OUT and its parent were created by the run: removed


def test_unwritable_out_is_refused_before_processing(bags, tmp_path, monkeypatch, capsys):
    original = os.open

    def fake_open(path, flags, *args, **kwargs):
        if Path(path).name.startswith(".dpos-write-probe"):
            raise OSError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return original(path, flags, *args, **kwargs)

    monkeypatch.setattr(outdir.os, "open", fake_open)
    read = []
    monkeypatch.setattr(process_cli, "read_session", lambda *a, **k: read.append(1))
    assert process_cli.main([str(bags["full"]), "--out", str(tmp_path / "o")]) == 2
    line = _main_error(capsys)
    assert str(tmp_path / "o") in line and os.strerror(errno.EACCES) in line, line
    assert not read and not (tmp_path / "o").exists()


@pytest.mark.skipif(IS_ROOT, reason="running as root: a chmod 555 directory does not stop root's writes "
                    "(test_unwritable_out_is_refused_before_processing injects the refusal instead)")
def test_chmod_readonly_out_is_refused(bags, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        r = _run(str(bags["full"]), "--out", str(ro / "o"))
        assert r.returncode == 2 and str(ro) in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


@pytest.mark.parametrize(("args", "needle"), [
    (["--seed", "-1"], "--seed must be >= 0"),
    (["--particles", "0"], "--particles must be >= 1"),
    (["--workers", "-1"], "--workers must be >= 0"),
    (["--filter-rate", "0"], "--filter-rate must be > 0"),
    (["--output-rate", "nan"], "--output-rate must be >= 0"),
    (["--initial-attitude-error", "inf"], "--initial-attitude-error must be a finite"),
])
def test_bad_numbers_are_usage_errors(tmp_path, capsys, args, needle):
    with pytest.raises(SystemExit) as e:
        process_cli.main([str(tmp_path / "bag"), "--out", str(tmp_path / "o"), *args])
    assert e.value.code == 2
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_diverged_alignment_is_not_estimated_naming_why(tmp_path, capsys):
    """A sub-IMU whose gyro is in deg/s where rad/s are declared: its transfer alignment diverges
    (dpos_core.ta.guard), so its antenna is "not estimated" with the reason, exit 1, no traceback;
    the other wing's antenna is estimated."""
    from dpos_ros.contract import cdr
    from dpos_ros.contract import conversions as cv
    from dpos_ros.io.streams import TopicStream

    ss = SimulatedSession(load_scenario("paper_su", aircraft="paper_su_pair"), 2, 20.0)
    streams = []
    for s in session_streams(ss):
        if s.topic == "/sub_imu/sub_l/imu":
            lay = cdr.layout("imu", cv.sub_imu_frame("sub_l"))
            t_ns, vals = cdr.decode(lay, s.rows)
            vals[:, 13:16] *= 180.0 / np.pi  # deg/s written as rad/s
            s = TopicStream(s.topic, s.msgtype, t_ns, rows=cdr.encode(lay, t_ns, vals), qos=s.qos)
        streams.append(s)
    b = tmp_path / "degps"
    bag.write_streams(b, streams, custom_data=session_custom_data(ss, config_text("aircraft", "paper_su_pair")))
    assert process_cli.main([str(b), "--method", "ukf", "--workers", "1", "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "diverged" in err, err
    status = json.loads((tmp_path / "o" / SID / "status.json").read_text())
    assert status["antennas"]["ant_r"] == "estimated"
    assert status["antennas"]["ant_l"].startswith("not estimated") and "diverged" in status["antennas"]["ant_l"], status
