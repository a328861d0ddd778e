"""Whose clock a reference-vs-gyro shift belongs to, and what to do about it (issue 21).

The gyro is on the IMU clock; a reference file is read onto the LiDAR clock
(``t_lidar = t_file + reference.options.time_offset_s``). When the file's rotation rate matches
the gyro only shifted by ``s`` (``ω_ref(t + s) = ω_gyro(t)``,
:func:`l2calib.references.imu_check.compare_rotation_rate`), two clock errors add up:
the file's against the LiDAR (``ε``: the file reads ``ε`` s early) and the IMU's against the
LiDAR (``δ``, ``t_imu = t_lidar + δ``, the convention of ``calibration.yaml``): ``s = -(ε + δ)``.
The gyro alone cannot split the sum, so the reading follows what the file declares:

* ``body_frame`` ``lidar`` or ``other``: the file is taken to be on the LiDAR clock (that is what
  ``time_offset_s`` asserts), so the shift is a LiDAR–IMU offset ``δ = -s``, a property of the
  rig. ``reference.options.time_offset_s`` would move the file, not the IMU: the fixes are
  ``train.estimate_time_offset=true`` (which then starts from ``δ``) or re-stamping the IMU.
  A shift beyond what the estimation can represent (``policy.options.time_offset_bound_s``)
  is more likely a file on another clock; both readings are then given.
* ``body_frame`` ``imu`` (e.g. an INS solution): the file is taken to be on the IMU clock, so a
  shift is the file's own clock: set ``reference.options.time_offset_s``.
"""

from __future__ import annotations

import logging
import math

from l2calib.errors import ReferenceSourceError
from l2calib.references.imu_check import RateCheck

log = logging.getLogger("l2calib.references")

#: Shifts below this (s) are not reported: the 10 ms grid and 50 ms smoothing blur them.
MIN_SHIFT_S = 0.03
#: A shift counts when it gains this much correlation, or when it divides the misfit
#: ``1 - correlation`` by ``MIN_MISFIT_RATIO`` (smooth motion: 50 ms took a hand-held sway's
#: correlation from 0.958 to 0.992, a gain of only 0.034).
MIN_GAIN = 0.05
MIN_MISFIT_RATIO = 3.0


def is_shifted(res: RateCheck) -> bool:
    """Whether the check found a clear clock shift between the reference and the gyro."""
    if abs(res.best_shift_s) <= MIN_SHIFT_S:
        return False
    misfit0, misfit = 1.0 - res.correlation, 1.0 - res.best_correlation
    return res.best_correlation - res.correlation > MIN_GAIN or misfit0 > MIN_MISFIT_RATIO * misfit


def attribute_shift(
    res: RateCheck,
    where: str,
    body_frame: str,
    file_offset_s: float,
    estimate_time_offset: bool,
    time_offset_bound_s: float | None,
) -> float:
    """Reads a shift found by the clock check (see module docstring); raises unless usable.

    Args:
        res: The check's outcome, with :func:`is_shifted` true.
        where: The file and segment, for messages.
        body_frame: The file's ``reference.options.body_frame`` (``lidar``, ``imu``, ``other``).
        file_offset_s: The file's ``reference.options.time_offset_s`` (s).
        estimate_time_offset: ``train.estimate_time_offset``: the offset is part of the action.
        time_offset_bound_s: ``policy.options.time_offset_bound_s`` (s); ``None``: unbounded.

    Returns:
        The LiDAR–IMU offset ``δ`` (s, ``t_imu = t_lidar + δ``) to start the estimation from,
        when ``estimate_time_offset`` is on and the shift is read as such an offset.

    Raises:
        ReferenceSourceError: the shift is the file's clock, a LiDAR–IMU offset that is not
            estimated, or too large to be estimated; the message says which and the fix.
    """
    s, delta = res.best_shift_s, -res.best_shift_s
    seen = (
        f"{where}: the file's rotation rate matches the IMU gyro only when shifted by {s:+.3f} s "
        f"(correlation {res.correlation:.2f} -> {res.best_correlation:.2f})"
    )
    file_fix = f"reference.options.time_offset_s to {file_offset_s - s:.3f}"
    if body_frame == "imu":
        raise ReferenceSourceError(
            f"{seen}: the file describes the IMU (body_frame imu), so its stamps should follow "
            "the gyro's: the file is on another clock",
            fix=f"set {file_fix} (t_lidar = t_file + time_offset_s; this puts the file on the "
            "IMU clock)",
        )
    bound = math.inf if time_offset_bound_s is None else time_offset_bound_s
    if abs(delta) >= bound:
        raise ReferenceSourceError(
            f"{seen}: {abs(s):.3f} s is beyond the LiDAR–IMU offset the calibration can estimate "
            f"(policy.options.time_offset_bound_s = {bound:g} s), so the file is most likely on "
            "another clock than the LiDAR",
            fix=f"if the file is on another clock, set {file_fix}; if instead the IMU stamps run "
            f"{delta:+.3f} s against the LiDAR's, correct them in the bag (driver, PTP)",
        )
    offset = f"t_imu = t_lidar {'+' if delta >= 0 else '-'} {abs(delta):.3f} s"
    if estimate_time_offset:
        log.warning(
            "%s: the file is on the LiDAR clock (body_frame %s), so this is the LiDAR–IMU time "
            "offset (%s); the calibration estimates it starting from there",
            seen,
            body_frame,
            offset,
        )
        return delta
    raise ReferenceSourceError(
        f"{seen}: the file is on the LiDAR clock (body_frame {body_frame}), so the IMU is "
        f"shifted against the LiDAR ({offset}), not the file",
        fix=f"set train.estimate_time_offset=true (it starts from {delta:+.3f} s), or correct "
        f"the IMU stamps in the bag by {-delta:+.3f} s (driver, PTP); "
        "reference.options.time_offset_s moves the file, not the IMU",
    )
