"""The antenna CSV's rows (products.ta.write_csv_rows, a numba kernel): the text of
``np.savetxt`` with the same printf formats, but the stamp exact from the integer nanoseconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dpos_ros.products.ta import write_csv_rows

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
