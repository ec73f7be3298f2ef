"""Disk faults and unusable output directories in dpos-sim and dpos-process.

An output location that cannot be written is refused before any work (exit 2, one line naming
it); an OSError while writing (ENOSPC, EACCES, EROFS) is one line naming the path and the errno
text, exit 2, and what the run created is removed - nothing that existed before. The full disk is
injected (a writer that fails after N messages); a chmod'ed directory does not stop root, so that
variant is skipped as root while the injected one always runs."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from bag_faults import fail_bag_writes_after

from dpos_ros.cli import sim as sim_cli
from dpos_ros.io import outdir

IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def _refuse_probe(monkeypatch: pytest.MonkeyPatch, code: int) -> None:
    """Creating a file in the output's directory fails with ``code`` (a read-only mount, EROFS)."""
    original = os.open

    def fake_open(path, flags, *args, **kwargs):
        if Path(path).name.startswith(".dpos-write-probe"):
            raise OSError(code, os.strerror(code), str(path))
        return original(path, flags, *args, **kwargs)

    monkeypatch.setattr(outdir.os, "open", fake_open)


def _one_line(err: str, prog: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), err
    assert "Traceback" not in err
    return lines[0]


SIM = ["--scenario", "paper_su", "--duration", "5"]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EACCES])
def test_sim_write_fault_removes_its_partial_bag(tmp_path, monkeypatch, capsys, code):
    keep = tmp_path / "existing"
    keep.mkdir()
    (keep / "precious.txt").write_text("x")
    out = keep / "new" / "deeper" / "bag"
    fail_bag_writes_after(monkeypatch, 1000, code)
    assert sim_cli.main([*SIM, "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err, "dpos-sim")
    assert os.strerror(code) in line and errno.errorcode[code] in line and str(out) in line, line
    assert "removed the partial output" in line
    assert not (keep / "new").exists()  # the bag and the ancestors this run created
    assert sorted(p.name for p in keep.iterdir()) == ["precious.txt"]  # what existed is untouched


def test_sim_refuses_an_unwritable_out_before_simulating(tmp_path, monkeypatch, capsys):
    _refuse_probe(monkeypatch, errno.EROFS)
    called = []
    monkeypatch.setattr(sim_cli, "session_streams", lambda *a, **k: called.append(1))
    out = tmp_path / "ro" / "bag"
    assert sim_cli.main([*SIM, "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err, "dpos-sim")
    assert str(out) in line and os.strerror(errno.EROFS) in line, line
    assert not called and not (tmp_path / "ro").exists()


@pytest.mark.skipif(IS_ROOT, reason="running as root: a chmod 555 directory does not stop root's writes "
                    "(the injected EROFS/EACCES variants above cover the refusal)")
def test_sim_refuses_a_chmod_readonly_directory(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert sim_cli.main([*SIM, "--out", str(ro / "bag")]) == 2
        line = _one_line(capsys.readouterr().err, "dpos-sim")
        assert str(ro) in line and os.strerror(errno.EACCES) in line, line
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_sim_refuses_a_file_as_parent(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert sim_cli.main([*SIM, "--out", str(f / "bag")]) == 2
    line = _one_line(capsys.readouterr().err, "dpos-sim")
    assert f"{f} is not a directory" in line
    assert f.read_text() == "x"
