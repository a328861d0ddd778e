"""``kiss-icp`` reference: LiDAR-only odometry of each segment with KISS-ICP.

Stamps: every pose is stamped at its scan's latest point (``LidarScan.end_stamp_ns``, LiDAR
clock, int64 ns), as KISS-ICP's deskewing moves the scan into the sensor frame at that point
(see :mod:`l2calib.references.kiss_icp_runner`).

Coverage: the backends sample the reference at every scan end and at every point's time, so the
first scan's points (before its end) need a pose too. With a warm-up margin (``margin_s`` and the
pipeline passing ``sequences=``), KISS-ICP starts on the scans before the segment; the last
warm-up pose (a scan end at or before the segment's first point) is kept and the rest dropped.
The warm-up also gives KISS-ICP its velocity and local map before the segment starts, so the
segment's first scans are deskewed and registered like any other. Without a margin (a segment at
the start of a sequence, or no sequences given), one pose is extrapolated back to the first scan's
earliest point with the first inter-scan motion (constant velocity).

Each segment gets its own world frame (``world_frame="kiss-icp:<segment>"``): KISS-ICP starts at
the identity, and runs on different segments are not registered to each other.
"""

from __future__ import annotations

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.data import LidarScan
from l2calib.errors import DataError, ReferenceSourceError
from l2calib.references.odometry_source import LidarOdometryReference
from l2calib.references.options import KissIcpReferenceOptions
from l2calib.trajectory import Trajectory

NAME = "kiss-icp"


def _kiss_version() -> str:
    from importlib.metadata import version

    return version("kiss-icp")


def extrapolate_start(traj: Trajectory, start_ns: int) -> Trajectory:
    """Prepends the pose at ``start_ns`` (< first stamp), extrapolating the first motion.

    ``T(start) = T0 · exp(-s · log(T0⁻¹ T1))`` with ``s = (t0 - start) / (t1 - t0)``.
    """
    if len(traj) < 2 or start_ns >= traj.stamps_ns[0]:
        return traj
    T = traj.matrices()
    s = float(traj.stamps_ns[0] - start_ns) / float(traj.stamps_ns[1] - traj.stamps_ns[0])
    xi = geo.se3_log(geo.transform_inverse(T[0]) @ T[1])
    T_start = T[0] @ geo.se3_exp(-s * xi)
    stamps = np.concatenate([[start_ns], traj.stamps_ns]).astype(np.int64)
    return Trajectory.from_matrices(
        stamps, torch.cat([T_start[None], T]), traj.body_frame, traj.world_frame
    )


def run_segment(
    scans: list[LidarScan],
    warmup: list[LidarScan],
    options: KissIcpReferenceOptions,
    world_frame: str,
    progress: bool = False,
) -> Trajectory:
    """KISS-ICP over ``warmup + scans``; returns the poses covering ``scans`` (module docstring).

    Raises:
        ReferenceSourceError: fewer than 2 scans, bad options, or a non-finite KISS-ICP pose.
    """
    from l2calib.references.kiss_icp_runner import run_kiss_icp

    if len(scans) < 2:
        raise ReferenceSourceError(
            f"kiss-icp needs at least 2 scans in a segment, got {len(scans)}",
            fix="select longer segments (selection.window_s) or check the LiDAR topic",
        )
    try:
        traj = run_kiss_icp(
            warmup + scans, options, progress, deskew_iterations=options.deskew_iterations
        )
    except DataError as exc:
        raise ReferenceSourceError(f"kiss-icp: {exc.message}", fix=exc.fix) from None
    traj = Trajectory(traj.stamps_ns, traj.t_world_body, traj.quat_xyzw, "lidar", world_frame)
    first_point = scans[0].stamp_ns
    if warmup:
        before = np.flatnonzero(traj.stamps_ns[: len(warmup)] <= first_point)
        keep_from = int(before[-1]) if before.size else len(warmup)
        traj = traj.slice_time(int(traj.stamps_ns[keep_from]), int(traj.stamps_ns[-1]))
    return extrapolate_start(traj, first_point)


class KissIcpReference(LidarOdometryReference):
    """Reference trajectories from KISS-ICP, cached on disk.

    Args:
        options: Settings (KISS-ICP's own plus iterations, warm-up margin and cache).
        sequences: The sequences the segments were cut from, for warm-up scans (or ``None``).
        progress: Show a rich progress bar per segment.
    """

    name = NAME

    def version(self) -> str:
        """The installed kiss-icp's version."""
        return _kiss_version()

    def run_segment(
        self, scans: list[LidarScan], warmup: list[LidarScan], world_frame: str
    ) -> Trajectory:
        """KISS-ICP over the segment (see :func:`run_segment`)."""
        return run_segment(scans, warmup, self.options, world_frame, self.progress)
