"""``calibration.yaml``: the result in every form a robotics user pastes somewhere.

Direction: ``T_imu_lidar`` maps points from the LiDAR frame into the IMU frame
(``p_imu = R p_lidar + t``); it is also the pose of the LiDAR in the IMU frame. FAST-LIO's
``extrinsic_T``/``extrinsic_R`` and a URDF joint from the IMU link (parent) to the LiDAR link
(child) both take exactly this transform. Its inverse is written too, labelled ``T_lidar_imu``.

``status`` (:mod:`l2calib.status`) says whether to use it. A ``not-calibrated`` file holds either
a partial result for diagnosis (the probe after training found most axes flat) or, when
``calibrate`` stopped before training because the data is too short or too still, no extrinsic
at all: no ``T_imu_lidar`` and no other form of it, only ``status_reasons`` and a ``data``
summary. The readers (:mod:`l2calib.outputs.calibration_read`, re-exported here) refuse both
with :class:`~l2calib.errors.NotCalibratedError`.

Time offset (when estimated): ``t_imu = t_lidar + time_offset_s`` — the IMU stamps an instant
``time_offset_s`` later than the LiDAR does. FAST-LIO's ``common/time_offset_lidar_to_imu`` has
the same sign (hku-mars/FAST_LIO ``src/laserMapping.cpp``, ``imu_cbk``: every IMU stamp becomes
``stamp - time_offset_lidar_to_imu``), and LI-Init's "Time Lag IMU to LiDAR (second)" is the same
quantity (hku-mars/LiDAR_IMU_Init ``src/laserMapping.cpp``, ``imu_cbk``: ``stamp -
time_lag_IMU_wtr_lidar``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from l2calib import geometry as geo
from l2calib.errors import NotCalibratedError
from l2calib.outputs.calibration_read import read_extrinsic, read_status  # noqa: F401 (re-export)
from l2calib.status import NOT_CALIBRATED, UNRELIABLE

HEADER = (
    "# l2calib calibration result.\n"
    "# T_imu_lidar maps points from the LiDAR frame into the IMU frame (p_imu = R p_lidar + t),\n"
    "# i.e. it is the pose of the LiDAR in the IMU frame. rpy_deg: roll, pitch, yaw with\n"
    "# R = Rz(yaw) Ry(pitch) Rx(roll) (URDF / ROS convention). Units: m, deg, s.\n"
)
TIME_OFFSET_HEADER = (
    "# time_offset_s: t_imu = t_lidar + time_offset_s (the IMU stamps an instant this much later\n"
    "# than the LiDAR). FAST-LIO takes it with the same sign as common/time_offset_lidar_to_imu\n"
    "# (its imu_cbk subtracts it from every IMU stamp) with common/time_sync_en: false; in the\n"
    "# fast_lio block below extrinsic_T/R go under mapping:, the two time keys under common:.\n"
    "# LI-Init reports the same quantity, same sign, as 'Time Lag IMU to LiDAR (second)'.\n"
)


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
    # l2calib.time_offset_probe.OffsetResolution, and where the offset's estimation started (s)
    time_offset_resolution: Any | None = None
    time_offset_start_s: float | None = None
    final_reward: float | None = None
    evaluations: int = 0
    iterations: int = 0
    wall_time_s: float = 0.0
    stop_reason: str = ""
    undetermined: list[str] = field(default_factory=list)
    resolution: Any | None = None  # l2calib.sensitivity.AxisResolution
    # mean odometry-vs-reference error at the result: {"translation_m": .., "rotation_deg": ..}
    reference_agreement: dict[str, float | None] | None = None
    warnings: list[str] = field(default_factory=list)  # beyond undetermined axes
    extra: dict[str, Any] = field(default_factory=dict)
    # calibrated / unreliable / not-calibrated, and why (l2calib.status)
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
            "iterations": int(self.iterations),
            "wall_time_s": round(float(self.wall_time_s), 1),
            "stop_reason": self.stop_reason,
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
            "start_s": self.time_offset_start_s,
        }
        res = self.time_offset_resolution
        if res is not None:
            block.update(res.to_dict())
            if not np.isfinite(res.resolution_s):  # null resolution_s, and why
                block["undetermined"] = "the reward is flat over +/-30 ms of offset"
        return block


def _finite(resolution: Any | None, name: str, digits: int) -> list[float | None] | None:
    """Per-axis values of ``resolution.<name>`` with ``inf`` written as ``None``."""
    if resolution is None:
        return None
    vals = getattr(resolution, name)
    return [None if not np.isfinite(v) else round(float(v), digits) for v in vals]


NOT_CALIBRATED_HEADER = (
    "# NOT CALIBRATED: the data could not determine this extrinsic (status_reasons says what is\n"
    "# missing). The values below are a partial result for diagnosis only: do not use them.\n"
    "# No FAST-LIO / URDF blocks are written.\n"
)
STOPPED_HEADER = (
    "# NOT CALIBRATED: calibrate stopped before training, the data being too short or too still\n"
    "# (status_reasons says what is missing and how much motion to record; data summarises what\n"
    "# was found). No extrinsic is written: no T_imu_lidar, no FAST-LIO / URDF blocks.\n"
)
UNRELIABLE_COMMENT = (
    "# WARNING: status unreliable (see status_reasons): check this extrinsic before pasting it\n"
)


class _FlowRowsDumper(yaml.SafeDumper):
    """Writes lists of numbers on one line (``[a, b, c]``): matrices read as rows."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) or v is None for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_FlowRowsDumper.add_representer(list, _represent_list)


def write_calibration(path: str | Path, result: CalibrationResult) -> Path:
    """Writes ``calibration.yaml`` (never over a file the user made: see ``l2calib.outputs``)."""
    path = Path(path)
    body = yaml.dump(result.to_dict(), Dumper=_FlowRowsDumper, sort_keys=False, width=120)
    header = HEADER
    if result.stopped_before_training:  # the conventions of T_imu_lidar do not apply
        header = HEADER.splitlines(keepends=True)[0] + STOPPED_HEADER
    elif result.status == NOT_CALIBRATED:
        header += NOT_CALIBRATED_HEADER
    if result.time_offset_s is not None and not result.stopped_before_training:
        header += TIME_OFFSET_HEADER
    if result.status == UNRELIABLE:
        lines = body.splitlines(keepends=True)
        body = "".join(
            UNRELIABLE_COMMENT + line
            if line.startswith(("fast_lio:", "urdf:", "li_init:"))
            else line
            for line in lines
        )
    path.write_text(header + body)
    return path
