"""Geoid undulation N from a grid file the user gives: height above the geoid H = h - N (h the
WGS-84 ellipsoidal height).  No model is built in: without a file the products say their heights
are ellipsoidal (docs/design.md "Session products"; docs/transfer_alignment.md "Heights above
the geoid").

Two common grid formats, read as they are distributed (the file is memory-mapped: an EGM2008 1'
grid of 0.5 GB costs only the pages the track touches):

- GeographicLib's ``.pgm`` (``geographiclib-get-geoids``: ``egm84-15.pgm``, ``egm96-5.pgm``,
  ``egm2008-1.pgm``, ...): a binary PGM (``P5``), header comments ``# Offset <m>`` and
  ``# Scale <m>``, big-endian 16-bit samples, N = Offset + Scale * sample; row 0 at latitude
  +90 deg down to -90 deg (``H`` rows, spacing 180 / (H - 1)), column 0 at longitude 0 deg
  eastwards (``W`` columns, spacing 360 / W, the last one wrapping to the first).
- NOAA / PROJ ``.gtx`` (VDatum; ``egm96_15.gtx``, national geoid models): a 40-byte big-endian
  header (lower-left latitude, lower-left longitude, latitude spacing, longitude spacing [deg] as
  float64, rows, columns as int32), then rows x columns big-endian float32 [m], south to north,
  each row west to east; -88.8888 is "no value".  A grid whose columns span 360 deg wraps in
  longitude (any longitude convention, 0..360 or -180..180); a regional one covers its extent.

The undulation is interpolated bilinearly in latitude and longitude between the four grid
nodes around the point (exact at the nodes).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.errors import InputError
from dpos_core.units import FloatArray

#: the formats :func:`load_geoid` reads (file name suffixes)
GEOID_FORMATS = (".pgm", ".gtx")
#: the "no value" of a .gtx grid
GTX_NULL = -88.8888
_GTX_HEADER = struct.Struct(">4d2i")


@dataclass(frozen=True)
class GeoidGrid:
    """A geoid grid: ``samples`` (rows, cols) with ``N = offset + scale * sample`` [m]; row ``i``
    at latitude ``lat0_deg + i * dlat_deg`` (``dlat_deg`` < 0 for rows from the north), column
    ``j`` at longitude ``lon0_deg + j * dlon_deg``; ``period`` the columns of 360 deg when the grid
    wraps in longitude, else 0; ``null`` a sample value meaning "no value" (or None)."""

    path: Path
    name: str
    samples: NDArray
    lat0_deg: float
    dlat_deg: float
    lon0_deg: float
    dlon_deg: float
    offset: float = 0.0
    scale: float = 1.0
    period: int = 0
    null: float | None = None

    def __reduce__(self) -> tuple:
        """Pickled as its file (a worker process maps it again), not its samples."""
        return (load_geoid, (self.path,))

    def extent_text(self) -> str:
        """Its latitude and longitude span, for messages."""
        rows, cols = self.samples.shape
        lats = sorted((self.lat0_deg, self.lat0_deg + (rows - 1) * self.dlat_deg))
        if self.period:
            return f"latitude {lats[0]:g}..{lats[1]:g} deg, every longitude"
        return (f"latitude {lats[0]:g}..{lats[1]:g} deg, longitude {self.lon0_deg:g}.."
                f"{self.lon0_deg + (cols - 1) * self.dlon_deg:g} deg")

    def undulation(self, lat_rad: FloatArray, lon_rad: FloatArray) -> FloatArray:
        """N [m] (n,) at the points ``lat_rad``, ``lon_rad`` (n,) [rad], bilinear between the four
        nodes around each point; NaN where the grid does not cover the point (outside its
        extent, or a node without value)."""
        lat = np.rad2deg(np.atleast_1d(np.asarray(lat_rad, dtype=float)))
        lon = np.rad2deg(np.atleast_1d(np.asarray(lon_rad, dtype=float)))
        rows, cols = self.samples.shape
        y = (lat - self.lat0_deg) / self.dlat_deg
        x = (lon - self.lon0_deg) / self.dlon_deg
        if self.period:
            x = np.mod(x, self.period)
        ok = np.isfinite(x) & np.isfinite(y) & (y >= 0) & (y <= rows - 1) & (x >= 0) & (x <= (self.period or cols - 1))
        y, x = np.where(ok, y, 0.0), np.where(ok, x, 0.0)
        i0 = np.minimum(np.floor(y).astype(np.intp), max(rows - 2, 0))
        j0 = np.minimum(np.floor(x).astype(np.intp), (self.period or cols - 1) - 1 if cols > 1 else 0)
        fy, fx = y - i0, x - j0
        i1 = np.minimum(i0 + 1, rows - 1)
        j1 = (j0 + 1) % self.period if self.period else np.minimum(j0 + 1, cols - 1)
        s = self.samples
        corners = np.stack([s[i0, j0], s[i0, j1], s[i1, j0], s[i1, j1]]).astype(float)  # (4, n)
        if self.null is not None:
            corners[np.isclose(corners, self.null, rtol=0.0, atol=1e-4)] = np.nan
        n = self.offset + self.scale * ((1 - fy) * ((1 - fx) * corners[0] + fx * corners[1]) + fy * ((1 - fx) * corners[2] + fx * corners[3]))
        return np.where(ok, n, np.nan)


def load_geoid(path: str | Path) -> GeoidGrid:
    """The grid of ``path`` (module docstring: ``.pgm`` or ``.gtx``, told by the file's content);
    :class:`~dpos_core.errors.InputError` (one line) for a file that is not such a grid."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise InputError(f"geoid grid {path}: {e.strerror or e}") from None
    if head.startswith(b"P5"):
        return _load_pgm(path, head)
    if path.suffix.lower() == ".gtx":
        return _load_gtx(path, head)
    raise InputError(f"geoid grid {path}: not a GeographicLib .pgm (P5) nor a NOAA/PROJ .gtx grid")


def _load_pgm(path: Path, head: bytes) -> GeoidGrid:
    """A GeographicLib geoid ``.pgm`` (module docstring)."""
    fields: list[bytes] = []
    meta: dict[str, float] = {}
    pos = 2
    while len(fields) < 3:
        while pos < len(head) and head[pos:pos + 1].isspace():
            pos += 1
        if pos >= len(head):
            raise InputError(f"geoid grid {path}: truncated PGM header")
        if head[pos:pos + 1] == b"#":
            end = head.find(b"\n", pos)
            end = len(head) if end < 0 else end
            words = head[pos + 1:end].decode("ascii", "replace").split()
            if len(words) >= 2 and words[0] in ("Offset", "Scale"):
                try:
                    meta[words[0]] = float(words[1])
                except ValueError:
                    raise InputError(f"geoid grid {path}: bad PGM {words[0]} {words[1]!r}") from None
            pos = end + 1
            continue
        end = pos
        while end < len(head) and not head[end:end + 1].isspace():
            end += 1
        fields.append(head[pos:end])
        pos = end
    pos += 1  # the one whitespace after the maximum value
    try:
        cols, rows, maxval = (int(v) for v in fields)
    except ValueError:
        raise InputError(f"geoid grid {path}: bad PGM size {b' '.join(fields)!r}") from None
    if maxval != 65535 or cols < 2 or rows < 2:
        raise InputError(f"geoid grid {path}: a geoid PGM has 16-bit samples (maximum 65535) on at least 2 x 2 nodes, "
                         f"this one {cols} x {rows}, maximum {maxval}")
    if "Offset" not in meta or "Scale" not in meta:
        raise InputError(f"geoid grid {path}: a PGM without '# Offset' and '# Scale' is not a GeographicLib geoid grid")
    samples = _map(path, ">u2", pos, rows, cols)
    return GeoidGrid(path, path.name, samples, 90.0, -180.0 / (rows - 1), 0.0, 360.0 / cols,
                     meta["Offset"], meta["Scale"], period=cols)


def _load_gtx(path: Path, head: bytes) -> GeoidGrid:
    """A NOAA / PROJ ``.gtx`` grid (module docstring)."""
    if len(head) < _GTX_HEADER.size:
        raise InputError(f"geoid grid {path}: shorter than a .gtx header")
    lat0, lon0, dlat, dlon, rows, cols = _GTX_HEADER.unpack(head[:_GTX_HEADER.size])
    if not (all(math.isfinite(v) for v in (lat0, lon0, dlat, dlon)) and dlat > 0 and dlon > 0 and rows >= 2 and cols >= 2
            and -90.0 <= lat0 and lat0 + (rows - 1) * dlat <= 90.0 + 1e-6 and (cols - 1) * dlon <= 360.0 + dlon + 1e-6):
        raise InputError(f"geoid grid {path}: not a .gtx grid (header: latitude {lat0:g} + {rows} x {dlat:g}, "
                         f"longitude {lon0:g} + {cols} x {dlon:g})")
    per = 360.0 / dlon
    period = int(round(per)) if abs(per - round(per)) < 1e-6 and cols >= round(per) else 0
    samples = _map(path, ">f4", _GTX_HEADER.size, rows, cols)
    return GeoidGrid(path, path.name, samples, lat0, dlat, lon0, dlon, period=period, null=GTX_NULL)


def _map(path: Path, dtype: str, offset: int, rows: int, cols: int) -> NDArray:
    """The (rows, cols) samples of ``path`` from byte ``offset``, memory-mapped; InputError when
    the file's size is not that of the header's grid."""
    need = offset + rows * cols * np.dtype(dtype).itemsize
    size = path.stat().st_size
    if size != need:
        raise InputError(f"geoid grid {path}: {size} bytes, its header says {rows} x {cols} samples ({need} bytes)")
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=(rows, cols))
