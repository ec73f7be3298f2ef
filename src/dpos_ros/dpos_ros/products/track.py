"""Antenna tracks a GIS opens directly: GeoJSON (RFC 7946), one LineString per antenna.

Coordinates are ``[longitude, latitude, height]`` in degrees and metres on WGS-84 (the GNSS
frame; the height is ellipsoidal, as RFC 7946 defines it), one point per ``every_s`` of the
antenna's rows (the first row of each interval), so a 4 h flight stays a few MB. Each feature's
properties name the antenna, the time scale and the first and last point's time in GPS time
(week, seconds of week) and in UTC (leap seconds from :mod:`dpos_core.imports.timescales`).
Rows come block by block (:meth:`TrackWriter.add`): memory holds the kept points only.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dpos_core.imports.timescales import GPS_EPOCH_UNIX_S, WEEK_S, gpst_to_utc_ns
from dpos_core.units import DEG, FloatArray

_NS = 1_000_000_000
#: decimals of the coordinates: 1e-9 deg is 0.1 mm on the ground; heights to the millimetre
LONLAT_DECIMALS, HEIGHT_DECIMALS = 9, 3


def _iso(t_ns: int) -> str:
    """``t_ns`` [ns since 1970-01-01 on its scale] as ISO 8601 with nanoseconds (no zone letter)."""
    s, ns = divmod(int(t_ns), _NS)
    return dt.datetime.fromtimestamp(s, dt.UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{ns:09d}"


def time_fields(gpst_ns: int) -> dict[str, object]:
    """A GPS time [ns on the Unix calendar, no leap seconds] as the fields a surveyor reads:
    GPS week and seconds of week, the GPST date-time and the UTC date-time (``Z``)."""
    week, sow_ns = divmod(int(gpst_ns) - GPS_EPOCH_UNIX_S * _NS, WEEK_S * _NS)
    utc_ns = int(gpst_to_utc_ns(np.array([gpst_ns], dtype=np.int64))[0])
    return {"gps_week": int(week), "gps_sow_s": round(sow_ns / _NS, 9), "gpst": _iso(gpst_ns), "utc": _iso(utc_ns) + "Z"}


class TrackWriter:
    """GeoJSON tracks of the antennas, built from their rows block by block.

    Args:
        every_s: one point per this interval of the rows' time [s] (> 0).
    """

    def __init__(self, every_s: float = 1.0) -> None:
        if not np.isfinite(every_s) or every_s <= 0:
            raise ValueError(f"track interval every_s={every_s!r} must be a positive number of seconds")
        self.every_ns = int(round(every_s * _NS))
        self._points: dict[str, list[NDArray[np.float64]]] = {}
        self._t: dict[str, list[NDArray[np.int64]]] = {}
        self._first_ns: dict[str, int] = {}
        self._last_slot: dict[str, int] = {}

    def add(self, name: str, t_ns: NDArray[np.int64], llh_rad: FloatArray) -> None:
        """Rows of antenna ``name`` in time order: ``t_ns`` (N,) GPS time [ns], ``llh_rad`` (N, 3)
        latitude, longitude [rad] and ellipsoidal height [m]. Non-finite rows are left out."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        llh = np.asarray(llh_rad, dtype=float).reshape(-1, 3)
        if t_ns.shape[0] != llh.shape[0]:
            raise ValueError(f"{name}: {t_ns.shape[0]} stamps for {llh.shape[0]} positions")
        ok = np.isfinite(llh).all(axis=1)
        t_ns, llh = t_ns[ok], llh[ok]
        self._points.setdefault(name, [])
        self._t.setdefault(name, [])
        if t_ns.size == 0:
            return
        first = self._first_ns.setdefault(name, int(t_ns[0]))
        slot = (t_ns - first) // self.every_ns  # the interval of each row, from the antenna's first row
        keep = slot > np.r_[self._last_slot.get(name, -1), slot[:-1]]  # the first row of each interval
        if keep.any():
            self._t[name].append(t_ns[keep])
            self._points[name].append(llh[keep])
            self._last_slot[name] = int(slot[keep][-1])

    def geojson(self) -> dict[str, object]:
        """The FeatureCollection (RFC 7946): one LineString feature per antenna with points (an
        antenna with a single point is a Point; one without any is left out)."""
        features: list[dict[str, object]] = []
        for name in self._points:
            if not self._points[name]:
                continue
            t = np.concatenate(self._t[name])
            llh = np.concatenate(self._points[name])
            coords = [[round(float(lon), LONLAT_DECIMALS), round(float(lat), LONLAT_DECIMALS), round(float(h), HEIGHT_DECIMALS)]
                      for lat, lon, h in zip(llh[:, 0] / DEG, llh[:, 1] / DEG, llh[:, 2], strict=True)]
            geometry = {"type": "LineString", "coordinates": coords} if len(coords) > 1 else {"type": "Point", "coordinates": coords[0]}
            features.append({
                "type": "Feature",
                "geometry": geometry,
                "properties": {
                    "antenna": name,
                    "points": len(coords),
                    "interval_s": self.every_ns / _NS,
                    "datum": "WGS-84 (the GNSS frame); height above the ellipsoid [m]",
                    "time_scale": "GPS time (GPST)",
                    "start": time_fields(int(t[0])),
                    "end": time_fields(int(t[-1])),
                },
            })
        return {"type": "FeatureCollection", "features": features}

    def write(self, path: Path) -> None:
        """Write :meth:`geojson` to ``path`` (UTF-8, compact JSON)."""
        Path(path).write_text(json.dumps(self.geojson(), separators=(",", ":")) + "\n", encoding="utf-8")


__all__ = ["TrackWriter", "time_fields", "LONLAT_DECIMALS", "HEIGHT_DECIMALS"]
