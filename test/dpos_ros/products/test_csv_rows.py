"""The antenna CSV's rows (products.write.write_csv_rows, a numba kernel): the text of
``np.savetxt`` with the same printf formats, but the stamp exact from the integer nanoseconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dpos_ros.products.write import write_csv_rows

FORMATS = (("f", 10), ("f", 4), ("f", 0), ("e", 4), ("e", 1), ("d", 0))
PRINTF = ["%.10f", "%.4f", "%.0f", "%.4e", "%.1e", "%d"]


def _cells(path: Path) -> list[list[str]]:
    return [line.split(",") for line in path.read_text().splitlines()[1:]]


def test_rows_are_savetxt_text_and_the_stamp_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    n = 5000
    t_ns = 1_700_000_000_123_456_789 + np.arange(n, dtype=np.int64) * 5_000_001
    cols = np.column_stack([rng.normal(34.0, 1.0, n), rng.normal(0.0, 3000.0, n), rng.normal(0.0, 50.0, n),
                            rng.normal(0.0, 1.0, n) * 10.0 ** rng.integers(-12, 6, n),
                            rng.normal(0.0, 1.0, n) * 10.0 ** rng.integers(-3, 3, n), rng.integers(0, 2**20, n)])
    cols[:8, 3] = [0.0, -0.0, np.nan, np.inf, -np.inf, 9.99996e-5, 9.99994e-5, 1.0]
    cols[:3, 1] = [-0.00001, 0.00004, -2.5]
    write_csv_rows(tmp_path / "k.csv", "h", t_ns, cols, FORMATS)
    np.savetxt(tmp_path / "s.csv", cols, delimiter=",", header="h", comments="", fmt=PRINTF)
    ours, ref = _cells(tmp_path / "k.csv"), _cells(tmp_path / "s.csv")
    assert len(ours) == n and (tmp_path / "k.csv").read_text().startswith("h\n")
    for k in (0, 1, n - 1):  # the stamp: seconds and 9 decimals from the integer, not through a float
        s, ns = divmod(int(t_ns[k]), 1_000_000_000)
        assert ours[k][0] == f"{s}.{ns:09d}"
    same = sum(a == b for row_a, row_b in zip(ours, ref, strict=True) for a, b in zip(row_a[1:], row_b, strict=True))
    assert same >= cols.size - 5  # printf rounds the exact binary value: a near-tie may differ in its last digit
    got = np.array([[float(c) for c in row[1:]] for row in ours])
    want = np.array([[float(c) for c in row] for row in ref])
    np.testing.assert_array_equal(got[~np.isfinite(want)], want[~np.isfinite(want)].astype(str).astype(float))
    ok = np.isfinite(want)
    ulp = np.array([1e-10, 1e-4, 1.0, 0.0, 0.0, 1.0])[None, :] + np.abs(want) * np.array([0, 0, 0, 1e-4, 1e-1, 0])[None, :]
    assert np.all(np.abs(got[ok] - want[ok]) <= np.broadcast_to(ulp, want.shape)[ok] * 1.0001)
    assert ours[1][4] == "-0.0000e+00" and ours[2][4] == "nan" and ours[3][4] == "inf" and ours[4][4] == "-inf"
    assert ours[0][2] == "-0.0000" and ours[5][4] == ref[5][3] == "1.0000e-04"


def _near_tie(v: float, kind: str, dec: int) -> bool:
    """``v``'s scaled value within 1e-6 of a rounding tie (printf and the kernel may differ there)."""
    a = abs(v)
    if kind == "e" and a > 0:
        a = a / 10.0 ** np.floor(np.log10(a))
    x = a * 10.0**dec
    return abs(x - np.floor(x) - 0.5) < 1e-6 * max(1.0, x * 1e-9)


