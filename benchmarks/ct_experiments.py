"""ct-lidar experiments: APE, loss and per-term motion errors on short simulated runs.

Run (single-threaded)::

    OMP_NUM_THREADS=1 python -m benchmarks.ct_experiments --cases hh16-0 uav16-11 \
        --duration 12 --set neighbours=20 --terms

Prints one row per case: SE(3)-aligned APE RMSE and max (cm) of the poses solved (up to the
loss, if lost), lost yes/no and when, seconds per scan. ``--terms`` also prints, per second of
the run, the RMS error of each motion term (``R_b``, ``t_b``, ``ω``, ``α``, ``v``, ``a``)
against the truth's least-squares fit of the same model over each scan (unaligned: the
odometry's world is the truth's LiDAR pose at the first scan).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.alignment import ape
from l2calib.data import NS_PER_S
from l2calib.errors import ReferenceLostTrackError
from l2calib.references.ct_motion import sample_poses
from l2calib.references.ct_odometry import CtLidarOdometry
from l2calib.references.options import CtLidarOptions
from l2calib.sim import SimConfig, lidar_models, simulate
from l2calib.trajectory import Trajectory

#: case -> (motion profile, LiDAR model, world, seed)
CASES = {
    "hh16-0": ("handheld", "ouster-os1-16", "urban", 0),
    "hh16-1": ("handheld", "ouster-os1-16", "urban", 1),
    "uav16-11": ("uav", "ouster-os1-16", "urban", 11),
    "uav16-hall-1": ("uav", "ouster-os1-16", "hall", 1),
    "ugv16-2": ("ugv", "ouster-os1-16", "urban", 2),
    "hh360-0": ("handheld", "livox-mid360", "urban", 0),
    "hhvlp16-3": ("handheld", "velodyne-vlp-16", "urban", 3),
    "uavvlp16-4": ("uav", "velodyne-vlp-16", "hall", 4),
    "hh64-5": ("handheld", "ouster-os1-64", "hall", 5),
    "ugv32-6": ("ugv", "velodyne-vlp-32c", "urban", 6),
    "uavxt32-7": ("uav", "hesai-pandar-xt32", "urban", 7),
    "uavvlp16-5": ("uav", "velodyne-vlp-16", "hall", 5),
    "uavvlp16-6": ("uav", "velodyne-vlp-16", "urban", 6),
    "hhvlp16-1": ("handheld", "velodyne-vlp-16", "urban", 1),
    "hhvlp16-2": ("handheld", "velodyne-vlp-16", "urban", 2),
    "hhvlp32-1": ("handheld", "velodyne-vlp-32c", "urban", 1),
    "hhxt32-1": ("handheld", "hesai-pandar-xt32", "urban", 1),
    "hh64-1": ("handheld", "ouster-os1-64", "urban", 1),
}


def simulate_case(name: str, duration_s: float, lidar_set: dict | None = None):  # noqa: ANN201
    """The simulated run of a case; ``lidar_set`` overrides the sim config's ``lidar`` fields."""
    profile, lidar, world, seed = CASES[name]
    cfg = {
        "duration_s": duration_s,
        "seed": seed,
        "world": {"name": world},
        "motion": {"profile": profile},
        "lidar": {"model": lidar, **(lidar_set or {})},
        "imu": {"model": "vn100"},
    }
    return simulate(SimConfig.model_validate(cfg))


