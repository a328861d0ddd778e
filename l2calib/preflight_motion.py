"""Whether a bag holds enough motion to calibrate (``l2calib inspect``, before any training).

:func:`motion_check` runs the recipe's data selection on the IMU samples and the LiDAR scan
stamps that ``inspect`` has already read (no point is loaded) and applies the same rules as
``calibrate``'s status (:func:`l2calib.assess.status.data_shortfalls`): selected data shorter
than half a selection window, or every IMU axis below the excitation thresholds, is too little to
calibrate. The warnings give the numbers: seconds of motion and selectable data against
``selection.window_s``, RMS rate and acceleration against the thresholds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from l2calib.data import NS_PER_S, ImuSamples, Sequence
from l2calib.errors import DataError
from l2calib.io.imu_reader import ImuTopicReader, ImuUnits, to_imu_samples
from l2calib.io.lidar_scans import LidarTopicReader
from l2calib.preflight_checks import Issue
from l2calib.recipe import SelectionConfig


@dataclass(frozen=True, eq=False)
class _ScanStamps:
    """A scan source of stamps only (the selection needs no points)."""

    stamps_ns: np.ndarray
    empty_before: np.ndarray | None = None

    def load(self, start_ns: int, end_ns: int) -> list:
        """No measurements: this source only times the scans."""
        return []


@dataclass
class MotionReport:
    """How much of a bag the selection could calibrate on.

    Attributes:
        moving_s: Time in the LiDAR-IMU overlap with IMU samples that is not still (s).
        overlap_s: LiDAR-IMU overlap (s).
        selected_s: What the selection picks (s).
        window_s, budget_s: The recipe's ``selection.window_s`` and ``selection.budget_s``.
        gyro_rms_rad_s: ``[3]`` RMS angular rate per IMU axis over the selection (over the whole
            overlap when nothing is selected).
        accel_rms_m_s2: ``[3]`` RMS gravity-free acceleration per IMU axis, likewise.
        notes: The selection's notes (gaps, dropped scans, budget).
        yaw_share: Share of the rotation about the vertical over the overlap
            (:mod:`l2calib.selection.planar`); at or above ``train.planar_min_yaw_share`` the
            motion is planar and calibrate holds the vertical lever arm.
    """

    moving_s: float
    overlap_s: float
    selected_s: float
    window_s: float
    budget_s: float
    gyro_rms_rad_s: list[float]
    accel_rms_m_s2: list[float]
    notes: list[str] = field(default_factory=list)
    yaw_share: float | None = None


def motion_check(
    path: str | Path,
    lidar: LidarTopicReader,
    imu: ImuTopicReader,
    units: ImuUnits,
    cfg: SelectionConfig,
) -> tuple[MotionReport | None, list[Issue]]:
    """Runs the selection on what ``inspect`` read; returns its numbers and warnings.

    Returns:
        ``(None, [])`` when the streams cannot be combined (the reading errors say why).
    """
    from l2calib.assess.status import data_shortfalls
    from l2calib.selection.greedy import select_windows

    where_imu = f"{path}: {imu.topic}"
    try:
        samples, _ = to_imu_samples(imu.finish(), units, where_imu)
    except DataError:
        return None, []
    index = lidar.scan_index()
    if index["stamp_ns"].size < 2:
        return None, []
    meta = {
        "imu_topic": imu.topic,
        "lidar_topic": lidar.topic,
        "empty_scans": len(lidar.stats) - int(index["stamp_ns"].size),
    }
    seq = Sequence(
        Path(path).stem, samples, _ScanStamps(index["stamp_ns"], index["empty_before"]), meta
    )
    if seq.end_ns <= seq.start_ns:
        return None, []
    sel = select_windows([seq], cfg)
    basis = sel
    if not sel.chosen:  # the excitation of the whole overlap says how still it is
        basis = select_windows([seq], cfg.model_copy(update={"enabled": False}))
    stats = sel.windows[seq.name]
    step = cfg.step_s
    overlap = (seq.end_ns - seq.start_ns) / NS_PER_S
    b0 = stats.block_start_ns
    n = np.searchsorted(samples.stamps_ns, b0 + int(step * NS_PER_S)) - np.searchsorted(
        samples.stamps_ns, b0
    )
    moving = min(overlap, float(np.count_nonzero(~stats.block_still & (n >= 2))) * step)
    report = MotionReport(
        moving_s=moving,
        overlap_s=overlap,
        selected_s=sel.total_s,
        window_s=cfg.window_s,
        budget_s=cfg.budget_s,
        gyro_rms_rad_s=[float(x) for x in basis.gyro_rms_rad_s],
        accel_rms_m_s2=[float(x) for x in basis.accel_rms_m_s2],
        notes=list(sel.notes),
    )
    planar = _planar_issue(samples, seq, f"{lidar.topic} + {imu.topic}")
    report.yaw_share = planar[0]
    excitation = (basis.gyro_rms_rad_s, basis.accel_rms_m_s2)
    issues = [
        Issue(
            "warning",
            f"{lidar.topic} + {imu.topic}",
            f"too short or too still to calibrate: {what} ({moving:.1f} s of motion in "
            f"{overlap:.1f} s of LiDAR-IMU overlap, {sel.total_s:.1f} s selectable)",
            fix,
        )
        for what, fix in data_shortfalls(sel.total_s, excitation, cfg)
    ]
    return report, issues + planar[1]


def _planar_issue(samples, seq: Sequence, where: str) -> tuple[float | None, list[Issue]]:
    """The overlap's vertical rotation share, and a note when the motion is planar."""
    from l2calib.recipe import SelectionConfig, TrainConfig
    from l2calib.selection.planar import ONE_WAY_SHARE, planar_motion

    keep = (samples.stamps_ns >= seq.start_ns) & (samples.stamps_ns <= seq.end_ns)
    if not keep.any():
        return None, []
    motion = planar_motion(
        [ImuSamples(samples.stamps_ns[keep], samples.gyro_rad_s[keep], samples.accel_m_s2[keep])]
    )
    if motion.turning_samples == 0:
        return None, []
    share = TrainConfig.model_fields["planar_min_yaw_share"].default
    budget = SelectionConfig.model_fields["planar_budget_s"].default
    window = SelectionConfig.model_fields["planar_window_s"].default
    if not motion.planar(share):
        return motion.yaw_share, []
    issues = [
        Issue(
            "info",
            where,
            f"planar, yaw-dominant motion (a ground vehicle?): {motion.describe()}. The lever "
            "arm's vertical component cannot be determined from it: calibrate holds it at "
            "policy.prior's value (else 0 m, named as not estimated), searches the rest and "
            "trains with the ground-vehicle settings (8 Newton polish rounds; from no rotation "
            "guess also no hand-over and 6 refinement rounds: l2calib.train.vertical_hold); "
            "the selection keeps up "
            f"to selection.planar_budget_s ({budget:g} s by default) of the drive in windows of "
            f"at least {window:g} s",
            "give policy.prior with the height difference from a drawing (translation_m), or "
            "add a stretch with roll and pitch (ramps, kerbs); longer drives with more turns "
            "help the rest (raise selection.planar_budget_s)",
        )
    ]
    if motion.one_way_share >= ONE_WAY_SHARE:
        issues.append(
            Issue(
                "info",
                where,
                f"the turns all go one way ({100 * motion.one_way_share:.0f} % of the turning, "
                "a loop): a LiDAR-only reference's error in the turns is then not averaged out "
                "and reaches the horizontal lever arm (simulated 16-beam drives with ct-lidar: "
                "one-way loops up to 2.4 cm off along x or y, either way round, figure-8 drives, "
                "which turn both ways and twice as much, within 1.4 cm)",
                "with ct-lidar or kiss-icp as reference, record a drive that turns both ways (a "
                "figure-8, or the loop both ways round) or calibrate several drives together; an "
                "exact reference (gt-file, rtk) is not affected",
            )
        )
    return motion.yaw_share, issues
