"""Timing statistics of a topic: rate, span, gaps, non-monotonic stamps, header vs record time.

:func:`lidar_gaps` finds the holes of a LiDAR stream that matter for calibration: a hole left by
at most :data:`MAX_BRIDGED_EMPTY_SCANS` consecutive empty scans (no valid point; dropped on
reading) is bridged, as the IMU carries the odometry over a few scan periods; longer runs of
empty scans and missing messages are gaps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from l2calib.data import NS_PER_S


@dataclass(frozen=True)
class StampStats:
    """Timing of one topic's header stamps (and their record times).

    Attributes:
        count: Messages.
        first_ns, last_ns: Earliest and latest header stamp (ns).
        rate_hz: 1 / median interval (0 with fewer than two messages).
        gap_threshold_s: Intervals longer than this are gaps.
        gaps_ns: ``[(before_ns, after_ns), ...]`` stamps around each gap, in time order.
        non_monotonic: Messages whose stamp is earlier than the previous one (arrival order).
        duplicates: Messages with the same stamp as an earlier one.
        record_minus_header_s: ``(median, max |.|)`` of record time minus header stamp (s), or
            ``None`` without record times.
        zero_stamps: Messages with a zero header stamp (driver left it unset).
    """

    count: int
    first_ns: int
    last_ns: int
    rate_hz: float
    gap_threshold_s: float
    gaps_ns: list[tuple[int, int]] = field(default_factory=list)
    non_monotonic: int = 0
    duplicates: int = 0
    record_minus_header_s: tuple[float, float] | None = None
    zero_stamps: int = 0

    @property
    def span_s(self) -> float:
        """Last minus first stamp (s)."""
        return (self.last_ns - self.first_ns) / NS_PER_S

    @property
    def max_gap_s(self) -> float:
        """Longest gap (s), 0 without gaps."""
        return max(((b - a) / NS_PER_S for a, b in self.gaps_ns), default=0.0)

    def as_dict(self) -> dict:
        """JSON-serialisable form."""
        return {
            "count": self.count,
            "first_ns": self.first_ns,
            "last_ns": self.last_ns,
            "span_s": self.span_s,
            "rate_hz": self.rate_hz,
            "gap_threshold_s": self.gap_threshold_s,
            "gaps_ns": [list(g) for g in self.gaps_ns],
            "max_gap_s": self.max_gap_s,
            "non_monotonic": self.non_monotonic,
            "duplicates": self.duplicates,
            "record_minus_header_s": self.record_minus_header_s,
            "zero_stamps": self.zero_stamps,
        }


def stamp_stats(
    header_ns: np.ndarray,
    record_ns: np.ndarray | None = None,
    gap_factor: float = 5.0,
    min_gap_s: float = 0.0,
) -> StampStats:
    """Timing statistics of stamps in arrival order.

    Args:
        header_ns: ``[N]`` header stamps in the order the messages were recorded.
        record_ns: ``[N]`` record times, or ``None``.
        gap_factor: An interval longer than ``gap_factor`` x the median interval is a gap.
        min_gap_s: ... and longer than this (s).
    """
    h = np.asarray(header_ns, dtype=np.int64)
    n = int(h.size)
    if n == 0:
        return StampStats(0, 0, 0, 0.0, 0.0)
    d_arrival = np.diff(h)
    s = np.unique(h)
    d = np.diff(s)
    med = float(np.median(d)) / NS_PER_S if d.size else 0.0
    thr = max(gap_factor * med, min_gap_s)
    gaps = []
    if d.size and thr > 0:
        idx = np.flatnonzero(d > thr * NS_PER_S)
        gaps = [(int(s[i]), int(s[i + 1])) for i in idx]
    rmh = None
    if record_ns is not None and len(record_ns) == n:
        diff = (np.asarray(record_ns, dtype=np.int64) - h) / NS_PER_S
        rmh = (float(np.median(diff)), float(np.max(np.abs(diff))))
    return StampStats(
        count=n,
        first_ns=int(s[0]),
        last_ns=int(s[-1]),
        rate_hz=1.0 / med if med > 0 else 0.0,
        gap_threshold_s=thr,
        gaps_ns=gaps,
        non_monotonic=int(np.count_nonzero(d_arrival < 0)),
        duplicates=n - int(s.size),
        record_minus_header_s=rmh,
        zero_stamps=int(np.count_nonzero(h == 0)),
    )


#: Consecutive empty scans (dropped on reading) that still do not make a LiDAR gap.
MAX_BRIDGED_EMPTY_SCANS = 2


def lidar_gaps(
    stamps_ns: np.ndarray, empty_before: np.ndarray | None, gap_factor: float
) -> list[tuple[int, int]]:
    """Gaps between kept LiDAR scans that are not bridged over a few empty scans.

    Args:
        stamps_ns: ``[S]`` increasing stamps of the scans that kept points.
        empty_before: ``[S]`` empty messages right before each kept scan (``None``: unknown,
            every hole counts).
        gap_factor: A hole longer than ``gap_factor`` x the median scan interval is a gap
            (plus one interval per bridged empty scan).

    Returns:
        ``[(before_ns, after_ns), ...]`` stamps of the kept scans around each gap.
    """
    st = np.asarray(stamps_ns, dtype=np.int64)
    d = np.diff(st)
    if d.size == 0:
        return []
    med = float(np.median(d))
    allowed = np.full(d.size, gap_factor * med)
    if empty_before is not None:
        n = np.asarray(empty_before, dtype=np.int64)[1:]
        bridged = (n > 0) & (n <= MAX_BRIDGED_EMPTY_SCANS)
        allowed[bridged] += n[bridged] * med
    return [(int(st[i]), int(st[i + 1])) for i in np.flatnonzero(d > allowed)]
