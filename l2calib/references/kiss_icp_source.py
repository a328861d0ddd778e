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

import logging
from collections.abc import Sequence as Seq

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.data import NS_PER_S, LidarScan, Segment, Sequence
from l2calib.errors import DataError, ReferenceSourceError
from l2calib.interfaces import ReferenceSource, ReferenceTrajectory
from l2calib.references.cache import (
    ReferenceCache,
    cache_key,
    segment_fingerprint,
    trajectory_arrays,
    trajectory_from_arrays,
)
from l2calib.references.options import KissIcpReferenceOptions
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")
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


class KissIcpReference(ReferenceSource):
    """Reference trajectories from KISS-ICP, cached on disk.

    Args:
        options: Settings (KISS-ICP's own plus iterations, warm-up margin and cache).
        sequences: The sequences the segments were cut from (by ``Segment.sequence`` name), to
            load warm-up scans; ``None`` runs without warm-up.
        progress: Show a rich progress bar per segment.
    """

    def __init__(
        self,
        options: KissIcpReferenceOptions,
        sequences: Seq[Sequence] | None = None,
        progress: bool = False,
        **_: object,
    ) -> None:
        self.options = options
        self.sequences = {s.name: s for s in (sequences or [])}
        self.progress = progress
        self.cache = ReferenceCache(options.cache_dir, options.cache)

    def _warmup(self, seg: Segment) -> list[LidarScan]:
        seq = self.sequences.get(seg.sequence)
        if seq is None or self.options.margin_s <= 0:
            return []
        start = seg.start_ns - int(self.options.margin_s * NS_PER_S)
        first = seg.scans[0].stamp_ns if seg.measurements else seg.start_ns
        return [m for m in seq.scans.load(start, first - 1) if isinstance(m, LidarScan)]

    def key(self, seg: Segment, warmup: list[LidarScan]) -> str:
        """Cache key of one segment's reference."""
        opts = self.options.model_dump(exclude={"cache", "cache_dir"})
        return cache_key(
            {
                "source": NAME,
                "kiss_icp": _kiss_version(),
                "options": opts,
                "segment": segment_fingerprint(seg.scans, seg.start_ns, seg.end_ns),
                "warmup": segment_fingerprint(warmup, 0, 0) if warmup else None,
            }
        )

    def compute_one(self, seg: Segment) -> ReferenceTrajectory:
        """The reference of one segment (from the cache when possible)."""
        scans = seg.scans
        warmup = self._warmup(seg)
        world = f"{NAME}:{seg.name}"
        key = self.key(seg, warmup)

        def compute() -> dict[str, np.ndarray]:
            traj = run_segment(scans, warmup, self.options, world, self.progress)
            return trajectory_arrays(traj)

        summary = {"source": NAME, "segment": seg.name, "scans": len(scans), "warmup": len(warmup)}
        arrays, hit = self.cache.get_or_compute(key, compute, summary)
        try:
            traj = trajectory_from_arrays(arrays, "lidar", world)
        except DataError as exc:  # checksummed, so only a foreign writer gets here
            log.warning("reference cache entry %s is invalid (%s); recomputing", key, exc)
            self.cache.delete(key)
            traj = trajectory_from_arrays(compute(), "lidar", world)
        log.info(
            "kiss-icp reference of %s: %d poses (%s, %d warm-up scans)",
            seg.name,
            len(traj),
            "cached" if hit else "computed",
            len(warmup),
        )
        return ReferenceTrajectory(seg.name, traj, "pose", NAME)

    def compute(self, segments: Seq[Segment]) -> list[ReferenceTrajectory]:
        """One KISS-ICP reference per segment, in order (see module docstring)."""
        return [self.compute_one(seg) for seg in segments]
