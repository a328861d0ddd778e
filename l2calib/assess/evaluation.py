"""Scoring given extrinsics: the odometry's APE against the reference, one continuous run per bag.

What ``l2calib evaluate`` prints (through :meth:`l2calib.calibration.Calibration.evaluate`): each
extrinsic (e.g. the calibrated one and the one used before) runs the backend's evaluation mode —
for the LIO backends a continuous odometry with its own map and no re-anchoring (the spec's
``evaluation`` options, :class:`~l2calib.plugins.PluginSpec`) — on every whole sequence, and the
estimated LiDAR trajectory is compared with the recipe's reference (SE(3)-aligned APE).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from l2calib.interfaces import CandidateStatus, Extrinsic

__all__ = ["EvaluationRow", "evaluate_extrinsics"]


@dataclass(frozen=True)
class EvaluationRow:
    """One extrinsic on one sequence.

    Attributes:
        label: The extrinsic's name (e.g. its file name).
        segment: The sequence's segment name.
        ape: The :class:`~l2calib.alignment.ApeResult` (``None`` when fewer than 3 poses were
            valid: the odometry diverged or lost track at once).
        status: How the odometry ended (:class:`~l2calib.interfaces.CandidateStatus`).
    """

    label: str
    segment: str
    ape: Any | None
    status: CandidateStatus


def evaluate_extrinsics(
    recipe, sequences: Sequence[Any], extrinsics: dict[str, Extrinsic]
) -> list[EvaluationRow]:
    """Runs the backend's evaluation mode with each extrinsic on every whole sequence.

    Args:
        recipe: Recipe (reference, backend and its options, IMU noise).
        sequences: :class:`~l2calib.data.Sequence` objects, each used whole.
        extrinsics: ``label -> Extrinsic`` (a ``None`` time offset runs at 0 s).

    Returns:
        One :class:`EvaluationRow` per kept sequence and extrinsic (sequence-major).
    """
    from l2calib.alignment import ape
    from l2calib.pipeline import compute_references, kept_segments
    from l2calib.plugins import get_plugin
    from l2calib.trajectory import Trajectory

    segments = [seq.segment() for seq in sequences]
    references = compute_references(recipe, segments, sequences)
    segments = kept_segments(segments, references)
    spec = get_plugin("l2calib.backends", recipe.backend.name)
    backend = spec.build({**recipe.backend.options, **spec.evaluation}, imu=recipe.data.imu)
    try:
        backend.prepare(segments, references)
        labels = list(extrinsics)
        T = torch.stack([extrinsics[k].T_imu_lidar.to(torch.float64) for k in labels])
        offsets = torch.tensor(
            [extrinsics[k].time_offset_s or 0.0 for k in labels], dtype=torch.float64
        )
        outputs = backend.evaluate(T, offsets)
    finally:
        backend.close()
    rows = []
    for out, ref in zip(outputs, references, strict=True):
        for k, label in enumerate(labels):
            status = CandidateStatus(int(out.status[k]))
            valid = out.valid[k]
            if int(valid.sum()) < 3:
                rows.append(EvaluationRow(label, out.segment, None, status))
                continue
            est = Trajectory.from_matrices(
                out.stamps_ns[valid.numpy()], out.T_world_lidar[k][valid], "lidar"
            )
            rows.append(EvaluationRow(label, out.segment, ape(ref.trajectory, est), status))
    return rows
