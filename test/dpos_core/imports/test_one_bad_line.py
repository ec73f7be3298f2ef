"""One bad line costs one line: an IMU log whose time column has one glitched
stamp keeps every other line (the longest increasing sequence of stamps); a .pos whose lines are
out of order is sorted, with a count, not cut to the lines after the first reversal."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dpos_core.imports.logs import ImuColumns, increasing_lines, read_imu_csv, read_pos

T0 = 1_700_000_000.0
N = 200
HOUR = 3600.0


def _imu(tmp_path: Path, stamps: list[float]) -> Path:
    p = tmp_path / "imu.csv"
    p.write_text("".join(f"{t:.3f},0,0,9.8,0.01,0,0\n" for t in stamps))
    return p


COLS = ImuColumns(accel=(1, 2, 3), gyro=(4, 5, 6), accel_unit="mps2", gyro_unit="rad_s", counter=None, time=0)
GOOD = [T0 + 0.01 * k for k in range(N)]


def _glitch(*changes: tuple[int, float]) -> list[float]:
    s = list(GOOD)
    for i, dt in changes:
        s[i] += dt
    return s


# (case, stamps, the lines (0-based) that must be dropped): the case, then ours
IMU_CASES = [
    ("one line +1 h", _glitch((50, HOUR)), [50]),
    ("one line -1 h", _glitch((50, -HOUR)), [50]),
    ("the first line +1 h", _glitch((0, HOUR)), [0]),
    ("two lines +1 h and +1 day", _glitch((30, HOUR), (120, 86400.0)), [30, 120]),
    ("a repeated stamp", GOOD[:60] + [GOOD[59]] + GOOD[60:], [60]),
    ("three lines ahead in a row", _glitch((80, HOUR), (81, HOUR), (82, HOUR)), [80, 81, 82]),
]


@pytest.mark.parametrize("case, stamps, dropped", IMU_CASES, ids=[c[0] for c in IMU_CASES])
def test_a_glitched_time_column_costs_its_lines_only(tmp_path: Path, case: str, stamps: list[float], dropped: list[int]) -> None:
    log = read_imu_csv(_imu(tmp_path, stamps), COLS)
    assert len(log) == len(stamps) - len(dropped)
    assert [n - 1 for n, _ in log.skipped] == dropped  # (line numbers are 1-based)
    assert np.all(np.diff(log.t_ns) > 0)
    kept = np.delete(np.array(stamps), dropped)
    np.testing.assert_allclose(log.t_ns * 1e-9, kept, atol=1e-6)


def test_increasing_lines_is_the_longest_increasing_sequence() -> None:
    assert increasing_lines([]).tolist() == []
    assert increasing_lines([1, 2, 3]).all()
    assert increasing_lines([1, 2, 99, 3, 4]).tolist() == [True, True, False, True, True]
    assert increasing_lines([5, 1, 2, 3]).tolist() == [False, True, True, True]
    assert increasing_lines([1, 2, 2, 3]).tolist() == [True, True, False, True]  # a repeat: the earlier line kept


POS_HEADER = ("%  GPST            latitude(deg) longitude(deg) height(m) Q  ns  sdn(m)  sde(m)  sdu(m)  sdne(m) sdeu(m) sdun(m) "
              "age(s) ratio\n")


def _pos(tmp_path: Path, seconds: list[int]) -> Path:
    p = tmp_path / "sol.pos"
    p.write_text(POS_HEADER + "".join(f"2025/08/28 17:{30 + s // 60:02d}:{s % 60:02d}.000 40.0 -105.0 {1600 + s}.0 1 20 "
                                      "0.01 0.02 0.03 0 0 0 0.0 0.0\n" for s in seconds))
    return p


# (case, the seconds of the lines in file order, fixes kept, lines reordered): the issue's, then ours
POS_CASES = [
    ("all reversed", list(range(535, -1, -1)), 536, 535),
    ("one pair swapped", [0, 1, 3, 2, 4, 5], 6, 1),
    ("a block moved to the end", [*range(10, 20), *range(10)], 20, 1),
    ("a repeated line", [0, 1, 2, 2, 3], 4, 0),
]


@pytest.mark.parametrize("case, seconds, kept, reordered", POS_CASES, ids=[c[0] for c in POS_CASES])
def test_pos_lines_out_of_order_are_sorted_and_counted(tmp_path: Path, case: str, seconds: list[int], kept: int, reordered: int) -> None:
    log = read_pos(_pos(tmp_path, seconds))
    assert len(log) == kept and log.reordered == reordered
    assert np.all(np.diff(log.t_ns) > 0)
    np.testing.assert_allclose(log.llh[:, 2], 1600.0 + np.array(sorted(set(seconds))))  # each fix keeps its values
    assert len(log.skipped) == len(seconds) - kept
