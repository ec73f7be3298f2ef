"""The topics of a simulated session as serialized streams (design.md "Topics").

One function builds, for a device or for the whole aircraft, every topic's stamps and CDR
payloads.  ``dpos-sim`` writes them to a bag; the ``device: sim`` nodes publish the same bytes
live, so a live session and its bag carry identical samples.

Devices:
  ``master``          /dpos/datum, /master/imu, /gnss/fix, /gnss/vel, /sar/fix and /baro/pressure
                      (a scenario with a ``sar:`` block), /master/nav (reference:
                      truth + the scenario's main-system noise), /session/end, /truth/master, and
                      /truth/antenna/<name> of the antennas without IMU
  ``sub_imu/<name>``  /sub_imu/<name>/imu, /truth/sub_imu/<name>, /truth/antenna/<name> of its antennas
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray
from rclpy.serialization import serialize_message

from dpos_core.series import ImuSeries, NavSeries
from dpos_core.sim.chunked import ChunkedSession, Window
from dpos_core.sim.sar import baro_heights, sar_fixes
from dpos_core.sim.session import SimulatedSession
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.streams import TopicStream


def session_id(session: SimulatedSession) -> str:
    """``<scenario>_seed<N>``: names the products and is the frame_id of /session/end."""
    return f"{session.scenario.name}_seed{session.seed}"


def _odometry_stream(topic: str, child: str, series: NavSeries, session: SimulatedSession, datum_llh: NDArray[np.float64], *, with_cov: bool) -> TopicStream:
    t_ns = cv.stamps_ns(session.scenario.start_time_s, series.t_s)
    if with_cov:
        vals = cv.odometry_values_cov(series.llh, series.vel_n_mps, series.q_nb, datum_llh, series.omega_eb_b_radps,
                                      *series.required("pos_cov", "att_cov", "vel_cov"))
    else:
        vals = cv.odometry_values(series.llh, series.vel_n_mps, series.q_nb, datum_llh, series.omega_eb_b_radps)
    return TopicStream(topic, T.ODOMETRY, t_ns, rows=cv.odometry_rows(cv.WORLD_FRAME, child, t_ns, vals), qos="nav")


def _imu_stream(topic: str, frame: str, session: SimulatedSession, name: str, imu: ImuSeries | None = None) -> TopicStream:
    """The IMU ``name``'s topic: its samples ``imu`` (default the whole session's)."""
    ac = session.scenario.aircraft
    model = session.scenario.master_imu if name == "master" else ac.sub_imu(name).imu
    if imu is None:
        imu = session.master_imu() if name == "master" else session.sub_imu(name)
    t_ns = cv.stamps_ns(session.scenario.start_time_s, imu.t_s)
    # the Imu covariance carries the white-noise variance of one sample
    rate = session.scenario.rates.master_imu_hz if name == "master" else session.scenario.rates.sub_imu_hz
    rows = cv.imu_rows(frame, t_ns, imu.omega_radps, imu.f_mps2, *model.white_sigma(1.0 / rate))
    return TopicStream(topic, T.IMU, t_ns, rows=rows)


def sar_streams(session: SimulatedSession, datum_llh: NDArray[np.float64]) -> list[TopicStream]:
    """/sar/fix and /baro/pressure of a SINS/SAR scenario (its ``sar:`` block; dpos_core.sim.sar):
    the fixes only while the radar images, the barometer all the flight (sensor QoS)."""
    t0 = session.scenario.start_time_s
    fx, baro = sar_fixes(session), baro_heights(session)
    f_ns = cv.stamps_ns(t0, fx.t_s)
    b_ns = cv.stamps_ns(t0, baro.t_s)
    ps, hs, bs = float(np.asarray(fx.pos_sigma_m)), float(np.asarray(fx.heading_sigma_rad)), float(np.asarray(baro.sigma_m))
    return [
        TopicStream(T.SAR_FIX, T.POSE_COV, f_ns, blobs=tuple(
            serialize_message(cv.sar_fix_msg(int(t), fx.llh[i], float(fx.heading_rad[i]), ps, hs, datum_llh)) for i, t in enumerate(f_ns))),
        TopicStream(T.BARO_PRESSURE, T.FLUID_PRESSURE, b_ns, blobs=tuple(
            serialize_message(cv.baro_msg(int(t), float(baro.h_m[i]), bs)) for i, t in enumerate(b_ns))),
    ]


def device_streams(
    session: SimulatedSession, device: str, *, truth: bool = True, datum_llh: NDArray[np.float64] | None = None
) -> list[TopicStream]:
    """Streams of one device: ``master`` or ``sub_imu/<name>`` (see module docstring).

    ``datum_llh`` ([lat_rad, lon_rad, h_m]) is the origin of the ``enu`` frame of the poses; by
    default the scenario's start point.  All devices of a session must use the same datum.
    """
    datum = session.datum_llh if datum_llh is None else np.asarray(datum_llh, dtype=float)
    sc = session.scenario
    ac = sc.aircraft
    t0 = sc.start_time_s
    out: list[TopicStream] = []
    if device == "master":
        t_start = cv.stamps_ns(t0, np.array([0.0]))
        out.append(TopicStream(T.DATUM, T.NAVSATFIX, t_start, blobs=(serialize_message(cv.datum_msg(int(t_start[0]), datum)),), qos="datum"))
        out.append(_imu_stream(T.MASTER_IMU, cv.MASTER_FRAME, session, "master"))
        g = session.gnss()
        g_ns = cv.stamps_ns(t0, g.t_s)
        out.append(TopicStream(T.GNSS_FIX, T.NAVSATFIX, g_ns, blobs=tuple(
            serialize_message(cv.navsatfix_msg(int(t), cv.GNSS_FRAME, g.llh[i], g.pos_sigma_m[i])) for i, t in enumerate(g_ns))))
        out.append(TopicStream(T.GNSS_VEL, T.TWIST_COV, g_ns, blobs=tuple(
            serialize_message(cv.gnss_vel_msg(int(t), g.vel_n_mps[i], g.vel_sigma_mps[i])) for i, t in enumerate(g_ns))))
        if sc.sar is not None:
            out += sar_streams(session, datum)
        out.append(_odometry_stream(T.MASTER_NAV, cv.MASTER_FRAME, session.master_nav_reference(), session, datum, with_cov=True))
        if truth:
            out.append(_odometry_stream(T.TRUTH_MASTER, cv.MASTER_FRAME, session.truth("master"), session, datum, with_cov=False))
            for a in ac.antennas:
                if a.sub_imu is None:
                    out.append(_odometry_stream(T.truth_antenna(a.name), cv.antenna_frame(a.name), session.truth(f"antenna/{a.name}"), session, datum, with_cov=False))
        t_end = cv.stamps_ns(t0, np.array([session.duration_s]))
        out.append(TopicStream(T.SESSION_END, T.HEADER, t_end, blobs=(serialize_message(cv.session_end_msg(int(t_end[0]), session_id(session))),), qos="nav"))
        return out
    kind, _, name = device.partition("/")
    if kind != "sub_imu":
        raise ValueError(f"unknown device {device!r}: 'master' or 'sub_imu/<name>'")
    ac.sub_imu(name)  # KeyError naming the configured sub-IMUs
    out.append(_imu_stream(T.sub_imu(name), cv.sub_imu_frame(name), session, name))
    if truth:
        out.append(_odometry_stream(T.truth_sub_imu(name), cv.sub_imu_frame(name), session.truth(f"sub_imu/{name}"), session, datum, with_cov=False))
        for a in ac.antennas:
            if a.sub_imu == name:
                out.append(_odometry_stream(T.truth_antenna(a.name), cv.antenna_frame(a.name), session.truth(f"antenna/{a.name}"), session, datum, with_cov=False))
    return out


def session_streams(session: SimulatedSession, *, truth: bool = True, datum_llh: NDArray[np.float64] | None = None) -> list[TopicStream]:
    """Every topic of the session: the master device and every sub-IMU."""
    out = device_streams(session, "master", truth=truth, datum_llh=datum_llh)
    for s in session.scenario.aircraft.sub_imus:
        out += device_streams(session, f"sub_imu/{s.name}", truth=truth, datum_llh=datum_llh)
    return out



def _window_streams(session: SimulatedSession, w: Window, *, truth: bool, datum: NDArray[np.float64], last: bool,
                    sar: list[TopicStream] | None = None) -> list[TopicStream]:
    """The topics of :func:`session_streams`, in its order, over one window of a :class:`ChunkedSession`
    (``sar``: the session's /sar/fix and /baro/pressure, :func:`sar_streams`, cut to the window)."""
    sc = session.scenario
    ac = sc.aircraft
    t0 = sc.start_time_s
    first = w.t_a == 0.0
    out: list[TopicStream] = []
    t_start = cv.stamps_ns(t0, np.array([0.0]))
    out.append(TopicStream(T.DATUM, T.NAVSATFIX, t_start if first else t_start[:0],
                           blobs=(serialize_message(cv.datum_msg(int(t_start[0]), datum)),) if first else (), qos="datum"))
    out.append(_imu_stream(T.MASTER_IMU, cv.MASTER_FRAME, session, "master", w.master_imu))
    g = w.gnss
    g_ns = cv.stamps_ns(t0, g.t_s)
    out.append(TopicStream(T.GNSS_FIX, T.NAVSATFIX, g_ns, blobs=tuple(
        serialize_message(cv.navsatfix_msg(int(t), cv.GNSS_FRAME, g.llh[i], g.pos_sigma_m[i])) for i, t in enumerate(g_ns))))
    out.append(TopicStream(T.GNSS_VEL, T.TWIST_COV, g_ns, blobs=tuple(
        serialize_message(cv.gnss_vel_msg(int(t), g.vel_n_mps[i], g.vel_sigma_mps[i])) for i, t in enumerate(g_ns))))
    for st in sar or ():  # the window's (t_a, t_b] (t_a = 0: from the start)
        a_ns, b_ns = cv.stamps_ns(t0, np.array([w.t_a, w.t_b]))
        sel = np.flatnonzero(((st.t_ns > a_ns) | (w.t_a == 0.0)) & (st.t_ns <= b_ns))
        out.append(TopicStream(st.topic, st.msgtype, st.t_ns[sel], blobs=tuple(st.message(int(i)) for i in sel), qos=st.qos))
    out.append(_odometry_stream(T.MASTER_NAV, cv.MASTER_FRAME, w.master_nav, session, datum, with_cov=True))
    if truth:
        out.append(_odometry_stream(T.TRUTH_MASTER, cv.MASTER_FRAME, w.truth["master"], session, datum, with_cov=False))
        for a in ac.antennas:
            if a.sub_imu is None:
                out.append(_odometry_stream(T.truth_antenna(a.name), cv.antenna_frame(a.name), w.truth[f"antenna/{a.name}"], session,
                                            datum, with_cov=False))
    t_end = cv.stamps_ns(t0, np.array([session.duration_s]))
    out.append(TopicStream(T.SESSION_END, T.HEADER, t_end if last else t_end[:0],
                           blobs=(serialize_message(cv.session_end_msg(int(t_end[0]), session_id(session))),) if last else (), qos="nav"))
    for s in ac.sub_imus:
        out.append(_imu_stream(T.sub_imu(s.name), cv.sub_imu_frame(s.name), session, s.name, w.sub_imus[s.name]))
        if truth:
            out.append(_odometry_stream(T.truth_sub_imu(s.name), cv.sub_imu_frame(s.name), w.truth[f"sub_imu/{s.name}"], session,
                                        datum, with_cov=False))
            for a in ac.antennas:
                if a.sub_imu == s.name:
                    out.append(_odometry_stream(T.truth_antenna(a.name), cv.antenna_frame(a.name), w.truth[f"antenna/{a.name}"],
                                                session, datum, with_cov=False))
    return out


def chunked_session_streams(session: SimulatedSession, window_s: float, *, truth: bool = True,
                            datum_llh: NDArray[np.float64] | None = None) -> Iterator[list[TopicStream]]:
    """The topics of :func:`session_streams` window by window (:class:`dpos_core.sim.chunked.ChunkedSession`:
    the same seed gives the same messages whatever ``window_s``, not those of :func:`session_streams`):
    one list per window, every topic in each (empty where it has no message in the window)."""
    datum = session.datum_llh if datum_llh is None else np.asarray(datum_llh, dtype=float)
    cs = ChunkedSession(session, truth=truth)
    # a SINS/SAR scenario's fixes and heights: the whole session's (small: 1 Hz and 10 Hz; their draws do
    # not depend on the windows), each window's cut from them
    sar = sar_streams(session, datum) if session.scenario.sar is not None else None
    ws = cs.windows(window_s)
    w = next(ws, None)
    while w is not None:
        nxt = next(ws, None)
        yield _window_streams(session, w, truth=truth, datum=datum, last=nxt is None, sar=sar)
        w = nxt


def session_custom_data(session: SimulatedSession, aircraft_text: str) -> dict[str, str]:
    """``dpos.*`` metadata of a simulated recording: what dpos-process needs besides the topics."""
    sc = session.scenario
    fl = session.flight
    return {
        "dpos.session_id": session_id(session),
        "dpos.scenario": sc.name,
        "dpos.seed": str(session.seed),
        "dpos.start_time_s": repr(sc.start_time_s),
        "dpos.aircraft_yaml": aircraft_text,
        # imaging segments still inside a shortened flight (a cut one keeps its name)
        "dpos.imaging_segments": json.dumps({n: list(fl.segment_bounds(n)) for n in sc.imaging_segments if n in {s.name for s in sc.segments}}),
        "dpos.transfer_alignment": json.dumps(sc.transfer_alignment),
    }
