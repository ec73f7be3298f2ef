"""[LSFit] Tables 2 and 3: per-antenna RMSE of the array antennas, ours beside the paper's.

Table 2: the antennas with a sub-IMU (No. 1, 3, ..., 11; transfer alignment); Table 3: the
antennas without one (No. 2, 4, ..., 12; the least-squares wing fit).  Rows: latitude, longitude,
height [m], velocity east / north / up [m/s], heading, pitch, roll [deg], RMSE over the steady
flight ([LSFit]: 300 s).  An antenna ``antNN`` of the aircraft file is the paper's No. NN.
"""

from __future__ import annotations

import re

ROWS = (("Latitude (m)", "lat_m"), ("Longitude (m)", "lon_m"), ("Height (m)", "h_m"),
        ("Velocity east (m/s)", "vel_e_mps"), ("Velocity north (m/s)", "vel_n_mps"), ("Velocity up (m/s)", "vel_u_mps"),
        ("Heading (°)", "heading_deg"), ("Pitch (°)", "pitch_deg"), ("Roll (°)", "roll_deg"))

#: [LSFit] Table 2 (transfer alignment), RMSE per antenna No. 1, 3, 5, 7, 9, 11
PAPER_TABLE2: dict[int, dict[str, float]] = {
    n: dict(zip([k for _, k in ROWS], v, strict=True)) for n, v in {
        1: (0.0046, 0.0160, 0.0152, 0.005, 0.004, 0.0039, 0.0080, 0.0015, 0.0013),
        3: (0.0098, 0.0250, 0.0296, 0.006, 0.006, 0.0069, 0.0110, 0.0022, 0.0026),
        5: (0.0304, 0.0418, 0.0324, 0.008, 0.009, 0.0121, 0.0138, 0.0028, 0.0028),
        7: (0.0435, 0.0566, 0.0403, 0.0162, 0.0191, 0.0180, 0.0143, 0.0035, 0.0031),
        9: (0.0530, 0.0647, 0.0517, 0.0175, 0.0220, 0.0235, 0.0147, 0.0042, 0.0044),
        11: (0.0766, 0.0757, 0.0691, 0.0220, 0.0252, 0.0262, 0.0252, 0.0048, 0.0047),
    }.items()}
#: [LSFit] Table 3 (least-squares wing fit), RMSE per antenna No. 2, 4, ..., 12 (as printed; No. 2's
#: latitude 0.0551 and No. 6's north velocity 0.0018 break the trend along the span: likely typos)
PAPER_TABLE3: dict[int, dict[str, float]] = {
    n: dict(zip([k for _, k in ROWS], v, strict=True)) for n, v in {
        2: (0.0551, 0.0188, 0.0199, 0.0046, 0.0056, 0.0051, 0.0090, 0.0019, 0.0021),
        4: (0.0234, 0.0385, 0.0307, 0.0072, 0.0077, 0.0104, 0.0133, 0.0024, 0.0025),
        6: (0.0382, 0.0496, 0.0385, 0.0119, 0.0018, 0.0172, 0.0140, 0.0033, 0.0031),
        8: (0.0501, 0.0608, 0.0479, 0.0174, 0.0204, 0.0206, 0.0160, 0.0040, 0.0043),
        10: (0.0651, 0.0718, 0.0637, 0.0217, 0.0237, 0.0244, 0.0233, 0.0044, 0.0046),
        12: (0.0816, 0.0856, 0.0895, 0.0269, 0.0278, 0.0282, 0.0286, 0.0048, 0.0049),
    }.items()}
PAPER = {**PAPER_TABLE2, **PAPER_TABLE3}


def antenna_number(name: str) -> int | None:
    """The paper's No. of an antenna named ``ant<NN>`` (None for other names)."""
    m = re.fullmatch(r"ant(\d+)", name)
    return int(m.group(1)) if m else None


def _fmt(v: float | None) -> str:
    return "—" if v is None or v != v else f"{v:.4f}"


def table_md(title: str, rmse: dict[str, dict[str, float]], names: list[str], paper: dict[int, dict[str, float]]) -> str:
    """One table: a row per quantity, for every antenna in ``names`` our RMSE and the paper's.

    ``rmse``: ``{antenna: {key: RMSE}}`` (keys of :data:`ROWS`); antennas without a figure show —."""
    head = ["Quantity"]
    for n in names:
        no = antenna_number(n)
        head += [f"{n} ours", f"No.{no} paper" if no is not None else "paper"]
    lines = [f"### {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, key in ROWS:
        row = [label]
        for n in names:
            no = antenna_number(n)
            row += [_fmt(rmse.get(n, {}).get(key)), _fmt(paper.get(no, {}).get(key)) if no is not None else "—"]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def report_md(rmse: dict[str, dict[str, float]], carried: list[str], fitted: list[str], what: str = "") -> str:
    """[LSFit] Tables 2 (``carried``: antennas with a sub-IMU) and 3 (``fitted``) with the paper's columns."""
    parts = [f"## [LSFit] Tables 2 and 3{': ' + what if what else ''}", ""]
    parts.append(table_md("Table 2: antennas with a sub-IMU (transfer alignment)", rmse, carried, PAPER_TABLE2))
    parts.append(table_md("Table 3: antennas without a sub-IMU (least-squares wing fit)", rmse, fitted, PAPER_TABLE3))
    return "\n".join(parts)
