"""[LSFit] Tables 2 and 3 layout: the paper's figures as printed, ours beside them."""

from __future__ import annotations

from dpos_ros.products import lsfit_tables as L


def test_paper_figures_as_printed() -> None:
    assert sorted(L.PAPER_TABLE2) == [1, 3, 5, 7, 9, 11] and sorted(L.PAPER_TABLE3) == [2, 4, 6, 8, 10, 12]
    assert L.PAPER_TABLE2[1]["lat_m"] == 0.0046 and L.PAPER_TABLE2[11]["heading_deg"] == 0.0252
    assert L.PAPER_TABLE3[12]["h_m"] == 0.0895 and L.PAPER_TABLE3[2]["roll_deg"] == 0.0021
    # the paper's errors grow along the span (heading, Table 2 and 3)
    h = [L.PAPER[n]["heading_deg"] for n in range(1, 13)]
    assert all(b >= a for a, b in zip(h[::2], h[2::2], strict=False))


def test_report_puts_ours_beside_the_papers() -> None:
    rmse = {"ant01": {"lat_m": 0.0012, "heading_deg": 0.0031}, "ant02": {"lat_m": 0.0021}}
    md = L.report_md(rmse, ["ant01"], ["ant02"], "paper_wing")
    t2, t3 = md.split("### Table 3")
    assert "| Latitude (m) | 0.0012 | 0.0046 |" in t2 and "| Heading (°) | 0.0031 | 0.0080 |" in t2
    assert "| Latitude (m) | 0.0021 | 0.0551 |" in t3 and "| Heading (°) | — | 0.0090 |" in t3
    assert L.antenna_number("ant07") == 7 and L.antenna_number("left_tip") is None
