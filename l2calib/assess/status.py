"""Whether a finished run calibrated anything: ``calibrated``, ``unreliable`` or ``not-calibrated``.

``calibration.yaml`` → ``status`` is what scripts and batch summaries read:

* ``not-calibrated`` — the data could not determine the extrinsic: the resolution probe finds
  the reward flat along at least :data:`MIN_FLAT_AXES` of the six axes, or the selected data is
  shorter than half a selection window (``selection.window_s``), or every IMU axis is far below
  the selection's excitation thresholds (:data:`STILL_SHARE` of them: a rig all but at rest).
  ``l2calib calibrate`` then exits with :data:`EXIT_NOT_CALIBRATED` and omits the paste-ready
  FAST-LIO / URDF blocks. The data rules are checked before training
  (:func:`before_training`): data that breaks them is not trained on, and ``calibration.yaml``
  holds no extrinsic at all (only the status, the reasons and a summary of the data). A flat
  probe after training leaves the partial result, marked as such.
* ``unreliable`` — an extrinsic came out, but a warning makes it untrustworthy (the odometry and
  the reference still disagree after the restarts: :mod:`l2calib.assess.agreement`). The exit status
  stays 0; the paste-ready blocks carry a warning comment.
* ``calibrated`` — otherwise (axes the data resolves only weakly are still listed in
  ``uncertainty.undetermined``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

CALIBRATED, UNRELIABLE, NOT_CALIBRATED = "calibrated", "unreliable", "not-calibrated"
#: Exit status of ``l2calib calibrate`` when the data could not calibrate.
EXIT_NOT_CALIBRATED = 3
#: Flat axes (of 6) from which the result is not presented as a calibration.
MIN_FLAT_AXES = 4
#: Selected data below this share of ``selection.window_s`` is far too little.
MIN_WINDOW_SHARE = 0.5
#: Data is *clearly* too still only when every axis is below this share of the selection's
#: excitation thresholds (``selection.min_gyro_rad_s`` / ``min_accel_m_s2``). Below the full
#: thresholds an axis is only weakly excited, and weak excitation is what l2calib is for: the
#: simulated UAV flights (RMS 0.04/0.02/0.15 rad/s, 0.12/0.26/0.03 m/s^2, every axis under the
#: thresholds) calibrate to 1.6-2.8 cm / 0.16-0.24 deg (``benchmarks/results/calibration.json``,
#: ``uav all``), while a rig at rest shows about 0.01 rad/s and 0.02 m/s^2.
STILL_SHARE = 0.25


@dataclass
class Status:
    """The verdict on one run.

    Attributes:
        status: ``calibrated``, ``unreliable`` or ``not-calibrated``.
        reasons: Why (empty when calibrated), each naming what is missing and what to record.
    """

    status: str = CALIBRATED
    reasons: list[str] = field(default_factory=list)


def flat_axes(resolution: Any | None) -> list[str]:
    """Names of the axes along which no probe step lowered the reward (``inf`` resolution)."""
    if resolution is None:
        return []
    rows = [
        ("rotation about", resolution.rotation_deg),
        ("translation along", resolution.translation_m),
    ]
    return [
        f"{kind} {a}"
        for kind, vals in rows
        for a, v in zip("xyz", vals, strict=True)
        if np.isinf(v)
    ]


def data_shortfalls(
    total_s: float, excitation: tuple[Any, Any] | None, selection_cfg: Any
) -> list[tuple[str, str]]:
    """Why data is clearly too short or too still to calibrate, before or after training.

    The same rules serve ``calibrate``'s status and ``inspect``'s warnings.

    Args:
        total_s: Usable (selected) data (s).
        excitation: ``(gyro_rms_rad_s, accel_rms_m_s2)`` per IMU axis over that data, or
            ``None`` (not known: the selection was disabled).
        selection_cfg: The recipe's ``selection`` section (window length and thresholds).

    Returns:
        ``(what is missing, what to record)`` pairs; empty when the data may calibrate.
    """
    out: list[tuple[str, str]] = []
    window = float(selection_cfg.window_s)
    if total_s < MIN_WINDOW_SHARE * window:
        out.append(
            (
                f"only {total_s:.1f} s of usable data, far below one selection window "
                f"(selection.window_s = {window:g} s)",
                f"record at least {window:g} s of motion "
                f"(better {float(selection_cfg.budget_s):g} s, selection.budget_s)",
            )
        )
    if excitation is not None:
        gyro = np.asarray(excitation[0], dtype=float)
        accel = np.asarray(excitation[1], dtype=float)
        min_gyro = STILL_SHARE * selection_cfg.min_gyro_rad_s
        min_accel = STILL_SHARE * selection_cfg.min_accel_m_s2
        if (gyro < min_gyro).all() and (accel < min_accel).all():
            out.append(
                (
                    "the selected data is too still: RMS angular rate "
                    f"{_triple(gyro)} rad/s (below {min_gyro:g} on every axis) and "
                    f"gravity-free acceleration {_triple(accel)} m/s^2 (below {min_accel:g}); "
                    f"the selection asks for {selection_cfg.min_gyro_rad_s:g} rad/s and "
                    f"{selection_cfg.min_accel_m_s2:g} m/s^2 per axis",
                    "swing the rig about and along all three axes",
                )
            )
    return out


def before_training(data: Any, selection_cfg: Any) -> Status:
    """The verdict of the selected data alone, before any training.

    ``calibrate`` stops here, without training, when the data is clearly too short or too still
    (:func:`data_shortfalls`, the rules ``inspect`` warns with).

    Args:
        data: The selected data (a ``PreparedData``; its references are not needed).
        selection_cfg: The recipe's ``selection`` section (window length and thresholds).

    Returns:
        ``not-calibrated`` with what is missing and what to record, or ``calibrated`` (the data
        may calibrate: training decides).
    """
    missing = _data_reasons(data, selection_cfg)
    return Status(NOT_CALIBRATED, missing) if missing else Status()


def assess(result: Any, data: Any, selection_cfg: Any) -> Status:
    """The status of ``result`` computed on ``data`` (a ``PreparedData``).

    Args:
        result: The :class:`~l2calib.assess.result.CalibrationResult`.
        data: The prepared data (its segments and, when enabled, its selection).
        selection_cfg: The recipe's ``selection`` section (window length and thresholds).
    """
    missing = _data_reasons(data, selection_cfg)
    flat = flat_axes(result.resolution)
    if len(flat) >= MIN_FLAT_AXES:
        missing.append(
            f"the reward is flat along {len(flat)} of 6 axes ({', '.join(flat)}): the data does "
            "not constrain them; record motion that rotates about and accelerates along them"
        )
    if missing:
        return Status(NOT_CALIBRATED, missing)
    if result.warnings:
        return Status(UNRELIABLE, list(result.warnings))
    return Status()


def _data_reasons(data: Any, selection_cfg: Any) -> list[str]:
    """``data_shortfalls`` of the selected data, as ``"what: fix"`` lines."""
    total = float(sum(s.duration_s for s in data.segments))
    sel = data.selection
    excitation = None if sel is None else (sel.gyro_rms_rad_s, sel.accel_rms_m_s2)
    return [f"{what}: {fix}" for what, fix in data_shortfalls(total, excitation, selection_cfg)]


def _triple(v: np.ndarray) -> str:
    return "/".join(f"{x:.2f}" for x in v)
