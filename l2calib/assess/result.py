"""The result of a calibration run: the extrinsic, its spreads, probes and provenance.

Every stage fills it in (:mod:`l2calib.training`, then :func:`l2calib.assess.status.assess`);
:mod:`l2calib.outputs.calibration_file` writes it as ``calibration.yaml`` (:meth:`
CalibrationResult.to_dict` is that file's layout). Direction and time-offset conventions: see
that module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.assess.status import NOT_CALIBRATED, UNRELIABLE
from l2calib.errors import NotCalibratedError
from l2calib.interfaces import Extrinsic


@dataclass
class CalibrationResult:
    """The calibrated extrinsic with its uncertainty and provenance.

    ``T_imu_lidar`` is ``None`` when ``calibrate`` stopped before training (status
    ``not-calibrated``): then there is no extrinsic in any form.
    """

    T_imu_lidar: np.ndarray | None
    time_offset_s: float | None = None
    rotation_sigma_deg: list[float] | None = None
    translation_sigma_m: list[float] | None = None
    time_offset_sigma_s: float | None = None
    # l2calib.assess.time_offset_probe.OffsetResolution; where the offset's estimation began (s)
    time_offset_resolution: Any | None = None
    time_offset_start_s: float | None = None
    # how the offset was found: held at the rate correlation, known, or estimated jointly
    time_offset_method: str | None = None
    final_reward: float | None = None
    evaluations: int = 0
    # Σ over every odometry evaluation of the scans it estimated (the work; coarse-to-fine
    # iterations use a part of the data)
    candidate_scans: int = 0
    iterations: int = 0
    wall_time_s: float = 0.0
    # wall time (s) of each stage: reading, selection, reference, odometry_preparation,
    # training, refinement, probe, report_trajectories, report
    stage_s: dict[str, float] = field(default_factory=dict)
    stop_reason: str = ""
    undetermined: list[str] = field(default_factory=list)
    resolution: Any | None = None  # l2calib.assess.sensitivity.AxisResolution
    axis_uncertainty: Any | None = None  # l2calib.assess.uncertainty.AxisUncertainty
    # mean odometry-vs-reference error at the result: {"translation_m": .., "rotation_deg": ..}
    reference_agreement: dict[str, float | None] | None = None
    warnings: list[str] = field(default_factory=list)  # beyond undetermined axes
    extra: dict[str, Any] = field(default_factory=dict)
    # calibrated / unreliable / not-calibrated, and why (l2calib.assess.status)
    status: str = "calibrated"
    status_reasons: list[str] = field(default_factory=list)

    @property
    def stopped_before_training(self) -> bool:
        """True when no training ran, so there is no extrinsic (the data was too poor)."""
        return self.T_imu_lidar is None

    @property
    def matrix(self) -> np.ndarray:
        """``T_imu_lidar`` as a float64 array.

        Raises:
            NotCalibratedError: if there is none (``calibrate`` stopped before training).
        """
        if self.T_imu_lidar is None:
            raise NotCalibratedError(
                f"status {self.status}: calibrate stopped before training, so there is no "
                "extrinsic (status_reasons says what the data lacks)",
                fix="record the motion status_reasons asks for and calibrate again",
            )
        return np.asarray(self.T_imu_lidar, dtype=np.float64)

    @property
    def extrinsic(self) -> Extrinsic:
        """The result as an :class:`~l2calib.interfaces.Extrinsic` (torch, with the offset).

        Raises:
            NotCalibratedError: if there is none (see :attr:`matrix`).
        """
        return Extrinsic(torch.from_numpy(self.matrix.copy()), self.time_offset_s)

    @property
    def rpy_deg(self) -> np.ndarray:
        """Roll, pitch, yaw (deg) of ``R_imu_lidar``."""
        R = torch.from_numpy(self.matrix[:3, :3])
        return torch.rad2deg(geo.matrix_to_euler_rpy(R)).numpy()

    @property
    def quat_xyzw(self) -> np.ndarray:
        """Unit quaternion (xyzw, w >= 0) of ``R_imu_lidar``."""
        return geo.matrix_to_quat(torch.from_numpy(self.matrix[:3, :3])).numpy()

    def to_dict(self) -> dict[str, Any]:
        """The YAML content (plain Python types)."""
        head: dict[str, Any] = {
            "status": self.status,
            **({"status_reasons": list(self.status_reasons)} if self.status_reasons else {}),
        }
        training = {
            "final_reward": None if self.final_reward is None else round(self.final_reward, 6),
            "evaluations": int(self.evaluations),
            "candidate_scans": int(self.candidate_scans),
            "iterations": int(self.iterations),
            "wall_time_s": round(float(self.wall_time_s), 1),
            "stop_reason": self.stop_reason,
            "stage_s": {k: round(float(v), 1) for k, v in self.stage_s.items()},
        }
        if self.stopped_before_training:  # no extrinsic in any form, nothing to paste
            return {**head, "training": training, **self.extra}
        T = self.matrix
        t = T[:3, 3]
        rpy = self.rpy_deg
        inv = geo.transform_inverse(torch.from_numpy(T)).numpy()

        def r(x, n=6):
            return [round(float(v), n) for v in np.asarray(x).reshape(-1)]

        out: dict[str, Any] = {
            **head,
            "T_imu_lidar": [r(row, 9) for row in T],
            "translation_m": r(t),
            "quaternion_xyzw": r(self.quat_xyzw, 9),
            "rpy_deg": r(rpy, 4),
            "T_lidar_imu": [r(row, 9) for row in inv],
            "time_offset_s": None if self.time_offset_s is None else round(self.time_offset_s, 6),
            "uncertainty": {
                **_bounds(self.axis_uncertainty),
                # what the data resolves: the smallest perturbation about/along each LiDAR axis
                # that lowers the reward by 0.5 % (null: flat, i.e. not determined)
                "resolution_rotation_deg": _finite(self.resolution, "rotation_deg", 4),
                "resolution_translation_m": _finite(self.resolution, "translation_m", 5),
                # the policy's remaining spread (how far the search narrowed, not the data)
                "rotation_sigma_deg": r(self.rotation_sigma_deg or [], 4) or None,
                "translation_sigma_m": r(self.translation_sigma_m or [], 5) or None,
                "time_offset_sigma_s": self.time_offset_sigma_s,
                "undetermined": list(self.undetermined),
                # mean error of the odometry (with this extrinsic) against the reference, after
                # alignment: a few mm with a good reference; much more means the reference or
                # the odometry is wrong on this data, or the search stopped far from the optimum
                "reference_agreement": self.reference_agreement,
                "warnings": list(self.warnings),
            },
            "training": training,
        }
        if self.time_offset_s is not None:
            out["time_offset"] = self._time_offset_block()
        if self.status != NOT_CALIBRATED:  # nothing to paste when the data calibrated nothing
            note = "; UNRELIABLE: read status_reasons first" if self.status == UNRELIABLE else ""
            out["fast_lio"] = {  # FAST-LIO: extrinsic_T = LiDAR position in IMU frame, R rows
                "extrinsic_T": r(t),
                "extrinsic_R": r(T[:3, :3], 9),
            }
            if self.time_offset_s is not None:  # common/ in FAST-LIO's config (same sign)
                out["fast_lio"]["time_sync_en"] = False
                out["fast_lio"]["time_offset_lidar_to_imu"] = round(self.time_offset_s, 6)
                out["li_init"] = {"time_lag_imu_to_lidar_s": round(self.time_offset_s, 6)}
            out["urdf"] = (
                f'<origin xyz="{t[0]:.6f} {t[1]:.6f} {t[2]:.6f}" '
                f'rpy="{np.radians(rpy[0]):.6f} {np.radians(rpy[1]):.6f} '
                f'{np.radians(rpy[2]):.6f}"/>  <!-- parent: imu, child: lidar{note} -->'
            )
        out.update(self.extra)
        return out

    def _time_offset_block(self) -> dict[str, Any]:
        """``time_offset``: convention, resolution from the reward probe, starting value."""
        block: dict[str, Any] = {
            "convention": "t_imu = t_lidar + time_offset_s (s)",
            **({"method": self.time_offset_method} if self.time_offset_method else {}),
            "start_s": None
            if self.time_offset_start_s is None
            else float(self.time_offset_start_s),
        }
        res = self.time_offset_resolution
        if res is not None:
            block.update(res.to_dict())
            if not np.isfinite(res.resolution_s):  # null resolution_s, and why
                block["undetermined"] = "the reward is flat over +/-30 ms of offset"
        return block


def _bounds(unc: Any | None) -> dict[str, Any]:
    """``calibration.yaml`` → ``uncertainty``: the per-axis 95 % bounds and what they mean."""
    if unc is None:
        return {}

    def vals(values, factor: float, digits: int) -> list[float | None]:
        return [round(float(factor * v), digits) if np.isfinite(v) else None for v in values]

    out = {
        "bound95_rotation_deg": vals(unc.bound95[:3], 180 / np.pi, 4),
        "bound95_translation_m": vals(unc.bound95[3:6], 1.0, 5),
    }
    if len(unc.bound95) > 6:
        out["bound95_time_offset_s"] = vals(unc.bound95[6:], 1.0, 6)[0]
    out["bound95_meaning"] = (
        "per LiDAR axis, the error of this calibration lies within +/- the bound with about 95 % "
        "confidence: the data's noise (block sandwich, Student-t), the distance to the reward's "
        "own optimum, a model-misfit term (residuals counted once per bound95_"
        "correlation_scans) and, where the reference brings a second estimate of itself "
        "(ct-lidar's backward pass), the reference's own error (bound95_reference_*), from "
        "73-99 odometry runs around the result; null: the reward is flat along the axis (or "
        "the axis was held). docs/design.md"
    )
    out["bound95_correlation_scans"] = round(float(unc.tau), 2)
    ref = getattr(unc, "reference95", None)
    if ref is not None and np.any(ref > 0):
        out["bound95_reference_rotation_deg"] = vals(ref[:3], 180 / np.pi, 4)
        out["bound95_reference_translation_m"] = vals(ref[3:6], 1.0, 5)
    if getattr(unc, "caveats", None):
        out["bound95_caveats"] = list(unc.caveats)
    from l2calib.assess.uncertainty import AXIS_NAMES

    if unc.held:
        out["bound95_held"] = [AXIS_NAMES[i] for i in unc.held]
    return out


def _finite(resolution: Any | None, name: str, digits: int) -> list[float | None] | None:
    """Per-axis values of ``resolution.<name>`` with ``inf`` written as ``None``."""
    if resolution is None:
        return None
    vals = getattr(resolution, name)
    return [None if not np.isfinite(v) else round(float(v), digits) for v in vals]
