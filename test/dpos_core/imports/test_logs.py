"""Readers of real sensor logs (dpos_core.imports.logs) on the committed walk_0827 recording and on
small synthetic logs with the faults real logs have."""

from __future__ import annotations

import calendar
import struct
from pathlib import Path

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core.imports.logs import (
    GPS_UTC_LEAP_S,
    ImuColumns,
    ImuLog,
    LogFormatError,
    PosLog,
    TimeTag,
    decimate_mask,
    grid_offset_ns,
    outage_mask,
    read_imu_csv,
    read_pos,
    read_tag,
)
from dpos_core.units import DEG, G0_MPS2

WALK = REPO / "data" / "real" / "walk_0827"
NS = 1_000_000_000


def _gpst_ns(y: int, mo: int, d: int, hh: int, mm: int, ss: int, ms: int = 0) -> int:
    return calendar.timegm((y, mo, d, hh, mm, ss, 0, 0, 0)) * NS + ms * 1_000_000


def write_tag(path: Path, start_ns: int, records: list[tuple[int, int]], header: bytes = b"TIMETAG RTKLIB EX 2.5.0") -> Path:
    """An RTKLIB time tag: 64-byte header, uint32 time_t + float64 fraction, (tick_ms, file_pos) records."""
    sec, ns = divmod(start_ns, NS)
    body = header.ljust(64, b"\0") + struct.pack("<Id", sec, ns * 1e-9)
    body += b"".join(struct.pack("<II", t, p) for t, p in records)
    path.write_bytes(body)
    return path


POS_HEADER = ("%  GPST            latitude(deg) longitude(deg) height(m) Q  ns  sdn(m)  sde(m)  sdu(m)  sdne(m) sdeu(m) sdun(m) "
              "age(s) ratio vn(m/s) ve(m/s) vu(m/s) sdvn sdve sdvu sdvne sdveu sdvun\n")


def pos_line(t: str, lat: float = 40.0, lon: float = -105.0, h: float = 1600.0, q: int = 1, sd: tuple[float, ...] = (0.01, 0.02, 0.03, 0.0, 0.0, 0.0),
             vel: tuple[float, ...] | None = (0.1, 0.2, 0.3, 0.04, 0.05, 0.06, 0.0, 0.0, 0.0)) -> str:
    vals = [lat, lon, h, q, 20, *sd, 0.0, 0.0, *(vel or ())]
    return f"{t} " + " ".join(f"{v:.7f}" for v in vals) + "\n"


# ----------------------------------------------------------------------------- the real recording


@pytest.fixture(scope="module")
def tag() -> TimeTag:
    return read_tag(WALK / "imu_1730.csv.tag")


@pytest.fixture(scope="module")
def imu(tag: TimeTag) -> ImuLog:
    return read_imu_csv(WALK / "imu_1730.csv", ImuColumns(), tag)


@pytest.fixture(scope="module")
def pos() -> PosLog:
    return read_pos(WALK / "gnss_1730_sf.pos")


def test_tag_starts_at_the_recording_time(tag: TimeTag) -> None:
    assert tag.start_ns == _gpst_ns(2025, 8, 28, 17, 30, 40, 961)
    assert np.all(np.diff(tag.tick_ms) >= 0) and np.all(np.diff(tag.file_pos) >= 0)
    assert tag.span_s == pytest.approx(134.271, abs=1e-3)
    assert tag.tick_ms.size == tag.file_pos.size == (len(tag_bytes := (WALK / "imu_1730.csv.tag").read_bytes()) - 76) // 8
    assert tag_bytes.startswith(b"TIMETAG")


def test_imu_counts_and_skipped_lines(imu: ImuLog) -> None:
    assert len(imu) == 20455
    assert [n for n, _ in imu.skipped] == [1, 20457]
    assert all("cut line" in why for _, why in imu.skipped)
    assert imu.repeated == 6958
    assert imu.omega_radps.shape == imu.f_mps2.shape == (20455, 3)


def test_imu_stamps_map_the_counter_onto_the_tag(imu: ImuLog, tag: TimeTag) -> None:
    assert int(imu.t_ns[0]) == tag.start_ns == _gpst_ns(2025, 8, 28, 17, 30, 40, 961)
    assert np.all(np.diff(imu.t_ns) > 0)
    assert abs(imu.clock_scale - 1.0) < 1e-3 and imu.clock_scale != 1.0
    assert (int(imu.t_ns[-1]) - tag.start_ns) * 1e-9 == pytest.approx(tag.span_s, abs=1e-6)
    # the counter of the CSV (ms) scaled: the 2nd sample is 6 counter ms after the first
    dt_ms = np.diff(imu.t_ns) * 1e-6
    assert np.median(dt_ms) == pytest.approx(6.0 * imu.clock_scale, abs=1e-6)


