"""``dpos-sar``: the SINS/SAR/baro navigation of a recording ([Yan2016], docs/sar.md), offline, through
the same code as sar_nav_node (:mod:`dpos_ros.products.sar`) and with the same options as its
parameters.

    dpos-sim --scenario paper_sar --seed 1 --duration 300 --out out/sar_bag
    dpos-sar out/sar_bag --method ekf --out out/sar_ekf
    dpos-sar out/sar_bag --method rpf --particles 1000 --bandwidth-scale 0.5 --seed 1 --out out/sar_rpf

The recording needs ``/master/imu``, ``/master/nav`` (its first message is the initial state),
``/sar/fix``, ``/baro/pressure`` and ``/dpos/datum``; a missing one is exit 2 naming it.  Writes
``OUT/nav.csv`` (one row per filter epoch: time, latitude, longitude, height, ENU velocity, heading,
pitch, roll, their 1-sigmas) and ``OUT/report.json`` (the run's summary - ESS and MH acceptance
for the particle filters - and, with ``/truth/master`` in the recording, the mean absolute errors
against it).  ``dpos-process`` is the transfer alignment's (sub-IMUs); this is its sibling for the
main POS aided by SAR and the barometer.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dpos_core.attitude import quat_to_dcm
from dpos_core.frames import hpr_from_C_nb
from dpos_core.sar.navigate import SarNavSettings
from dpos_core.sar.pipeline import METHODS
from dpos_core.units import DEG
from dpos_ros.cli.options import MAX_PARTICLES, MAX_RATE_HZ, one_line_errors
from dpos_ros.contract import conversions as cv
from dpos_ros.contract import topics as T
from dpos_ros.io.bag import read_raw
from dpos_ros.io.gnss_ins import deserialize
from dpos_ros.products.sar import INPUT_TOPICS, SarInputError, errors_vs_truth, run, session_inputs, summary


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="dpos-sar", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="rosbag2 directory")
    ap.add_argument("--method", choices=METHODS, default="ekf", help="SINS/SAR filter (default ekf)")
    ap.add_argument("--particles", type=int, default=1000, help="particles of pf, rpf, mcmc_rpf (>= 2; default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the particle filters (>= 0)")
    ap.add_argument("--bandwidth-scale", type=float, default=1.0, help="regularization bandwidth in units of h_opt (rpf, mcmc_rpf; default 1)")
    ap.add_argument("--filter-rate", type=float, default=1.0, metavar="HZ", help="filter epochs [Hz] (default 1)")
    ap.add_argument("--baro-height-offset", type=float, default=0.0, metavar="M",
                    help="ellipsoidal height minus ISA pressure altitude [m] (default 0: the simulated barometer)")
    ap.add_argument("--out", type=Path, required=True)
    return ap


def _fail(msg: str) -> int:
    print(f"dpos-sar: error: {msg}", file=sys.stderr)
    return 2


@one_line_errors("dpos-sar")
def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.particles < 2 and args.method not in ("ekf", "ukf"):
        return _fail(f"--particles must be >= 2 for {args.method}, got {args.particles}")
    if args.seed < 0 or not args.bandwidth_scale > 0 or not args.filter_rate > 0:
        return _fail("--seed must be >= 0, --bandwidth-scale and --filter-rate > 0")
    if args.particles > MAX_PARTICLES or not args.filter_rate <= MAX_RATE_HZ:
        return _fail(f"--particles must be <= {MAX_PARTICLES} and --filter-rate <= {MAX_RATE_HZ:g} Hz "
                     f"(the filter's arrays grow with them), got {args.particles} and {args.filter_rate:g}")
    if not (math.isfinite(args.bandwidth_scale) and math.isfinite(args.baro_height_offset)):
        return _fail("--bandwidth-scale and --baro-height-offset must be finite")

    wanted = (*INPUT_TOPICS, T.DATUM, T.TRUTH_MASTER)
    try:
        raw = read_raw(args.bag, wanted)
    except Exception as e:  # rosbags raises its own errors for a missing or unreadable bag
        return _fail(f"{args.bag}: cannot read the bag ({type(e).__name__}: {e})")
    missing = [t for t in (*INPUT_TOPICS, T.DATUM) if t not in raw or not len(raw[t].blobs)]
    if missing:
        return _fail(f"{args.bag}: the SINS/SAR navigation needs the topics {', '.join(missing)} "
                     f"(the recording has: {', '.join(sorted(raw)) or 'none of them'})")
    datum = cv.datum_from_msg(deserialize(raw[T.DATUM].blobs[:1], raw[T.DATUM].msgtype)[0])
    t_imu, v_imu = cv.decode_raw_batch(list(raw[T.MASTER_IMU].blobs), "imu", cv.MASTER_FRAME)
    imu = cv.imu_from_values(t_imu, v_imu)
    nav_t, nav_v = cv.decode_raw(bytes(raw[T.MASTER_NAV].blobs[0]), "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
    fixes = [cv.sar_fix_from_msg(m, datum) for m in deserialize(list(raw[T.SAR_FIX].blobs), raw[T.SAR_FIX].msgtype)]
    baro = [cv.baro_from_msg(m) for m in deserialize(list(raw[T.BARO_PRESSURE].blobs), raw[T.BARO_PRESSURE].msgtype)]
    try:
        settings = SarNavSettings(method=args.method, n_particles=args.particles, seed=args.seed, bandwidth_scale=args.bandwidth_scale,
                                  filter_rate_hz=args.filter_rate)
        inputs = session_inputs(imu, (nav_t, nav_v), fixes, baro, datum, args.baro_height_offset)
        res = run(inputs, settings)
    except (SarInputError, ValueError) as e:
        return _fail(f"{args.bag}: {e}")
    report = summary(res, settings, inputs)
    if T.TRUTH_MASTER in raw:
        tt, tv = cv.decode_raw_batch(list(raw[T.TRUTH_MASTER].blobs), "odometry", cv.WORLD_FRAME, cv.MASTER_FRAME)
        err = errors_vs_truth(res, cv.odometry_from_values(tt, tv, datum), inputs.origin_ns)
        report["truth"] = {"epochs": err["epochs"], "mae": err["mae"]}
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        _write_csv(args.out / "nav.csv", res)
        (args.out / "report.json").write_text(json.dumps(report, indent=1) + "\n")
    except OSError as e:
        return _fail(f"{args.out}: {e}")
    print(f"dpos-sar: {args.method}: {report['epochs']} epochs ({report['epochs_with_fix']} with a SAR fix) over "
          f"{report['duration_s']:.0f} s; final 1-sigma position {', '.join(f'{x:.2f}' for x in report['final_pos_sigma_m'])} m, "
          f"heading {report['final_heading_sigma_arcmin']:.3f}'")
    if "mean_ess" in report:
        print(f"  particles {report['particles']}: mean ESS {report['mean_ess']:.1f}, final ESS {report['final_ess']:.1f}"
              + (f", MH acceptance {report['mean_accept']:.3f}" if "mean_accept" in report else ""))
    if "truth" in report:
        print("  MAE against /truth/master: " + ", ".join(f"{k} {v:.3g}" for k, v in report["truth"]["mae"].items()))
    print(f"wrote {args.out / 'nav.csv'}, {args.out / 'report.json'}")
    return 0


def _write_csv(path: Path, res) -> None:
    hpr = hpr_from_C_nb(quat_to_dcm(res.q_nb)) / DEG
    sp = np.sqrt(np.maximum(np.diagonal(res.pos_cov, axis1=1, axis2=2), 0.0))
    sv = np.sqrt(np.maximum(np.diagonal(res.vel_cov, axis1=1, axis2=2), 0.0))
    sa = np.sqrt(np.maximum(np.diagonal(res.att_cov, axis1=1, axis2=2), 0.0)) / DEG
    cols = np.column_stack([res.t_s, np.rad2deg(res.llh[:, :2]), res.llh[:, 2], res.vel_n_mps, hpr, sp, sv, sa, res.sar.astype(float)])
    header = ("t_s,lat_deg,lon_deg,h_m,vel_e_mps,vel_n_mps,vel_u_mps,heading_deg,pitch_deg,roll_deg,sigma_e_m,sigma_n_m,sigma_u_m,"
              "sigma_vel_e_mps,sigma_vel_n_mps,sigma_vel_u_mps,sigma_rot_e_deg,sigma_rot_n_deg,sigma_rot_u_deg,sar_fix")
    np.savetxt(path, cols, delimiter=",", header=header, comments="", fmt="%.10g")


if __name__ == "__main__":
    sys.exit(main())