def true_terms(run, stamps: np.ndarray, ends: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """``[S, 6, 3]`` truth's ``[rotvec(R_b), t_b, ω, α, v, a]`` per scan (odometry world)."""
    T0_inv = np.linalg.inv(run.lidar_poses(stamps[:1])[0])
    out = np.zeros((len(stamps), 6, 3))
    for k, (s, e) in enumerate(zip(stamps, ends, strict=True)):
        t_ns = np.linspace(s, e, 21).astype(np.int64)
        T = T0_inv @ run.lidar_poses(t_ns)
        tau = (t_ns - s) / NS_PER_S
        A = np.stack([tau, tau**2], axis=1)
        R_b = T[0, :3, :3]
        phi = Rotation.from_matrix(R_b.T @ T[:, :3, :3]).as_rotvec()
        w_al = np.linalg.lstsq(A, phi, rcond=None)[0]
        A3 = np.stack([np.ones_like(tau), tau, tau**2], axis=1)
        p = np.linalg.lstsq(A3, T[:, :3, 3], rcond=None)[0]
        out[k] = [Rotation.from_matrix(R_b).as_rotvec(), p[0], w_al[0], w_al[1], p[1], p[2]]
    return out


def term_errors(motions, truth: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """``[S, 6]`` norms of each term's error (rotation in deg, rest in the terms' units)."""
    err = np.zeros((len(motions), 6))
    for k, m in enumerate(motions):
        R_true = Rotation.from_rotvec(truth[k, 0]).as_matrix()
        err[k, 0] = np.degrees(np.linalg.norm(Rotation.from_matrix(R_true.T @ m.R_b).as_rotvec()))
        est = [m.t_b, m.omega, m.alpha, m.v, m.a]
        err[k, 1:] = [np.linalg.norm(x - truth[k, i + 1]) for i, x in enumerate(est)]
    return err


def run_case(
    name: str, duration_s: float, options: dict, terms: bool, lidar_set: dict | None = None
) -> dict:
    """Runs ct-lidar on one case; the row of results."""
    run = simulate_case(name, duration_s, lidar_set)
    scans = run.sequence().segment().scans
    odo = CtLidarOdometry(CtLidarOptions.model_validate(options))
    solved: list = []
    olds: list = []  # per scan: median distance to the old map (m), NaN if not checked
    ratios: list = []  # per scan: inlier ratio
    infos: list = []  # per scan: weakest information of the old map's planes (points)
    check = odo._check_tracking

    def recording_check(k, stamps, m):  # noqa: ANN001, ANN202
        if k == 1:
            solved.append(odo._start_motion)
        solved.append(m)
        olds.append(odo.last_old_residual)
        ratios.append(odo.last_inlier_ratio)
        infos.append(odo.last_old_info)
        check(k, stamps, m)

    odo._check_tracking = recording_check
    forward = odo._forward

    def recording_forward(prepared, stamps, start, *args, **kwargs):  # noqa: ANN001, ANN202
        odo._start_motion = start
        solved.clear()
        return forward(prepared, stamps, start, *args, **kwargs)

    odo._forward = recording_forward
    t0 = time.perf_counter()
    lost = None
    try:
        odo.run(scans)
    except ReferenceLostTrackError as exc:
        lost = str(exc).split("(")[0].replace("ct-lidar lost track ", "").strip()
    seconds = time.perf_counter() - t0
    motions = solved if lost is None else solved[:-1]
    stamps = np.array([s.stamp_ns for s in scans[: len(motions)]], np.int64)
    end_ns = scans[len(motions) - 1].end_stamp_ns
    t, R, p = sample_poses(stamps, motions, end_ns, 4)
    est = Trajectory(t, p, Rotation.from_matrix(R).as_quat(), "lidar", "odom")
    res = ape(run.gt_lidar, est)
    row = {
        "case": name,
        "lidar": run.lidar_spec.name,
        "ape_cm": round(100 * res.rmse_t, 2),
        "max_cm": round(100 * float(res.e_t.max()), 2),
        "lost": lost,
        "scans": f"{len(motions)}/{len(scans)}",
        "s_per_scan": round(seconds / len(scans), 3),
        "old_med_cm_p50_max": [
            round(100 * float(np.nanmedian(olds)), 2) if np.isfinite(olds).any() else None,
            round(100 * float(np.nanmax(olds)), 2) if np.isfinite(olds).any() else None,
        ],
        "old_info_min_p10_p50": [
            round(float(np.nanpercentile(infos, q)), 1) if np.isfinite(infos).any() else None
            for q in (0, 10, 50)
        ],
    }
    low = np.array(infos) < odo.o.lost_old_info
    longest = run_len = 0
    for x in low:
        run_len = run_len + 1 if x else 0
        longest = max(longest, run_len)
    row["old_unverified_longest_scans"] = longest
    row["inlier_min_first10_after"] = [
        round(min(ratios[:10]), 2),
        round(min(ratios[10:] or [1]), 2),
    ]
    if terms:
        ends = np.array([s.stamp_ns for s in scans[1 : len(motions) + 1]], np.int64)
        if len(ends) < len(motions):
            ends = np.append(ends, end_ns)
        truth = true_terms(run, stamps, ends)
        err = term_errors(motions, truth)
        per_s = int(round(1.0 / (np.median(np.diff(stamps)) / NS_PER_S)))
        print("  t(s)   R_b°    t_b m   ω rad/s  α       v m/s   a")
        for i in range(0, len(err), per_s):
            blk = err[i : i + per_s]
            rms = np.sqrt((blk**2).mean(axis=0))
            tt = (stamps[i] - stamps[0]) / NS_PER_S
            print(f"  {tt:4.1f} " + " ".join(f"{x:7.4f}" for x in rms))
        if lost is not None:
            print("  last 12 scans: errors | true |ω| |α| |v| |a| | inliers, old-map median cm")
            for k in range(max(0, len(err) - 12), len(err)):
                size = np.linalg.norm(truth[k, 2:], axis=1)
                print(
                    f"  {k:3d}  "
                    + " ".join(f"{x:7.4f}" for x in err[k])
                    + " | "
                    + " ".join(f"{x:6.2f}" for x in size)
                    + f" | {ratios[k - 1] if k else float('nan'):.2f} "
                    + f"{100 * olds[k - 1] if k else float('nan'):.2f}"
                )
            print("  last 12 scans: world error vectors of R_b (deg), t_b (cm), v (cm/s)")
            for k in range(max(0, len(err) - 12), len(err)):
                m = motions[k]
                R_true = Rotation.from_rotvec(truth[k, 0]).as_matrix()
                dth = np.degrees(Rotation.from_matrix(m.R_b @ R_true.T).as_rotvec())
                vecs = np.concatenate([dth, 100 * (m.t_b - truth[k, 1]), 100 * (m.v - truth[k, 4])])
                print(f"  {k:3d}  " + " ".join(f"{x:7.2f}" for x in vecs))
    return row


def parse_value(text: str):  # noqa: ANN201
    """A ``--set`` value as JSON when it parses, else as a string."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def main() -> None:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["hh16-0", "hh16-1", "uav16-11"])
    parser.add_argument("--duration", type=float, default=12.0)
    parser.add_argument(
        "--set", nargs="*", action="extend", default=[], help="CtLidarOptions field=value"
    )
    parser.add_argument("--terms", action="store_true", help="per-term errors per second")
    parser.add_argument(
        "--lidar", nargs="*", action="extend", default=[], help="sim config lidar field=value"
    )
    parser.add_argument(
        "--no-beam-azimuth", action="store_true", help="Ouster presets without beam azimuths"
    )
    args = parser.parse_args()
    options = {k: parse_value(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    lidar_set = {k: parse_value(v) for k, v in (kv.split("=", 1) for kv in args.lidar)}
    if args.no_beam_azimuth:
        for key, spec in lidar_models.LIDARS.items():
            lidar_models.LIDARS[key] = dataclasses.replace(spec, beam_azimuth_deg=())
    os.environ.setdefault("L2CALIB_CACHE", tempfile.mkdtemp(prefix="ct-exp-"))
    print(f"options {options} lidar {lidar_set} no-beam-azimuth {args.no_beam_azimuth}", flush=True)
    for name in args.cases:
        row = run_case(name, args.duration, options, args.terms, lidar_set)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
