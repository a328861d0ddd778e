"""``calibration.yaml`` → ``data``: what the calibration had to work with.

The numbers the status rules (:mod:`l2calib.assess.status`) judge: the LiDAR-IMU overlap of each
recording, the seconds selected against ``selection.window_s``, and the RMS excitation of the
selected data against the selection's thresholds. Written with every result, and the main
content of a file whose calibration stopped before training.
"""

from __future__ import annotations

from typing import Any

from l2calib.data import NS_PER_S


def data_summary(data: Any, selection_cfg: Any) -> dict[str, Any]:
    """A plain-types summary of the selected data.

    Args:
        data: The prepared (or only selected) data: its sequences, segments and selection.
        selection_cfg: The recipe's ``selection`` section.

    Returns:
        ``recordings`` (overlap per recording, s), ``selected_s``, ``segments``, the selection
        settings, and, when the selection ran, the RMS excitation per IMU axis beside its
        thresholds and the selection's notes.
    """
    out: dict[str, Any] = {
        "recordings_s": {
            seq.name: round((seq.end_ns - seq.start_ns) / NS_PER_S, 2) for seq in data.sequences
        },
        "selected_s": round(float(sum(s.duration_s for s in data.segments)), 2),
        "segments": len(data.segments),
        "selection": {
            "enabled": bool(selection_cfg.enabled),
            "window_s": float(selection_cfg.window_s),
            "budget_s": float(selection_cfg.budget_s),
        },
    }
    sel = data.selection
    if sel is not None:
        out["excitation"] = {
            "gyro_rms_rad_s": [round(float(v), 4) for v in sel.gyro_rms_rad_s],
            "min_gyro_rad_s": float(selection_cfg.min_gyro_rad_s),
            "accel_rms_m_s2": [round(float(v), 4) for v in sel.accel_rms_m_s2],
            "min_accel_m_s2": float(selection_cfg.min_accel_m_s2),
        }
        out["notes"] = list(sel.notes)
    return out