def test_numbers_are_pythons_formatting() -> None:
    """Each number as Python's ``%`` formats it (random magnitudes, signs, rounding carries, powers
    of ten, zeros of both signs, NaN, infinities), except at a near-tie."""
    from dpos_ros.products.write import csv_rows

    rng = np.random.default_rng(11)
    formats = (("f", 10), ("f", 4), ("f", 5), ("f", 6), ("f", 0), ("f", 1), ("e", 4), ("e", 1), ("e", 0), ("d", 0))
    n = 20000
    mag = np.array([10.0 ** rng.uniform(-12, 8, n) if k == "f" and d <= 6 else 10.0 ** rng.uniform(-12, 8 - d // 2, n) if k == "f"
                    else 10.0 ** rng.integers(-300, 300, n).astype(float) * rng.uniform(1, 10, n) if k == "e" else rng.integers(0, 2**40, n)
                    for k, d in formats]).T
    cols = rng.choice([-1.0, 1.0], mag.shape) * mag
    edge = [0.99999999995, 0.999999999996, 9.99995e-5, 9.99994e-5, 9.9999999e-1, 1.0, 10.0, 1e-300, 1e300, 123456.99999996,
            0.0, -0.0, np.nan, np.inf, -np.inf, -0.4, 0.5, 2.5, 1e15 * (1 - 2**-52), 1e-5, 1e5]
    for j, (k, _) in enumerate(formats):
        e = [v for v in edge if k != "f" or not np.isfinite(v) or abs(v) < 1e8] if k != "d" else [0.0, 7.0, 2.0**40, np.nan]
        cols[: len(e), j] = e
    cols[:, -1] = np.where(np.isfinite(cols[:, -1]), np.abs(np.round(cols[:, -1])), cols[:, -1])
    t_ns = rng.integers(-(2**62), 2**62, n)
    lines = csv_rows(t_ns, cols, formats).decode().splitlines()
    assert len(lines) == n
    differ = 0
    for i, line in enumerate(lines):
        cells = line.split(",")
        s, ns = divmod(abs(int(t_ns[i])), 1_000_000_000)
        assert cells[0] == ("-" if t_ns[i] < 0 else "") + f"{s}.{ns:09d}"
        for j, (k, d) in enumerate(formats):
            v = float(cols[i, j])
            want = f"{v:f}" if not np.isfinite(v) else f"{int(v)}" if k == "d" else format(v, f".{d}{k}")
            if cells[j + 1] != want:
                assert _near_tie(v, k, d), (i, j, v, cells[j + 1], want)
                differ += 1
    assert differ <= 20  # the edge values put at ties, and a few random ones


def test_log10_floor_starts_are_where_floor_log10_steps() -> None:
    """The kernel's exponent search (no ``log10`` per number): each start is the first double whose
    ``floor(log10)`` reaches its exponent, checked against libm's ``log10`` on the neighbouring doubles."""
    import math

    from dpos_ros.products import _csv_kernel as K

    starts = K.log10_floor_starts()
    for e in range(-323, 309):
        s = float(starts[e - K.E_MIN])
        assert math.floor(math.log10(s)) >= e
        below = s
        for _ in range(50):
            below = math.nextafter(below, 0.0)
            if below == 0.0:
                break
            assert math.floor(math.log10(below)) < e, (e, s)
    assert np.all(np.isinf(starts[309 - K.E_MIN:])) and starts[0] == 5e-324
    pow10 = K.pow10_table()
    assert pow10[-K.E_MIN] == 1.0 and pow10[3 - K.E_MIN] == 1000.0


def test_the_buffer_is_kept_between_blocks() -> None:
    """:class:`CsvRows`: blocks of text one after another (the exponent search's state carried over)
    are the text of all the rows at once."""
    from dpos_ros.products.write import CsvRows, csv_rows

    rng = np.random.default_rng(3)
    cols = rng.normal(0.0, 1.0, (3000, 6)) * 10.0 ** rng.uniform(-9, 3, (3000, 6))
    cols[:, 5] = np.abs(np.round(cols[:, 5]))
    t_ns = np.arange(3000, dtype=np.int64) * 5_000_000
    w = CsvRows(FORMATS)
    parts = [w.text(t_ns[a:a + 700], cols[a:a + 700]).tobytes() for a in range(0, 3000, 700)]
    assert b"".join(parts) == csv_rows(t_ns, cols, FORMATS)


def test_numbers_beyond_int64_are_written_as_exponents() -> None:
    """A %f or %d value whose digits do not fit an int64 (a diverged solution: 1e15 m/s at 5
    decimals) is written as %e with the column's decimals: still ASCII, still that number."""
    from dpos_ros.products.write import csv_rows

    formats = (("f", 5), ("f", 4), ("d", 0), ("f", 5))
    cols = np.array([[1e15, -2.5e15, 1e19, 3.0], [-1e300, 9.1e14, 12.0, -0.5]])
    text = csv_rows(np.array([0, 5], dtype=np.int64), cols, formats)
    assert all(b < 128 for b in text)
    lines = text.decode("ascii").splitlines()
    assert lines[0].split(",")[1:] == ["1.00000e+15", "-2.5000e+15", "1e+19", "3.00000"]
    assert lines[1].split(",")[1:] == ["-1.00000e+300", "910000000000000.0000", "12", "-0.50000"]
