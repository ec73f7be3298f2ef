"""``dpos-strapdown-demo``: strapdown demonstration on a closed-form flight.

Integrates a 30-deg-bank climbing turn (100 m/s, 600 s, 200 Hz) twice: with a perfect IMU, which
must return the truth, and with the sub-IMU error model of [Gong2018] sec. 4.1.2 (gyro 0.01 deg/h
constant + 0.01 deg/h random, accelerometer 50 ug + 50 ug), which shows free-inertial drift.
Prints an error table and the processing-time ratio, and writes a PNG of the errors.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from dpos_core.units import DEG_PER_H, UG_MPS2

from . import earth
from .analytic_trajectory import CoordinatedTurnClimb
from .attitude import attitude_error, dcm_to_quat
from .kinematics import integrate_increments
from .series import NavSeries
from .strapdown import NavState, Strapdown


def _errors(out: NavSeries, llh: np.ndarray, vel: np.ndarray, C: np.ndarray) -> dict[str, np.ndarray]:
    pos = earth.dllh_to_enu(out.llh - llh, llh)
    return {"pos_m": pos, "vel_mps": out.vel_n_mps - vel, "att_rad": attitude_error(out.C_nb, C)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dpos-strapdown-demo", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=600.0, help="flight duration [s] (default 600)")
    ap.add_argument("--rate", type=float, default=200.0, help="IMU rate [Hz] (default 200)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("out/demo"), help="directory for the PNG")
    args = ap.parse_args(argv)
    if args.duration <= 0 or args.rate <= 0:
        ap.error("--duration and --rate must be positive")

    traj = CoordinatedTurnClimb()
    t = np.arange(0.0, args.duration + 0.5 / args.rate, 1.0 / args.rate)
    llh, vel, C = traj.truth(t)
    dth, dv = integrate_increments(traj.imu_rates, t)
    s0 = NavState(0.0, dcm_to_quat(C[0]), vel[0], llh[0])
    print(f"dpos strapdown demo: {traj.speed_mps:.0f} m/s, {np.rad2deg(traj.bank_rad):.0f} deg bank "
          f"({np.rad2deg(traj.turn_rate_radps):.2f} deg/s), +-{traj.climb_amp_m:.0f} m climbs, "
          f"{args.duration:.0f} s at {args.rate:.0f} Hz from 40N 116E 500 m")

    Strapdown(s0).run_increments(t[1:3], dth[:2], dv[:2])  # JIT warm-up (cached on disk)
    t0 = time.perf_counter()
    perfect = Strapdown(s0).run_increments(t[1:], dth, dv)
    elapsed = time.perf_counter() - t0
    e_perfect = _errors(perfect, llh[1:], vel[1:], C[1:])

    rng = np.random.default_rng(args.seed)
    T = 1.0 / args.rate
    gyro_bias = rng.normal(0.0, 0.01 * DEG_PER_H, 3)
    acc_bias = rng.normal(0.0, 50 * UG_MPS2, 3)
    dth_s = dth + gyro_bias * T + rng.normal(0.0, 0.01 * DEG_PER_H, dth.shape) * T
    dv_s = dv + acc_bias * T + rng.normal(0.0, 50 * UG_MPS2, dv.shape) * T
    sensor = Strapdown(s0).run_increments(t[1:], dth_s, dv_s)
    e_sensor = _errors(sensor, llh[1:], vel[1:], C[1:])

    print(f"processing: {len(t) - 1} samples in {elapsed * 1e3:.1f} ms "
          f"(processing time / data duration = {elapsed / args.duration:.2e})")
    print()
    print(f"{'IMU':<22}{'t [s]':>7}{'|pos| [m]':>12}{'|vel| [m/s]':>13}{'att [deg]':>11}{'heading [deg]':>15}")
    for name, e in (("perfect", e_perfect), ("[Gong2018] sub-IMU", e_sensor)):
        for tq in (60.0, args.duration / 2, args.duration):
            i = min(int(round(tq * args.rate)) - 1, len(t) - 2)
            print(f"{name:<22}{t[i + 1]:>7.0f}{np.linalg.norm(e['pos_m'][i]):>12.2e}"
                  f"{np.linalg.norm(e['vel_mps'][i]):>13.2e}{np.rad2deg(np.linalg.norm(e['att_rad'][i, :2])):>11.2e}"
                  f"{np.rad2deg(abs(e['att_rad'][i, 2])):>15.2e}")

    png = _plot(args.out, t[1:], llh[1:], e_perfect, e_sensor)
    if png:
        print(f"\nerror plot: {png}")
    return 0


def _plot(out_dir: Path, t: np.ndarray, llh: np.ndarray, e_perfect: dict, e_sensor: dict) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    enu = earth.geodetic_to_enu(llh[:, 0], llh[:, 1], llh[:, 2], llh[0])
    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    ax[0, 0].plot(enu[:, 0] / 1e3, enu[:, 1] / 1e3)
    ax[0, 0].set(xlabel="East [km]", ylabel="North [km]", title="ground track", aspect="equal")
    for lab, e in (("perfect IMU", e_perfect), ("[Gong2018] sub-IMU", e_sensor)):
        ax[0, 1].semilogy(t, np.linalg.norm(e["pos_m"], axis=1) + 1e-12, label=lab)
        ax[1, 0].semilogy(t, np.linalg.norm(e["vel_mps"], axis=1) + 1e-15, label=lab)
        ax[1, 1].semilogy(t, np.rad2deg(np.linalg.norm(e["att_rad"], axis=1)) + 1e-15, label=lab)
    ax[0, 1].set(xlabel="t [s]", ylabel="m", title="position error")
    ax[1, 0].set(xlabel="t [s]", ylabel="m/s", title="velocity error")
    ax[1, 1].set(xlabel="t [s]", ylabel="deg", title="attitude error")
    for a in (ax[0, 1], ax[1, 0], ax[1, 1]):
        a.grid(True, which="both", alpha=0.3)
        a.legend()
    png = out_dir / "strapdown_errors.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png


if __name__ == "__main__":
    raise SystemExit(main())