def test_imu_values_and_units(imu: ImuLog) -> None:
    # first usable line (line 2): -0.017,-0.007,1.011,0.038,-0.160,0.160,3326345
    np.testing.assert_allclose(imu.f_mps2[0], np.array([-0.017, -0.007, 1.011]) * G0_MPS2, rtol=1e-12)
    np.testing.assert_allclose(imu.omega_radps[0], np.array([0.038, -0.160, 0.160]) * DEG, rtol=1e-12)
    # at rest at the start: about 1 g along +z (z up), little horizontal
    f0 = imu.f_mps2[:150].mean(axis=0)
    assert f0[2] == pytest.approx(G0_MPS2, rel=0.03)
    assert np.hypot(f0[0], f0[1]) < 0.05 * G0_MPS2
    assert np.all(np.abs(imu.omega_radps[:150]) < 2.0 * DEG)  # nearly still


def test_pos_reads_the_rtk_solution(pos: PosLog) -> None:
    assert len(pos) == 536 and pos.skipped == []
    assert np.rad2deg(pos.llh[0, 0]) == pytest.approx(40.0966916, abs=1e-9)
    assert np.rad2deg(pos.llh[0, 1]) == pytest.approx(-105.1471665, abs=1e-9)
    assert pos.llh[0, 2] == pytest.approx(1601.435)
    assert int(pos.t_ns[0]) == _gpst_ns(2025, 8, 28, 17, 30, 39, 749)
    assert np.all(np.diff(pos.t_ns) == 250_000_000)  # 4 Hz
    assert set(np.unique(pos.quality)) == {1, 2}
    assert pos.has_velocity
    # first line: vn 0.001, ve -0.002, vu 0.027 -> ENU
    np.testing.assert_allclose(pos.vel_n_mps[0], [-0.002, 0.001, 0.027], atol=1e-12)
    # covariance ENU from sdn, sde, sdu = 0.0098995, 0.0098995, 0.0100000 (off-diagonals 0)
    np.testing.assert_allclose(np.diag(pos.pos_cov_enu_m2[0]), [0.0098995**2, 0.0098995**2, 0.01**2], rtol=1e-12)
    np.testing.assert_allclose(np.diag(pos.vel_cov_enu[0]), [0.0494975**2] * 3, rtol=1e-12)


def test_pos_on_the_gps_second_grid(pos: PosLog) -> None:
    """The receiver's epochs are 1 ms before the grid: 4 per second, one of them at x.999."""
    off_ns = grid_offset_ns(pos.t_ns, 1.0)
    assert np.count_nonzero(off_ns == -1_000_000) == 134
    keep = decimate_mask(pos.t_ns, 1.0)
    assert keep.sum() == 134 and np.all(np.diff(pos.t_ns[keep]) == NS)
    assert decimate_mask(pos.t_ns, 4.0).all()
    assert not decimate_mask(pos.t_ns, 1.0, tol_s=0.5e-3).any()


def test_first_fix_precedes_the_first_imu_sample(pos: PosLog, imu: ImuLog) -> None:
    assert (int(pos.t_ns[0]) - int(imu.t_ns[0])) * 1e-9 == pytest.approx(-1.212, abs=1e-9)


# ----------------------------------------------------------------------------- synthetic IMU logs


def _imu_lines(n: int, counter0: int = 1000, step: int = 10) -> list[str]:
    return [f"0.0,0.0,1.0,{0.1 * k:.1f},0.0,-0.5,{counter0 + step * k}" for k in range(n)]


def test_imu_cut_lines_non_numeric_and_nan_are_skipped_with_their_line(tmp_path: Path) -> None:
    lines = _imu_lines(6)
    lines.insert(2, "0.0,0.0,1.0,0.3,0.0")  # line 3: cut
    lines.insert(4, "0.0,0.0,abc,0.3,0.0,-0.5,1025")  # line 5: not a number
    lines.insert(5, "0.0,nan,1.0,0.3,0.0,-0.5,1027")  # line 6: NaN
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(lines) + "\n")
    log = read_imu_csv(p, ImuColumns())
    assert len(log) == 6
    reasons = dict(log.skipped)
    assert sorted(reasons) == [3, 5, 6]
    assert "cut line" in reasons[3] and "not a number" in reasons[5] and "not finite" in reasons[6]
    # without a tag: counter seconds from the first sample
    np.testing.assert_array_equal(log.t_ns, np.arange(6) * 10_000_000)
    np.testing.assert_allclose(log.omega_radps[:, 0], np.arange(6) * 0.1 * DEG, rtol=1e-12)


