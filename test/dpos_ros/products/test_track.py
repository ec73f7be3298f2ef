"""GeoJSON antenna tracks (products.track): RFC 7946 structure read back by a JSON parser,
longitude before latitude, one point per interval from blocks of rows, and the time fields in
GPS week / seconds of week and UTC with the leap seconds of the date."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dpos_core.imports.timescales import GPS_EPOCH_UNIX_S
from dpos_core.units import DEG
from dpos_ros.products.track import TrackWriter, time_fields

NS = 1_000_000_000


def _rows(t0_ns: int, n: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    t = t0_ns + np.round(np.arange(n) / rate_hz * NS).astype(np.int64)
    llh = np.column_stack([np.full(n, 34.5 * DEG) + np.arange(n) * 1e-8, np.full(n, 108.9 * DEG), np.full(n, 1500.0)])
    return t, llh


def test_track_is_rfc7946_lon_lat_height_one_point_per_interval(tmp_path) -> None:
    t0 = (GPS_EPOCH_UNIX_S + 2300 * 604800 + 3600) * NS  # GPS week 2300, 1 h into it
    t, llh = _rows(t0, 1000, 100.0)  # 10 s at 100 Hz
    w = TrackWriter(every_s=1.0)
    for k in range(0, 1000, 137):  # blocks that do not fall on the intervals
        w.add("ant_l", t[k:k + 137], llh[k:k + 137])
    w.add("ant_r", t[:1], llh[:1])  # a single point
    w.write(tmp_path / "tracks.geojson")
    doc = json.loads((tmp_path / "tracks.geojson").read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection"
    left, right = doc["features"]
    assert left["type"] == "Feature" and left["geometry"]["type"] == "LineString"
    coords = left["geometry"]["coordinates"]
    assert len(coords) == 10 == left["properties"]["points"]  # 0, 1, ..., 9 s
    lon, lat, h = np.array(coords).T
    np.testing.assert_allclose(lon, 108.9, atol=1e-9)
    np.testing.assert_allclose(lat, (34.5 * DEG + np.arange(0, 1000, 100) * 1e-8) / DEG, atol=1e-9)
    np.testing.assert_allclose(h, 1500.0)
    assert right["geometry"] == {"type": "Point", "coordinates": [108.9, 34.5, 1500.0]}
    start, end = left["properties"]["start"], left["properties"]["end"]
    assert start["gps_week"] == 2300 and start["gps_sow_s"] == 3600.0 and end["gps_sow_s"] == 3609.0
    assert left["properties"]["time_scale"].startswith("GPS time")


def test_non_finite_rows_are_left_out_and_a_bad_interval_is_refused() -> None:
    t, llh = _rows(1_700_000_000 * NS, 300, 100.0)
    llh[:150] = np.nan
    w = TrackWriter(1.0)
    w.add("a", t, llh)
    (f,) = w.geojson()["features"]
    assert f["properties"]["points"] == 2  # from the first finite row (1.5 s): 1.5 and 2.5 s
    with pytest.raises(ValueError, match="every_s"):
        TrackWriter(0.0)


@pytest.mark.parametrize(("utc", "leap"), [("2016-06-30T12:00:00", 17), ("2017-06-30T12:00:00", 18)])
def test_time_fields_take_the_leap_seconds_of_the_date(utc: str, leap: int) -> None:
    import datetime as dt

    utc_s = int(dt.datetime.fromisoformat(utc).replace(tzinfo=dt.UTC).timestamp())
    f = time_fields((utc_s + leap) * NS)
    assert f["utc"] == utc + ".000000000Z"
    assert (f["gps_week"] * 604800 + f["gps_sow_s"]) == utc_s + leap - GPS_EPOCH_UNIX_S
