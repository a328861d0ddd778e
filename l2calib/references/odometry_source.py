"""Shared machinery of the LiDAR-odometry references (``kiss-icp``, ``ct-lidar``).

Both run a LiDAR-only odometry over each segment, optionally starting ``margin_s`` earlier on the
sequence's scans (warm-up: velocity and local map are ready when the segment starts), give each
segment its own world frame (``"<name>:<segment>"``) and cache the result on disk keyed by the
input scans, the options and the engine's version (:mod:`l2calib.references.cache`).
"""

from __future__ import annotations

import logging
from abc import abstractmethod
from collections.abc import Sequence as Seq
from typing import Any

import numpy as np

from l2calib.data import NS_PER_S, LidarScan, Segment, Sequence
from l2calib.errors import DataError, ReferenceLostTrackError
from l2calib.interfaces import ReferenceSource, ReferenceTrajectory
from l2calib.references.cache import (
    ReferenceCache,
    alternative_from_arrays,
    cache_key,
    segment_fingerprint,
    trajectory_arrays,
    trajectory_from_arrays,
)
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")


class LidarOdometryReference(ReferenceSource):
    """A reference source that runs a LiDAR odometry per segment, with warm-up and cache.

    Subclasses set :attr:`name` and implement :meth:`version` and :meth:`run_segment`.

    Args:
        options: The source's options (a model with ``margin_s``, ``cache``, ``cache_dir``).
        sequences: The sequences the segments were cut from (by ``Segment.sequence`` name), to
            load warm-up scans; ``None`` runs without warm-up.
        progress: Show a progress bar per segment.
    """

    name: str = ""

    def __init__(
        self, options: Any, sequences: Seq[Sequence] | None = None, progress: bool = False,
        **_: object,
    ) -> None:  # fmt: skip
        self.options = options
        self.sequences = {s.name: s for s in (sequences or [])}
        self.progress = progress
        self.cache = ReferenceCache(options.cache_dir, options.cache)

    @abstractmethod
    def version(self) -> str:
        """Version of the odometry engine (part of the cache key)."""

    @abstractmethod
    def run_segment(
        self, scans: list[LidarScan], warmup: list[LidarScan], world_frame: str
    ) -> Trajectory:
        """Poses ``T_world_lidar`` covering ``scans`` from their first point to the last end."""

    def run_passes(
        self, scans: list[LidarScan], warmup: list[LidarScan], world_frame: str, **extra: Any
    ) -> tuple[Trajectory, Trajectory | None]:
        """:meth:`run_segment`'s poses and a second estimate at the same stamps, or ``None``.

        The second is :attr:`ReferenceTrajectory.alternative` (none here; ct-lidar's backward
        pass gives one).
        """
        return self.run_segment(scans, warmup, world_frame, **extra), None

    def warmup_s(self) -> float:
        """Seconds of scans loaded before each segment (``margin_s``; more where retried)."""
        return self.options.margin_s

    def _warmup(self, seg: Segment) -> list[LidarScan]:
        seq = self.sequences.get(seg.sequence)
        if seq is None or self.warmup_s() <= 0:
            return []
        start = seg.start_ns - int(self.warmup_s() * NS_PER_S)
        first = seg.scans[0].stamp_ns if seg.measurements else seg.start_ns
        return [m for m in seq.scans.load(start, first - 1) if isinstance(m, LidarScan)]

    def key_options(self) -> dict[str, Any]:
        """The options that decide the result (part of the cache key)."""
        return self.options.model_dump(exclude={"cache", "cache_dir"})

    def leadout(self, seg: Segment) -> list[LidarScan]:
        """Scans after the segment that the source also runs on (none here).

        ct-lidar's backward pass starts on them.
        """
        return []

    def key(self, seg: Segment, warmup: list[LidarScan], leadout: Seq[LidarScan] = ()) -> str:
        """Cache key of one segment's reference."""
        opts = self.key_options()
        parts = {
            "source": self.name,
            "engine": self.version(),
            "options": opts,
            "segment": segment_fingerprint(seg.scans, seg.start_ns, seg.end_ns),
            "warmup": segment_fingerprint(warmup, 0, 0) if warmup else None,
        }
        if leadout:
            parts["leadout"] = segment_fingerprint(list(leadout), 0, 0)
        return cache_key(parts)

    def compute_one(self, seg: Segment) -> ReferenceTrajectory:
        """The reference of one segment (from the cache when possible)."""
        scans = seg.scans
        warmup = self._warmup(seg)
        leadout = self.leadout(seg)
        world = f"{self.name}:{seg.name}"
        key = self.key(seg, warmup, leadout)
        extra = {"leadout": leadout} if leadout else {}

        def compute() -> dict[str, np.ndarray]:
            return trajectory_arrays(*self.run_passes(scans, warmup, world, **extra))

        summary = {"source": self.name, "segment": seg.name, "scans": len(scans),
                   "warmup": len(warmup)}  # fmt: skip
        arrays, hit = self.cache.get_or_compute(key, compute, summary)
        try:
            traj = trajectory_from_arrays(arrays, "lidar", world)
            alternative = alternative_from_arrays(arrays, "lidar", world)
        except DataError as exc:  # checksummed, so only a foreign writer gets here
            log.warning("reference cache entry %s is invalid (%s); recomputing", key, exc)
            self.cache.delete(key)
            arrays = compute()
            traj = trajectory_from_arrays(arrays, "lidar", world)
            alternative = alternative_from_arrays(arrays, "lidar", world)
        log.info(
            "%s reference of %s: %d poses (%s, %d warm-up scans)",
            self.name,
            seg.name,
            len(traj),
            "cached" if hit else "computed",
            len(warmup),
        )
        return ReferenceTrajectory(seg.name, traj, "pose", self.name, alternative=alternative)

    def compute_results(
        self, segments: Seq[Segment]
    ) -> dict[str, ReferenceTrajectory | ReferenceLostTrackError]:
        """Each segment's reference, or the error of the odometry that lost track on it."""
        out: dict[str, ReferenceTrajectory | ReferenceLostTrackError] = {}
        for seg in segments:
            try:
                out[seg.name] = self.compute_one(seg)
            except ReferenceLostTrackError as exc:
                out[seg.name] = exc
        return out

    def compute(self, segments: Seq[Segment]) -> list[ReferenceTrajectory]:
        """One reference per segment, in order (see module docstring).

        Raises:
            ReferenceLostTrackError: on any segment where the odometry lost track, after trying
                every segment; its ``lost`` names those segments and ``tracked`` holds the
                references of the others (the pipeline calibrates on those).
        """
        results = self.compute_results(segments)
        refs = [r for s in segments if isinstance(r := results[s.name], ReferenceTrajectory)]
        lost = {s.name: r for s in segments if isinstance(r := results[s.name], Exception)}
        if not lost:
            return refs
        name, first = next(iter(lost.items()))
        others = f" (also lost: {', '.join(list(lost)[1:])})" if len(lost) > 1 else ""
        raise ReferenceLostTrackError(
            f"{self.name} lost track on {len(lost)} of {len(segments)} segment(s); on {name}: "
            f"{first.message}{others}",
            fix=first.fix,
            lost=list(lost),
            tracked=refs,
        )
