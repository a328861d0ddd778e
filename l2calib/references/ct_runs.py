"""One ct-lidar run over several segments, from the recording's start where it is near.

The odometry knows nothing when it starts: scan 0 becomes the map with a motion guessed from
two scans. Started mid-swing, that first map is deskewed with a wrong motion and the run carries
its error; started at rest it is right. Measured on a 20 s hand-held OS1-16 simulation (seed 1,
urban; ``docs/references.md``, "Runs"): the 4 s segment from 10.5 s tracked to 2.48 cm with a 1 s
warm-up and lost track with 3 s or 6 s of it, but to **0.19 cm** when the odometry ran from the
recording's start; the segment from 6.0 s: lost / 0.95 cm with 1 s / 3 s of warm-up, 0.22 cm
from the start. A hand-held recording usually starts at rest (the rig is picked up after the
recording starts), so:

* the segments of one sequence that lie within ``chain_gap_s`` of each other are cut from **one**
  odometry run (later segments also meet a grown map, and the shared scans are solved once);
* that run starts at the sequence's first scan when its first segment begins within
  ``from_start_s`` of it, else ``margin_s`` before the segment (the per-segment warm-up);
* when a run loses track, each of its segments is computed on its own with the per-segment
  warm-up and its earlier starts (:func:`l2calib.references.ct_lidar_source.run_segment`), as
  before runs existed.

The reference still uses the LiDAR alone: where a run starts depends on the segments' times.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, LidarScan, Segment, Sequence
from l2calib.trajectory import Trajectory


@dataclass
class OdometryRun:
    """One odometry run covering ``segments`` (of one sequence, in time order).

    Attributes:
        sequence: The sequence the segments were cut from.
        start_ns: Where the run starts (its scans: from here to the last segment's last scan).
        segments: The segments cut from it.
    """

    sequence: Sequence
    start_ns: int
    segments: list[Segment]

    def scans(self) -> list[LidarScan]:
        """The run's scans: from ``start_ns`` through the last segment's last scan."""
        last = self.segments[-1].scans[-1].stamp_ns
        loaded = self.sequence.scans.load(self.start_ns, last)
        return [m for m in loaded if isinstance(m, LidarScan)]

    def leads_in(self) -> bool:
        """Whether the run starts before its first segment's first scan."""
        return self.start_ns < self.segments[0].scans[0].stamp_ns


def plan_runs(
    segments: Seq[Segment],
    sequences: dict[str, Sequence],
    from_start_s: float,
    chain_gap_s: float,
    margin_s: float,
) -> tuple[list[OdometryRun], list[Segment]]:
    """Groups segments into runs (see the module docstring).

    Returns:
        The runs, and the segments left to the per-segment path: those of an unknown sequence
        and those alone in a run that would start no earlier than the per-segment warm-up.
    """
    by_seq: dict[str, list[Segment]] = {}
    alone: list[Segment] = []
    for seg in segments:
        (by_seq.setdefault(seg.sequence, []) if seg.sequence in sequences else alone).append(seg)
    runs: list[OdometryRun] = []
    for name, segs in by_seq.items():
        seq = sequences[name]
        groups: list[list[Segment]] = []
        for seg in sorted(segs, key=lambda s: s.start_ns):
            if groups and seg.start_ns - groups[-1][-1].end_ns <= chain_gap_s * NS_PER_S:
                groups[-1].append(seg)
            else:
                groups.append([seg])
        for group in groups:
            near = group[0].start_ns - seq.start_ns <= from_start_s * NS_PER_S
            start = seq.start_ns if near else group[0].start_ns - int(margin_s * NS_PER_S)
            if len(group) == 1 and not near:
                alone.append(group[0])
            else:
                runs.append(OdometryRun(seq, max(start, seq.start_ns), group))
    return runs, alone


def cut(
    t_ns: np.ndarray, R: np.ndarray, p: np.ndarray, seg: Segment, world_frame: str
) -> Trajectory:
    """The poses of one run (``[N]`` ns, ``[N,3,3]``, ``[N,3]``) that cover ``seg``'s points.

    From its first scan's first point through the first pose at or after its last point.
    """
    first, last = seg.scans[0].stamp_ns, seg.scans[-1].end_stamp_ns
    i0 = int(np.searchsorted(t_ns, first, side="left"))
    i1 = min(int(np.searchsorted(t_ns, last, side="left")) + 1, len(t_ns))
    q = Rotation.from_matrix(R[i0:i1]).as_quat()
    return Trajectory(t_ns[i0:i1].astype(np.int64), p[i0:i1], q, "lidar", world_frame)
