"""dpos_core.geoid: the geoid grids a surveyor has (GeographicLib .pgm, NOAA/PROJ .gtx), written
here with a known undulation field: exact at the nodes, bilinear between them, wrapped across the
0/360 deg seam, NaN outside a regional grid, and files that are not such grids refused."""

from __future__ import annotations

import pickle
import struct
from pathlib import Path

import numpy as np
import pytest

from dpos_core.errors import InputError
from dpos_core.geoid import GTX_NULL, load_geoid

RNG = np.random.default_rng(7)


def write_pgm(path: Path, samples: np.ndarray, offset: float, scale: float) -> Path:
    """A GeographicLib geoid PGM of ``samples`` (H, W) uint16, row 0 at +90 deg, column 0 at 0 deg."""
    h, w = samples.shape
    head = (f"P5\n# Geoid file in PGM format for the GeographicLib::Geoid class\n# Description test field\n"
            f"# Offset {offset}\n# Scale {scale}\n# Origin 90N 0E\n{w} {h}\n65535\n").encode()
    path.write_bytes(head + samples.astype(">u2").tobytes())
    return path


def write_gtx(path: Path, values: np.ndarray, lat0: float, lon0: float, dlat: float, dlon: float) -> Path:
    """A .gtx grid of ``values`` (rows south to north, columns west to east) [m]."""
    rows, cols = values.shape
    path.write_bytes(struct.pack(">4d2i", lat0, lon0, dlat, dlon, rows, cols) + values.astype(">f4").tobytes())
    return path


def N(grid, lat_deg, lon_deg):
    return grid.undulation(np.deg2rad(np.atleast_1d(lat_deg)), np.deg2rad(np.atleast_1d(lon_deg)))


@pytest.fixture()
def pgm(tmp_path: Path):
    """A global 30 deg x 45 deg grid (7 rows 90..-90, 8 columns 0..315) of random samples."""
    s = RNG.integers(0, 65535, size=(7, 8))
    return load_geoid(write_pgm(tmp_path / "test-30.pgm", s, -108.0, 0.003)), -108.0 + 0.003 * s


def test_pgm_nodes_between_and_the_seam(pgm) -> None:
    g, v = pgm  # v[i, j]: latitude 90 - 30 i, longitude 45 j
    lat = 90 - 30 * np.arange(7)
    for i in range(7):
        for j in range(8):
            assert N(g, lat[i], 45 * j)[0] == pytest.approx(v[i, j], abs=1e-9)
    # between nodes: a quarter of the way south from row 2, 60 % east of column 3
    want = (0.75 * (0.4 * v[2, 3] + 0.6 * v[2, 4]) + 0.25 * (0.4 * v[3, 3] + 0.6 * v[3, 4]))
    assert N(g, 30 - 7.5, 135 + 27)[0] == pytest.approx(want, abs=1e-9)
    # across the seam: between column 7 (315 deg) and column 0 (360 = 0 deg), any longitude convention
    want = 0.5 * (0.2 * v[1, 7] + 0.8 * v[1, 0]) + 0.5 * (0.2 * v[2, 7] + 0.8 * v[2, 0])
    for lon in (351.0, -9.0, 711.0):
        assert N(g, 45.0, lon)[0] == pytest.approx(want, abs=1e-9)
    assert np.isfinite(N(g, [-90.0, 90.0], [0.0, 359.99])).all()  # the poles and the last column are covered


def test_gtx_global_wraps_and_regional_covers_its_extent(tmp_path: Path) -> None:
    # global, PROJ's egm96_15.gtx layout: longitude -180..180 (the last column repeats the first)
    v = RNG.normal(0.0, 30.0, size=(7, 9))
    v[:, -1] = v[:, 0]
    g = load_geoid(write_gtx(tmp_path / "global.gtx", v, -90.0, -180.0, 30.0, 45.0))
    assert g.period == 8
    assert N(g, 30.0, 0.0)[0] == pytest.approx(v[4, 4], abs=1e-5)
    want = 0.5 * v[4, 7] + 0.5 * v[4, 0]  # 157.5 .. 180 = -180 deg
    assert N(g, 30.0, 180.0 - 22.5)[0] == pytest.approx(want, abs=1e-5)
    assert N(g, 30.0, 180.0 + 22.5)[0] == pytest.approx(0.5 * v[4, 0] + 0.5 * v[4, 1], abs=1e-5)
    # regional: 30..40 N, 100..120 E at 5 deg; outside it (and on a node without value) NaN
    r = RNG.normal(-20.0, 5.0, size=(3, 5))
    r[2, 4] = GTX_NULL
    g = load_geoid(write_gtx(tmp_path / "region.gtx", r, 30.0, 100.0, 5.0, 5.0))
    assert g.period == 0
    assert N(g, 32.5, 102.5)[0] == pytest.approx(r[:2, :2].mean(), abs=1e-5)
    got = N(g, [29.9, 35.0, 35.0, 38.0], [105.0, 99.9, 120.1, 118.0])
    assert np.isnan(got).all()  # south of it, west, east, and the cell of the null node
    assert pickle.loads(pickle.dumps(g)).samples.shape == (3, 5)  # (pickled as its file, for the workers)


def test_files_that_are_not_geoid_grids_are_refused(tmp_path: Path) -> None:
    text = tmp_path / "notes.pgm"
    text.write_text("a geoid, honestly\n")
    bad_size = write_gtx(tmp_path / "cut.gtx", np.zeros((3, 3)), 0.0, 0.0, 1.0, 1.0)
    bad_size.write_bytes(bad_size.read_bytes()[:-4])
    bad_head = tmp_path / "nan.gtx"
    bad_head.write_bytes(struct.pack(">4d2i", float("nan"), 0.0, 1.0, 1.0, 2, 2) + bytes(16))
    plain_pgm = tmp_path / "photo.pgm"
    plain_pgm.write_bytes(b"P5\n2 2\n255\n" + bytes(4))
    no_meta = tmp_path / "nometa.pgm"
    no_meta.write_bytes(b"P5\n2 2\n65535\n" + bytes(8))
    for path, why in ((text, "not a GeographicLib"), (bad_size, "its header says"), (bad_head, "not a .gtx grid"),
                      (plain_pgm, "16-bit"), (no_meta, "Offset"), (tmp_path / "missing.gtx", "geoid grid")):
        with pytest.raises(InputError, match=why) as e:
            load_geoid(path)
        assert "\n" not in str(e.value)
