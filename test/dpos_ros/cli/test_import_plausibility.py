"""dpos-import refuses a log whose values show a unit or format mistake, in one line with exit 2
(dpos_core.plausibility); the honest walk_0827 log is imported (test_import.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from repo_paths import REPO

from dpos_ros.cli import import_

WALK = REPO / "data" / "real" / "walk_0827"
IMU_CSV, TAG, POS = WALK / "imu_1730.csv", WALK / "imu_1730.csv.tag", WALK / "gnss_1730_sf.pos"
G0_MPS2 = 9.80665
DEG = 0.017453292519943295


def _convert_imu(tmp: Path, accel: float = 1.0, gyro: float = 1.0) -> Path:
    """walk_0827's IMU CSV with its accelerometer columns x ``accel`` and its gyro columns x ``gyro``."""
    out = tmp / "imu.csv"
    lines = []
    for line in IMU_CSV.read_text().splitlines():
        p = line.split(",")
        if len(p) == 7:
            try:
                v = [float(x) for x in p[:6]]
            except ValueError:
                lines.append(line)
                continue
            p[:6] = [f"{x * accel:.6g}" for x in v[:3]] + [f"{x * gyro:.6g}" for x in v[3:]]
        lines.append(",".join(p))
    out.write_text("\n".join(lines) + "\n")
    return out


def _run(capsys: pytest.CaptureFixture[str], tmp: Path, imu: Path = IMU_CSV, pos: Path | None = POS) -> tuple[int, str]:
    argv = ["--imu", str(imu), "--tag", str(TAG), "--out", str(tmp / "out"), "--quiet"]
    argv += ["--pos", str(pos)] if pos is not None else []
    rc = import_.main(argv)
    err = capsys.readouterr().err
    return rc, err


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(("accel", "gyro", "pos", "says"), [
    (G0_MPS2, 1.0, False, r"--imu .*imu\.csv: median \|f\| .* \(9\.\d+ g\).*looks like m/s\^2 read as g.*--accel-unit g"),
    (1.0 / G0_MPS2, 1.0, False, r"looks like g read as m/s\^2"),
    (1.0, 1.0 / DEG, False, r"99th percentile of \|omega\|.*looks like deg/s read as rad/s"),
    (1.0, DEG, True, r"--imu .*: 90th percentile of \|omega\| is 1\.\d+ deg/s against \d+\.\d+ deg/s of the course of --pos.*"
                     r"looks like rad/s read as deg/s .*--gyro-unit deg_s"),
])
def test_imu_log_in_the_wrong_unit_is_refused_in_one_line(tmp_path, capsys, accel, gyro, pos, says):
    imu = _convert_imu(tmp_path, accel, gyro)
    rc, err = _run(capsys, tmp_path, imu, POS if pos else None)
    assert rc == 2
    assert re.search(says, _one_line(err)), err
    assert not (tmp_path / "out").exists()


def _pos_lines(transform) -> list[str]:
    return [line if line.startswith("%") else transform(line) for line in POS.read_text().splitlines()]


def test_pos_with_zero_sigmas_is_refused(tmp_path, capsys):
    def zero(line: str) -> str:
        p = line.split()
        p[7:10] = ["0.0000", "0.0000", "0.0000"]
        return " ".join(p)
    pos = tmp_path / "zero.pos"
    pos.write_text("\n".join(_pos_lines(zero)) + "\n")
    rc, err = _run(capsys, tmp_path, pos=pos)
    assert rc == 2 and "not > 0 (an exact fix claimed)" in _one_line(err)


def _dms(x: float) -> str:
    s = "-" if x < 0 else ""
    x = abs(x)
    d, m = int(x), int((x - int(x)) * 60)
    return f"{s}{d} {m:02d} {(x - d - m / 60) * 3600:07.4f}"


def test_dms_pos_without_its_header_is_refused(tmp_path, capsys):
    def dms(line: str) -> str:
        p = line.split()
        return " ".join([p[0], p[1], _dms(float(p[2])), _dms(float(p[3])), *p[4:]])
    pos = tmp_path / "dms.pos"
    pos.write_text("\n".join(x for x in _pos_lines(dms) if not x.startswith("%")) + "\n")
    rc, err = _run(capsys, tmp_path, pos=pos)
    assert rc == 2 and "dms solution without its header" in _one_line(err)


def test_fixes_of_another_day_are_refused(tmp_path, capsys):
    def next_day(line: str) -> str:
        return line.replace("2025/08/28", "2025/08/29", 1)
    pos = tmp_path / "day.pos"
    pos.write_text("\n".join(_pos_lines(next_day)) + "\n")
    rc, err = _run(capsys, tmp_path, pos=pos)
    line = _one_line(err)
    assert rc == 2 and "do not overlap" in line and "another day" in line


def _install_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("test_import_install_helpers", Path(__file__).parent / "test_import_install.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize(("col", "scale", "says"), [
    (slice(1, 4), DEG, r"--sub left \(.*\): 90th percentile of \|omega\| .* of the --nav solution's attitude .*looks like rad/s read as deg/s"),
    (slice(1, 4), 1.0 / DEG, r"looks like deg/s read as rad/s"),
    (slice(4, 7), 1.0 / G0_MPS2, r"--sub left \(.*\): median \|f\| .*looks like g read as m/s\^2"),
])
def test_sub_log_in_the_wrong_unit_is_refused_in_one_line(tmp_path, capsys, col, scale, says):
    mod = _install_module()
    nav, sub = tmp_path / "nav.csv", tmp_path / "left.csv"
    mod._write_nav(nav)
    mod._write_sub(sub)
    lines = sub.read_text().splitlines()
    for i in range(1, len(lines)):
        p = lines[i].split(",")
        p[col] = [f"{float(x) * scale:.7g}" for x in p[col]]
        lines[i] = ",".join(p)
    sub.write_text("\n".join(lines) + "\n")
    rc = import_.main(mod._argv(nav, sub, tmp_path / "out", "--quiet"))
    err = capsys.readouterr().err
    assert rc == 2 and re.search(says, _one_line(err)), err
