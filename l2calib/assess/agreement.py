"""An honesty check: does the odometry agree with the reference at the calibrated extrinsic?

The resolution probe measures how sharp the reward is, not whether its peak is in the right
place: a reference that is itself wrong gives a sharp peak at a wrong extrinsic, and a search
stuck in a local optimum looks sharp too. Both show as a large remaining error between the
odometry and the reference at the result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["DISAGREEMENT_LIMITS", "disagreement_warnings", "finite_or_none"]


#: Mean odometry-vs-reference error at the result above which the reference (or the odometry)
#: is named as unreliable. Measured on the simulator at the true extrinsic: 0.3–0.6 cm and
#: 0.01–0.04° with the true LiDAR trajectory (handheld, uav, ugv; OS1-16 and MID-360) or with
#: ct-lidar (handheld MID-360); 103 cm and 4.6° with KISS-ICP on a
#: hand-swung 16-beam LiDAR (whose calibration is then 43 cm off while every axis looks sharp);
#: ~50 cm / 50° at the local optimum a ugv single-sequence run stopped in (137 cm / 180° off).
DISAGREEMENT_LIMITS = {"translation_m": 0.03, "rotation_deg": 0.5}


def disagreement_warnings(agreement: dict[str, float | None], sources: Sequence[str]) -> list[str]:
    """A warning when the odometry and the reference still disagree at the calibrated extrinsic.

    The resolution probe measures how sharp the reward is, not whether its peak is in the right
    place: a reference that is itself wrong gives a sharp peak at a wrong extrinsic, and a search
    stuck in a local optimum looks sharp too. Both show as a large remaining error between the
    odometry and the reference.

    Args:
        agreement: mean errors at the result, ``translation_m`` (m) and ``rotation_deg`` (deg;
            ``None`` when the reference has no orientation).
        sources: the references' source names, for the message.
    """
    if not any(v is not None and v > DISAGREEMENT_LIMITS[k] for k, v in agreement.items()):
        return []
    t, r = agreement["translation_m"], agreement["rotation_deg"]
    size = " / ".join(txt for txt in (_fmt(t, 100, "cm", 1), _fmt(r, 1, "deg", 2)) if txt)
    return [
        f"even at the calibrated extrinsic the odometry and the reference "
        f"({', '.join(sources)}) disagree by {size} on average (a few mm with a good "
        "reference): the reference or the odometry is inaccurate on this data, or the search "
        "stopped far from the best extrinsic, and the result may be off by as much; check the "
        "reference (docs/references.md), use a more accurate one, or calibrate over more "
        "sequences"
    ]


def _fmt(value: float | None, scale: float, unit: str, digits: int) -> str:
    return "" if value is None else f"{scale * value:.{digits}f} {unit}"


def finite_or_none(value: Any, digits: int) -> float | None:
    """``value`` rounded to ``digits``, or ``None`` when it is not finite (NaN: not measured)."""
    v = float(value)
    return round(v, digits) if np.isfinite(v) else None
