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

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, LidarScan
from l2calib.errors import ReferenceLostTrackError
from l2calib.references.ct_motion import sample_poses
from l2calib.references.ct_odometry import CtLidarOdometry
from l2calib.references.odometry_source import LidarOdometryReference
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")

NAME = "ct-lidar"
ENGINE_VERSION = "8"  # bump when the odometry's results change, to invalidate cached references


def cold_starts(warmup: list[LidarScan], first_ns: int, options) -> list[int]:  # noqa: ANN001
    """Where the attempts start: indices into ``warmup`` (``len(warmup)``: no warm-up).

    The first ``margin_s`` before the segment's first scan (``first_ns``), each next one twice
    as far back, as far as the loaded scans reach; no index twice.
    """
    stamps = np.array([s.stamp_ns for s in warmup], np.int64)
    starts: list[int] = []
    for j in range(options.cold_starts):
        back_s = options.margin_s * 2**j
        i = int(np.searchsorted(stamps, first_ns - int(back_s * NS_PER_S)))
        if i not in starts:
            starts.append(i)
    return starts


def run_segment(
    scans: list[LidarScan],
    warmup: list[LidarScan],
    options,  # noqa: ANN001 - CtLidarOptions
    world_frame: str,
    progress: bool = False,
) -> Trajectory:
    """The odometry over ``warmup + scans``; keeps the poses from the segment's first point.

    A start mid-swing can lose track within a few seconds, and so can a hard swing met with a
    young map (measured: of 12 four-second hand-held OS1-16 segments with a 1 s warm-up, 4 of
    the first 9 lost, while the whole 20 s run from rest tracks to 0.2 cm). So where track is
    lost before ``cold_start_window_s`` into the segment, the odometry starts again twice as
    far back (:func:`cold_starts`), up to ``cold_starts`` starts; a later loss, or the last
    start's, is raised.

    Raises:
        ReferenceSourceError: fewer than 2 scans, or a non-finite pose.
        ReferenceLostTrackError: every start lost track.
    """
    starts = cold_starts(warmup, scans[0].stamp_ns, options)
    for n, i in enumerate(starts):
        all_scans = warmup[i:] + scans
        odo = CtLidarOdometry(options)
        try:
            stamps, motions = _run(odo, all_scans, world_frame, progress)
            break
        except ReferenceLostTrackError as exc:
            back = (scans[0].stamp_ns - all_scans[0].stamp_ns) / NS_PER_S
            early = (
                odo.lost_at_s is not None and odo.lost_at_s - back <= options.cold_start_window_s
            )
            if n == len(starts) - 1 or not early:
                if n == 0:
                    raise
                raise ReferenceLostTrackError(
                    f"{exc.message} (start {n + 1} of {len(starts)}, {back:.1f} s before "
                    f"{world_frame}; the starts nearer to it lost track too)",
                    fix=exc.fix,
                ) from exc
            log.info("%s: lost track %.1f s after start %d; starting earlier", world_frame,
                     odo.lost_at_s, n + 1)  # fmt: skip
    t, R, p = sample_poses(stamps, motions, all_scans[-1].end_stamp_ns, options.poses_per_scan)
    keep = t >= scans[0].stamp_ns
    q = Rotation.from_matrix(R[keep]).as_quat()
    return Trajectory(t[keep].astype(np.int64), p[keep], q, "lidar", world_frame)


def _run(odo: CtLidarOdometry, scans: list[LidarScan], world_frame: str, progress: bool):  # noqa: ANN202
    """``odo.run(scans)``, with a progress bar when asked."""
    if not progress:
        return odo.run(scans)
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task(f"{NAME} {world_frame}", total=len(scans) - 1)
        return odo.run(scans, on_scan=lambda _: bar.advance(task))


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

    def warmup_s(self) -> float:
        """``margin_s`` times room for the earlier starts (:func:`cold_starts`)."""
        return self.options.margin_s * 2 ** (self.options.cold_starts - 1)

    def run_segment(
        self, scans: list[LidarScan], warmup: list[LidarScan], world_frame: str
    ) -> Trajectory:
        """The odometry over the segment (see :func:`run_segment`)."""
        return run_segment(scans, warmup, self.options, world_frame, self.progress)
