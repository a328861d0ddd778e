"""Peer LIO for :mod:`benchmarks.bench_backends`: ``rko-lio`` (PRBonn) on a simulated run.

rko-lio (``pip install rko-lio``; MIT; C++ with a Python API) runs one trajectory per instance
and takes the extrinsics per call: ``add_imu_measurement(..., extrinsic_imu2base)`` and
``register_scan(points, abs_point_stamps_ns, extrinsic_lidar2base, start_ns, end_ns)``. Here the
base frame is the IMU (``imu2base = I``, ``lidar2base = T_imu_lidar``), so its poses are
``T_world_imu`` at each scan's end; the LiDAR poses are ``T_world_imu @ T_imu_lidar``. IMU samples
up to each scan's end are fed before the scan (what its ``LidarIMUSequencer`` does). It starts in
its own gravity-aligned frame (``initialization_phase``, the run begins with 1 s at rest), so its
APE is computed after an SE(3) Umeyama alignment (evo's APE), unlike the l2calib backends, which
start in the reference frame. No visualisation, no logging to disk (the C++ core prints a
profiling summary at exit, which cannot be switched off).

Timing covers only the ``add_imu_measurement`` / ``register_scan`` loop (inputs converted first).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.alignment import ape
from l2calib.trajectory import Trajectory

PEER_CASES = {  # label -> LIOConfig overrides (defaults otherwise)
    "rko-lio defaults": {},
    "rko-lio voxel 0.5 m": {"voxel_size": 0.5},
}


def run_rko_lio(run, overrides: dict[str, Any], threads: int = 1) -> dict[str, Any]:
    """One rko-lio run over ``run`` with the true extrinsic: timing and SE(3)-aligned APE."""
    from rko_lio.config import LIOConfig
    from rko_lio.lio import LIO

    cfg = LIOConfig(**{"max_num_threads": threads, "initialization_phase": True, **overrides})
    imu = run.imu
    scans = [
        (s.stamp_ns, s.end_stamp_ns, np.asarray(s.points_lidar, np.float64), s.point_stamps_ns)
        for s in run.scans
        if len(s)
    ]
    eye, T = np.eye(4), np.asarray(run.T_imu_lidar, np.float64)
    lio = LIO(cfg)
    j, m = 0, len(imu.stamps_ns)
    t, c = time.perf_counter(), time.process_time()
    for start, end, pts, stamps in scans:
        while j < m and imu.stamps_ns[j] < end:
            lio.add_imu_measurement(
                imu.accel_m_s2[j], imu.gyro_rad_s[j], int(imu.stamps_ns[j]), eye
            )
            j += 1
        lio.register_scan(pts, stamps, T, start, end)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    stamps_ns, poses = lio.poses_with_timestamps()
    stamps_ns, poses = np.asarray(stamps_ns, np.int64), np.asarray(poses, np.float64)
    T_world_imu = geo.transform_from_quat(
        torch.from_numpy(poses[:, 3:7]), torch.from_numpy(poses[:, :3])
    ).numpy()
    keep = stamps_ns >= run.scans[0].stamp_ns + 1_000_000_000  # as the backends: from 1 s on
    est = Trajectory.from_matrices(stamps_ns[keep], T_world_imu[keep] @ T, body_frame="lidar")
    err = ape(run.gt_lidar, est)
    return {
        "backend": "rko-lio",
        "config": {k: getattr(cfg, k) for k in ("voxel_size", "max_num_threads", "deskew",
                                               "double_downsample", "initialization_phase")},
        "scans": len(scans),
        "poses": int(keep.sum()),
        "seconds": wall,
        "cpu_seconds": cpu,
        "scans_per_s": len(scans) / wall,
        "scans_per_cpu_s": len(scans) / cpu,
        "ape_rmse_m": err.rmse_t,
        "ape_max_m": float(err.e_t.max()),
        "ape_rot_rmse_deg": err.rmse_r_deg,
        "alignment": "se3",
    }  # fmt: skip


def rko_lio_cases(run, quick: bool = False, threads: int = 1) -> dict[str, Any]:
    """Every :data:`PEER_CASES` entry, or an ``error`` entry saying why rko-lio could not run."""
    try:
        import rko_lio  # noqa: F401
    except ImportError as exc:
        return {"error": f"rko-lio is not installed ({exc}); pip install rko-lio"}
    cases = dict(list(PEER_CASES.items())[:1]) if quick else PEER_CASES
    return {"cases": {label: run_rko_lio(run, o, threads) for label, o in cases.items()}}
