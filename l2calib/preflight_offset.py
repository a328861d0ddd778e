"""The LiDAR–IMU time offset, before any calibration (``l2calib inspect``, issue 21 item 3).

:func:`offset_check` opens the bag as a sequence (a second pass: the scans' points are needed),
runs :func:`l2calib.time_offset_estimate.estimate_offset` on its most excited stretch (ct-lidar's
``|ω|`` against the gyro's; no extrinsic needed) and turns the result into an issue for the
report and, when an offset is found, the recipe lines that start the calibration from it.
"""

from __future__ import annotations

from pathlib import Path

from l2calib.data import NS_PER_S
from l2calib.errors import DataError
from l2calib.preflight_checks import Issue
from l2calib.recipe import DataConfig
from l2calib.time_offset_estimate import OffsetEstimate

#: Offsets smaller than this (s) are reported as none found (the estimate's noise is ~0.1 ms;
#: a LiDAR driver's stamp jitter is about a millisecond).
NEGLIGIBLE_S = 0.002
#: Least LiDAR–IMU overlap (s) for an estimate: the stretch plus margins for the shift search.
MIN_OVERLAP_S = 7.0


def offset_check(
    path: str | Path, data: DataConfig, overlap_s: float | None
) -> tuple[OffsetEstimate | None, list[Issue], dict]:
    """Estimates the offset of one bag.

    Args:
        path: The bag.
        data: Recipe ``data`` section (topics, units, time conventions).
        overlap_s: LiDAR-IMU overlap found by ``inspect`` (s).

    Returns:
        ``(estimate, issues, suggested)``: the estimate (``None`` when not attempted), one
        ``info`` or ``warning`` issue saying what was found, and recipe settings
        (``{"train": {...}}``) when an offset worth starting from was found.
    """
    from l2calib.io.sequences import open_sequence
    from l2calib.time_offset_estimate import estimate_offset

    where = f"{path}: time offset"
    if overlap_s is None or overlap_s < MIN_OVERLAP_S:
        why = f"{overlap_s or 0:.1f} s of LiDAR-IMU overlap, the estimate needs {MIN_OVERLAP_S:g} s"
        return None, [Issue("info", where, f"not estimated: {why}", "")], {}
    try:
        seq = open_sequence(path, data, auto_topics=True)  # the bag's only LiDAR / IMU topic
    except DataError as e:
        return None, [Issue("info", where, f"not estimated: {e.message}", e.fix or "")], {}
    est = estimate_offset(seq)
    a = est.stretch[0] - seq.start_ns / NS_PER_S
    span = f"{est.stretch[1] - est.stretch[0]:.1f} s from {a:.1f} s into the recording"
    if not est.observable:
        issue = Issue(
            "warning",
            where,
            f"weakly observable on this recording ({est.reason}; over {span}): no offset claimed",
            "record a few seconds of rotation back and forth (any axis) to measure it, or "
            "calibrate with train.estimate_time_offset=true and read its resolution in "
            "calibration.yaml",
        )
        return est, [issue], {}
    ms = 1000 * est.time_offset_s
    quality = f"|ω| correlation {est.correlation:.3f}, sharpness {est.sharpness:.1f}, over {span}"
    if abs(est.time_offset_s) < NEGLIGIBLE_S:
        msg = f"none found: {ms:+.1f} ms (t_imu = t_lidar + offset; {quality})"
        return est, [Issue("info", where, msg, "")], {}
    issue = Issue(
        "warning",
        where,
        f"the IMU's stamps are {ms:+.1f} ms off the LiDAR's (t_imu = t_lidar + "
        f"{est.time_offset_s:+.4f} s; {quality})",
        "calibrate with train.estimate_time_offset=true and train.init_time_offset_s="
        f"{est.time_offset_s:.4f} (suggested settings below), or fix the driver's stamps",
    )
    start = round(float(est.time_offset_s), 4)
    return est, [issue], {"train": {"estimate_time_offset": True, "init_time_offset_s": start}}
