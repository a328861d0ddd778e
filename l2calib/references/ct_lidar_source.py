"""``ct-lidar`` reference: continuous-time LiDAR-only odometry of each segment.

The engine is :mod:`l2calib.references.ct_odometry`: every scan has its own smooth motion, so
aggressive hand-held motion that defeats KISS-ICP's constant-velocity deskew is followed (see
``docs/references.md`` for measured accuracy). Poses are written at ``poses_per_scan`` even
times in every scan (the first at the scan's first point) and at the last scan's latest point,
so the reference covers every point of the segment without extrapolation. Warm-up, per-segment
world frames (``ct-lidar:<segment>``) and the disk cache are those of
:class:`~l2calib.references.odometry_source.LidarOdometryReference`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import LidarScan
from l2calib.references.ct_odometry import CtLidarOdometry, sample_poses
from l2calib.references.odometry_source import LidarOdometryReference
from l2calib.trajectory import Trajectory

NAME = "ct-lidar"
ENGINE_VERSION = "8"  # bump when the odometry's results change, to invalidate cached references


def run_segment(
    scans: list[LidarScan],
    warmup: list[LidarScan],
    options,  # noqa: ANN001 - CtLidarOptions
    world_frame: str,
    progress: bool = False,
) -> Trajectory:
    """The odometry over ``warmup + scans``; keeps the poses from the segment's first point.

    Raises:
        ReferenceSourceError: fewer than 2 scans, or a non-finite pose.
    """
    all_scans = warmup + scans
    odo = CtLidarOdometry(options)
    if progress:
        from rich.progress import Progress

        with Progress(transient=True) as bar:
            task = bar.add_task(f"{NAME} {world_frame}", total=len(all_scans) - 1)
            stamps, motions = odo.run(all_scans, on_scan=lambda _: bar.advance(task))
    else:
        stamps, motions = odo.run(all_scans)
    t, R, p = sample_poses(stamps, motions, all_scans[-1].end_stamp_ns, options.poses_per_scan)
    keep = t >= scans[0].stamp_ns
    q = Rotation.from_matrix(R[keep]).as_quat()
    return Trajectory(t[keep].astype(np.int64), p[keep], q, "lidar", world_frame)


class CtLidarReference(LidarOdometryReference):
    """Reference trajectories from the continuous-time LiDAR odometry, cached on disk.

    Args:
        options: :class:`~l2calib.references.options.CtLidarOptions`.
        sequences: The sequences the segments were cut from, for warm-up scans (or ``None``).
        progress: Show a progress bar per segment.
    """

    name = NAME

    def version(self) -> str:
        """Version of the engine's results."""
        return ENGINE_VERSION

    def run_segment(
        self, scans: list[LidarScan], warmup: list[LidarScan], world_frame: str
    ) -> Trajectory:
        """The odometry over the segment (see :func:`run_segment`)."""
        return run_segment(scans, warmup, self.options, world_frame, self.progress)