def test_imu_non_increasing_counter_is_skipped(tmp_path: Path) -> None:
    lines = _imu_lines(5)
    lines.insert(3, "0.0,0.0,1.0,9.9,0.0,-0.5,1020")  # line 4: repeats the counter of line 3
    lines.insert(4, "0.0,0.0,1.0,9.9,0.0,-0.5,1005")  # line 5: goes back
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(lines) + "\n")
    log = read_imu_csv(p, ImuColumns())
    assert len(log) == 5 and np.all(np.diff(log.t_ns) > 0)
    reasons = dict(log.skipped)
    assert sorted(reasons) == [4, 5]
    assert "1020" in reasons[4] and "not after" in reasons[4] and "1005" in reasons[5]


def test_imu_repeated_samples_are_counted_and_kept(tmp_path: Path) -> None:
    p = tmp_path / "imu.csv"
    p.write_text("1,2,3,4,5,6,100\n1,2,3,4,5,6,110\n1,2,3,4,5,6,120\n1,2,3,4,5,7,130\n")
    log = read_imu_csv(p, ImuColumns(accel_unit="mps2", gyro_unit="rad_s"))
    assert len(log) == 4 and log.repeated == 2
    np.testing.assert_array_equal(log.f_mps2[0], [1.0, 2.0, 3.0])


def test_imu_counter_mapped_onto_a_tag(tmp_path: Path) -> None:
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(_imu_lines(101)) + "\n")  # 1.000 s of counter
    start = _gpst_ns(2024, 1, 2, 3, 4, 5, 250)
    tg = read_tag(write_tag(tmp_path / "imu.csv.tag", start, [(0, 0), (500, 900), (1001, 1800)]))  # logger: 1.001 s
    log = read_imu_csv(p, ImuColumns(), tg)
    assert int(log.t_ns[0]) == start and int(log.t_ns[-1]) == start + 1_001_000_000
    assert log.clock_scale == pytest.approx(1.001)
    # a counter unit that does not fit the tag is refused, naming the file
    with pytest.raises(LogFormatError, match=r"imu\.csv: the IMU counter spans 2\.000 s but the tag 1\.001 s"):
        read_imu_csv(p, ImuColumns(counter_unit_s=2e-3), tg)


def test_imu_time_column_and_whitespace_delimiter(tmp_path: Path) -> None:
    p = tmp_path / "imu.txt"
    t0 = 1_700_000_000.0
    p.write_text("time ax ay az gx gy gz\n" + "".join(f"{t0 + 0.01 * k:.2f}  0 0 9.8  0.01 0 0\n" for k in range(4))
                 + "nan 0 0 9.8 0.01 0 0\n")
    log = read_imu_csv(p, ImuColumns(accel=(1, 2, 3), gyro=(4, 5, 6), accel_unit="mps2", gyro_unit="rad_s", counter=None, time=0,
                                     skip_header=1, delimiter=" "))
    assert len(log) == 4
    assert log.skipped == [(6, "a field is not finite")]  # line 1 (the header) is ignored: --skip-header
    # exact: the decimal seconds are not rounded through float64 (which is good to ~120 ns today)
    np.testing.assert_array_equal(log.t_ns, 1_700_000_000 * NS + np.arange(4) * 10_000_000)


