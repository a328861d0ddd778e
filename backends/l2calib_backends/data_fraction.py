"""Coarse-to-fine scoring: which part of each prepared segment an evaluation runs on.

While the policy is still wide (tens of degrees and centimetres), a part of the data ranks its
candidates as well as all of it. The trainer asks the backend for a fraction of the data
(:meth:`~l2calib.interfaces.OdometryBackend.use_data_fraction`); every candidate of the
following evaluations then runs on the same part, so the rewards of one iteration stay
comparable.

* **Windowed runs** (re-anchored windows, well-excited data): a subset of the windows, spread
  evenly over each segment (not its first stretch: the excitation varies along a recording).
  The count is decided over all segments together (:func:`window_counts`), so a fraction of a
  few short segments is not rounded up per segment; every segment keeps at least one window.
* **One continuous run** per segment (weakly excited data): all of it, whatever the fraction.
  On weakly excited data the information is spread along the drive (a yaw turn grades the lever
  arm, an acceleration on a straight the yaw of the extrinsic) and no part ranks candidates like
  the whole: scored on each drive's first quarter, a simulated ground-vehicle run came out
  0.83° off instead of 0.46°; on its most turning quarter PPO settled 50° off in yaw with a
  1.8 m lever arm that explains the turn (both in
  ``benchmarks/results/experiments/speed_weak_stretch.json``); how well a part ranks depends
  on where it lies (``benchmarks/bench_coarse_ranking.py``). Such runs save work only through
  the early stops (``docs/design.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from l2calib_backends.initialise import ReferenceMotion
from l2calib_backends.prepare import ScanTensors


@dataclass(frozen=True)
class WindowPlan:
    """The windows of one segment that an evaluation runs.

    Attributes:
        starts: First (reference-anchored) scan of each kept window.
        ends: Last scan each kept window estimates.
        keep: Indices of the kept windows among all of the segment's windows.
    """

    starts: list[int]
    ends: list[int]
    keep: list[int]

    @property
    def scans(self) -> int:
        """Scans estimated per candidate."""
        return sum(e - s for s, e in zip(self.starts, self.ends, strict=True))


def full_plan(starts: list[int], num_scans: int) -> WindowPlan:
    """All windows: window ``w`` estimates the scans up to the next window's start."""
    return WindowPlan(list(starts), list(starts[1:]) + [num_scans - 1], list(range(len(starts))))


def window_counts(windows: list[int], fraction: float) -> list[int]:
    """Windows to keep per segment for about ``fraction`` of all of them (each keeps ≥ 1).

    The total is ``ceil(fraction · Σ windows)`` (at least one per segment), split in proportion
    to each segment's windows by largest remainder.
    """
    if fraction >= 1.0:
        return list(windows)
    total = min(sum(windows), max(len(windows), math.ceil(fraction * sum(windows) - 1e-9)))
    ideal = [total * w / sum(windows) for w in windows]
    counts = [max(1, min(w, math.floor(x))) for w, x in zip(windows, ideal, strict=True)]
    order = sorted(range(len(windows)), key=lambda i: ideal[i] - math.floor(ideal[i]), reverse=True)
    for i in order * 2:  # hand out what is left, largest remainder first
        if sum(counts) >= total:
            break
        if counts[i] < windows[i]:
            counts[i] += 1
    return counts


def plan_windows(
    starts: list[int], num_scans: int, fraction: float, count: int | None = None
) -> WindowPlan:
    """The windows for about ``fraction`` (0–1] of a segment's scans (module docstring).

    ``count`` fixes how many windows a windowed segment keeps (see :func:`window_counts`).
    """
    full = full_plan(starts, num_scans)
    W = len(starts)
    if fraction >= 1.0 or W == 1 or (count is not None and count >= W):
        return full  # one continuous run: all of it (module docstring)
    n = count if count is not None else max(1, min(W, round(fraction * W)))
    keep = sorted({min(W - 1, int((i + 0.5) * W / n)) for i in range(n)})
    return WindowPlan([full.starts[w] for w in keep], [full.ends[w] for w in keep], keep)


def motion_subset(motion: ReferenceMotion, keep: list[int]) -> ReferenceMotion:
    """The reference motion at the kept windows' starts (the rest is per segment)."""
    if keep == list(range(motion.R0.shape[0])):
        return motion
    return replace(
        motion, R0=motion.R0[keep], p0=motion.p0[keep], v0=motion.v0[keep], w0=motion.w0[keep]
    )


def seeds_subset(seeds: ScanTensors | None, keep: list[int]) -> ScanTensors | None:
    """The own-map seed points of the kept windows (``None`` in the shared-map mode)."""
    if seeds is None or keep == list(range(seeds.points.shape[0])):
        return seeds
    return ScanTensors(seeds.points[keep], seeds.dt_end[keep], seeds.mask[keep], seeds.ranges[keep])
