"""What the selection tells the user about gaps and dropped scans, and why it found nothing.

:func:`gap_notes` names every IMU / LiDAR gap the selection had to work around (topic, time into
the recording, stamp, length) and the empty scans dropped on reading; :func:`no_window_reason`
explains an empty selection by its real cause (gaps, dropped scans, still periods, too little
data) instead of a generic "still or too short".
"""

from __future__ import annotations

from collections.abc import Sequence as Seq

import numpy as np

from l2calib.data import NS_PER_S, Sequence
from l2calib.selection.excitation import WindowStats

#: Gaps named one by one per sequence and sensor (the rest are counted).
MAX_NAMED_GAPS = 3


def describe_gap(seq: Sequence, kind: str, gap: tuple[int, int]) -> str:
    """``IMU gap of 2.005 s at 3.995 s (stamp 1700000003.995 s) on /imu/data``."""
    a, b = gap
    topic = seq.meta.get("imu_topic" if kind == "IMU" else "lidar_topic")
    on = f" on {topic}" if topic else ""
    return (
        f"{kind} gap of {(b - a) / NS_PER_S:.3f} s at {(a - seq.start_ns) / NS_PER_S:.3f} s "
        f"(stamp {a / NS_PER_S:.3f} s){on}"
    )


def _gap_list(seq: Sequence, stats: WindowStats) -> list[str]:
    out = []
    for kind, gaps in (("IMU", stats.imu_gaps_ns), ("LiDAR", stats.lidar_gaps_ns)):
        inside = [g for g in gaps if g[0] < seq.end_ns and g[1] > seq.start_ns]
        longest = sorted(inside, key=lambda g: g[0] - g[1])[:MAX_NAMED_GAPS]
        out += [describe_gap(seq, kind, g) for g in sorted(longest)]
        if len(inside) > len(longest):
            out.append(f"{len(inside) - len(longest)} shorter {kind} gap(s)")
    return out


def gap_notes(sequences: Seq[Sequence], stats: dict[str, WindowStats]) -> list[str]:
    """Notes on the gaps no window spans and on the empty scans dropped, per sequence."""
    notes = []
    for seq in sequences:
        ws = stats.get(seq.name)
        gaps = _gap_list(seq, ws) if ws is not None else []
        if gaps:
            notes.append(
                f"{seq.name}: {'; '.join(gaps)}: no window spans a gap (the selection uses the "
                "data on either side)"
            )
        empty = int(seq.meta.get("empty_scans", 0))
        if empty:
            topic = seq.meta.get("lidar_topic", "the LiDAR topic")
            notes.append(
                f"{seq.name}: {empty} empty / all-NaN scan(s) of {topic} dropped on reading "
                "(the windows bridge isolated ones)"
            )
    return notes


def no_window_reason(
    sequences: Seq[Sequence], stats: dict[str, WindowStats], window_s: float
) -> str:
    """Why no window of any sequence was eligible, naming gaps, dropped scans and still data."""
    parts = []
    for seq in sequences:
        ws = stats.get(seq.name)
        if ws is None or not len(ws):
            parts.append(f"{seq.name}: no IMU/LiDAR overlap to cut a window from")
            continue
        span = (seq.end_ns - seq.start_ns) / NS_PER_S
        still = float(np.mean(ws.block_still)) if len(ws.block_still) else 0.0
        why = []
        if still > 0.999:
            why.append(f"every window is still (all of its {span:.1f} s)")
        elif still > 0:
            why.append(f"{100 * still:.0f} % of its {span:.1f} s still")
        why += _gap_list(seq, ws)
        empty = int(seq.meta.get("empty_scans", 0))
        if empty:
            why.append(f"{empty} empty / all-NaN scan(s) dropped")
        if not why:  # e.g. windows with fewer than two IMU samples
            why.append(f"no window of {min(window_s, span):.1f} s holds usable IMU data")
        parts.append(f"{seq.name}: " + "; ".join(why))
    return " | ".join(parts)


#: With the selection disabled, an IMU gap longer than this inside a recording is an error (the
#: odometry would propagate over it blind: a whole 10 Hz scan period without IMU samples).
MAX_IMU_GAP_S = 0.1


def check_imu_gaps_whole(sequences: Seq[Sequence]) -> None:
    """Raises on an IMU gap a whole-recording calibration (``selection.enabled=false``) cannot use.

    Raises:
        DataError: naming the bag, the IMU topic, the gap's time, stamp and length, and the fix.
    """
    from l2calib.errors import DataError
    from l2calib.selection.excitation import IMU_GAP_FACTOR, IMU_MIN_GAP_S, find_gaps

    for seq in sequences:
        gaps = [
            g
            for g in find_gaps(seq.imu.stamps_ns, IMU_GAP_FACTOR, IMU_MIN_GAP_S)
            if g[1] - g[0] > MAX_IMU_GAP_S * NS_PER_S and g[0] < seq.end_ns and g[1] > seq.start_ns
        ]
        if not gaps:
            continue
        a, b = max(gaps, key=lambda g: g[1] - g[0])
        where = seq.meta.get("path", seq.name)
        more = ""
        if len(gaps) > 1:
            more = f" (and {len(gaps) - 1} more longer than {MAX_IMU_GAP_S:g} s)"
        raise DataError(
            f"{where}: {describe_gap(seq, 'IMU', (a, b))}{more}: with selection.enabled=false the "
            "whole recording is used and the odometry cannot run across it",
            fix="set selection.enabled=true (its windows avoid the gap), or cut the bag to end "
            f"before stamp {a / NS_PER_S:.3f} s or start after {b / NS_PER_S:.3f} s",
        )