def test_imu_without_a_usable_line_names_the_file_and_the_reasons(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("a,b,c,d,e,f,g\n1,2\n")
    with pytest.raises(LogFormatError, match=r"bad\.csv: no usable IMU line \(2 skipped: line 1: a field is not a number; line 2: 2 field"):
        read_imu_csv(p, ImuColumns(accel=(0, 1, 2), gyro=(3, 4, 5), counter=None, time=6))
    with pytest.raises(ValueError, match="accel_unit must be one of"):
        ImuColumns(accel_unit="ft_s2")
    with pytest.raises(ValueError, match="distinct"):
        ImuColumns(accel=(0, 1, 2), gyro=(2, 3, 4))


# ----------------------------------------------------------------------------- synthetic tags


def test_tag_with_a_bad_header_is_refused(tmp_path: Path) -> None:
    p = write_tag(tmp_path / "x.tag", _gpst_ns(2025, 1, 1, 0, 0, 0), [(0, 0)], header=b"NOTATAG")
    with pytest.raises(LogFormatError, match=r"x\.tag: not an RTKLIB time tag"):
        read_tag(p)
    short = tmp_path / "short.tag"
    short.write_bytes(b"TIMETAG RTKLIB")
    with pytest.raises(LogFormatError, match=r"short\.tag: not an RTKLIB time tag"):
        read_tag(short)
    bad_frac = tmp_path / "frac.tag"
    bad_frac.write_bytes(b"TIMETAG".ljust(64, b"\0") + struct.pack("<Id", 1_700_000_000, 1.5))
    with pytest.raises(LogFormatError, match=r"frac\.tag: time fraction 1\.5 at byte 68"):
        read_tag(bad_frac)


# ----------------------------------------------------------------------------- synthetic .pos files


def test_pos_in_utc_is_shifted_to_gpst(tmp_path: Path) -> None:
    p = tmp_path / "utc.pos"
    p.write_text(POS_HEADER.replace("GPST", "UTC ") + pos_line("2025/08/28 17:30:21.749") + pos_line("2025/08/28 17:30:22.749"))
    log = read_pos(p)
    assert int(log.t_ns[0]) == _gpst_ns(2025, 8, 28, 17, 30, 21, 749) + GPS_UTC_LEAP_S * NS
    assert GPS_UTC_LEAP_S == 18


def test_pos_in_utc_from_2016_gets_its_own_leap_seconds(tmp_path: Path) -> None:
    """A UTC .pos file of 2016 is shifted by 17 s (the table), not today's 18 s."""
    p = tmp_path / "utc2016.pos"
    p.write_text(POS_HEADER.replace("GPST", "UTC ") + pos_line("2016/12/31 23:59:58.000") + pos_line("2017/01/01 00:00:01.000"))
    log = read_pos(p)
    assert int(log.t_ns[0]) == _gpst_ns(2016, 12, 31, 23, 59, 58, 0) + 17 * NS
    assert int(log.t_ns[1]) == _gpst_ns(2017, 1, 1, 0, 0, 1, 0) + 18 * NS


def test_pos_in_gps_week_and_time_of_week(tmp_path: Path) -> None:
    p = tmp_path / "tow.pos"
    p.write_text(POS_HEADER + pos_line("2381 408639.999") + pos_line("2381 408640.249"))
    log = read_pos(p)
    assert int(log.t_ns[0]) == _gpst_ns(2025, 8, 28, 17, 30, 39, 999)
    assert int(log.t_ns[1] - log.t_ns[0]) == 250_000_000


def test_pos_without_velocity_columns(tmp_path: Path) -> None:
    p = tmp_path / "novel.pos"
    header = POS_HEADER.split(" vn(m/s)")[0] + "\n"
    p.write_text(header + pos_line("2025/08/28 17:30:40.000", vel=None) + pos_line("2025/08/28 17:30:41.000", vel=None))
    log = read_pos(p)
    assert len(log) == 2 and not log.has_velocity
    assert np.all(np.isnan(log.vel_n_mps)) and np.all(np.isnan(log.vel_cov_enu))
    np.testing.assert_allclose(np.diag(log.pos_cov_enu_m2[0]), [0.02**2, 0.01**2, 0.03**2])


def test_pos_signed_covariances_are_enu(tmp_path: Path) -> None:
    """RTKLIB writes sdne = sign(c_ne) sqrt(|c_ne|): the ENU matrix gets c_en = c_ne etc."""
    p = tmp_path / "cov.pos"
    p.write_text(POS_HEADER + pos_line("2025/08/28 17:30:40.000", sd=(0.1, 0.2, 0.3, -0.05, 0.04, 0.03)))
    c = read_pos(p).pos_cov_enu_m2[0]
    expected = np.array([[0.04, -0.0025, 0.0016], [-0.0025, 0.01, 0.0009], [0.0016, 0.0009, 0.09]])
    np.testing.assert_allclose(c, expected, atol=1e-15)


def test_pos_bad_lines_are_skipped_with_their_line(tmp_path: Path) -> None:
    p = tmp_path / "bad_lines.pos"
    p.write_text(POS_HEADER + pos_line("2025/08/28 17:30:40.000") + "2025/08/28 17:30:40.250 40.0 -105.0\n"
                 + pos_line("2025/08/28 17:30:40.500").replace("1600.0000000", "nan")
                 + pos_line("2025/08/28 17:30:40.000") + pos_line("2025/08/28 17:30:41.000"))
    log = read_pos(p)
    assert len(log) == 2
    reasons = dict(log.skipped)
    assert sorted(reasons) == [3, 4, 5]
    assert "cut line" in reasons[3] and "not finite" in reasons[4] and "not after the previous" in reasons[5]


def test_pos_ecef_and_baseline_solutions_are_refused(tmp_path: Path) -> None:
    ecef = tmp_path / "ecef.pos"
    ecef.write_text("%  GPST                  x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)   sdy(m)   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio\n"
                    "2025/08/28 17:30:40.000  -1283000.0 -4726000.0 4074000.0 1 20 0.01 0.01 0.01 0 0 0 0 0\n")
    with pytest.raises(LogFormatError, match=r"ecef\.pos: ECEF / baseline solutions are not supported.*out-solformat=llh"):
        read_pos(ecef)
    enu = tmp_path / "enu.pos"
    enu.write_text("%  GPST   e-baseline(m)  n-baseline(m)  u-baseline(m)   Q  ns   sde(m)   sdn(m)   sdu(m)  sden(m)  sdnu(m)  sdue(m) age(s)  ratio  baseline(m)\n"
                   "2025/08/28 17:30:40.000  12.0 34.0 5.0 1 20 0.01 0.01 0.01 0 0 0 0 0 36.4\n")
    with pytest.raises(LogFormatError, match=r"enu\.pos: ECEF / baseline solutions are not supported"):
        read_pos(enu)
    # written without a header: the coordinates are not latitude / longitude
    bare = tmp_path / "bare.pos"
    bare.write_text("2025/08/28 17:30:40.000  -1283000.0 -4726000.0 4074000.0 1 20 0.01 0.01 0.01 0 0 0 0 0\n")
    with pytest.raises(LogFormatError, match=r"bare\.pos: not an RTKLIB \.pos solution \(no header, no usable solution line; 1 skipped: line 1: latitude -1\.283e\+06"):
        read_pos(bare)


def test_pos_in_dms_or_not_a_pos_file_is_refused(tmp_path: Path) -> None:
    dms = tmp_path / "dms.pos"
    dms.write_text("%  GPST   latitude(d'\")   longitude(d'\")  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)\n")
    with pytest.raises(LogFormatError, match=r"dms\.pos: latitude / longitude must be in degrees"):
        read_pos(dms)
    other = tmp_path / "notes.txt"
    other.write_text("hello\n")
    with pytest.raises(LogFormatError, match=r"notes\.txt: not an RTKLIB \.pos solution"):
        read_pos(other)


# ----------------------------------------------------------------------------- masks


def test_outage_mask_is_half_open_after_the_origin() -> None:
    origin = 1_000 * NS
    t = origin + np.array([59.999, 60.0, 74.999, 75.0, 80.0]) * 1e9
    keep = outage_mask(t.astype(np.int64), [(60.0, 75.0)], origin)
    np.testing.assert_array_equal(keep, [True, False, False, True, True])
    with pytest.raises(ValueError, match="must end after it starts"):
        outage_mask(t.astype(np.int64), [(5.0, 3.0)], origin)


def test_grid_offset_is_exact_for_todays_stamps_and_fractional_rates() -> None:
    t = np.array([_gpst_ns(2025, 8, 28, 17, 30, 39, 999), _gpst_ns(2025, 8, 28, 17, 30, 40, 1), _gpst_ns(2025, 8, 28, 17, 30, 40, 500)])
    np.testing.assert_array_equal(grid_offset_ns(t, 1.0), [-1_000_000, 1_000_000, 500_000_000])
    np.testing.assert_array_equal(grid_offset_ns(t, 2.0), [-1_000_000, 1_000_000, 0])
    # 0.2 Hz: the grid of GPS time (origin the GPS epoch, 1980-01-06, a whole number of 5 s from the Unix epoch)
    assert grid_offset_ns(np.array([_gpst_ns(2025, 8, 28, 17, 30, 40)]), 0.2)[0] == 0
    # 2/3 Hz: a 1.5 s grid stays exact over 45 years of GPS time
    g = _gpst_ns(2025, 8, 28, 0, 0, 0) + np.arange(4) * 1_500_000_000
    assert (int(g[0]) // NS - 315_964_800) % 3 == 0  # 2025-08-28 00:00:00 GPST is on the 1.5 s grid
    np.testing.assert_array_equal(grid_offset_ns(g, 2 / 3), [0, 0, 0, 0])
    with pytest.raises(ValueError, match="rate must be > 0"):
        decimate_mask(t, 0.0)
