"""Reading ``calibration.yaml`` (or an ``extrinsic_gt.yaml``) back: the extrinsic and the status.

Every reader of a calibration file goes through here, so a ``not-calibrated`` file (no extrinsic,
or a partial result for diagnosis only: :mod:`l2calib.outputs.calibration_file`) is refused with
one clear :class:`~l2calib.errors.NotCalibratedError` naming the file and its status.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from l2calib import geometry as geo
from l2calib.assess.status import NOT_CALIBRATED
from l2calib.errors import DataError, NotCalibratedError
from l2calib.interfaces import Extrinsic


def read_extrinsic(path: str | Path) -> Extrinsic:
    """``T_imu_lidar`` (and time offset) from a calibration.yaml or an ``extrinsic_gt.yaml``.

    Accepts a 4×4 ``T_imu_lidar``, or ``translation_m`` with ``quaternion_xyzw`` or ``rpy_deg``.

    Returns:
        The :class:`~l2calib.interfaces.Extrinsic` (``time_offset_s`` ``None`` when the file
        has none).

    Raises:
        NotCalibratedError: if the file's ``status`` is ``not-calibrated`` (it holds no
            extrinsic, or only a partial result for diagnosis).
        DataError: if the file is missing, not YAML, or holds no valid extrinsic.
    """
    path = Path(path)
    data = _load(path)
    refuse_not_calibrated(path, data)
    offset = data.get("time_offset_s")
    if "T_imu_lidar" in data:
        T = np.asarray(data["T_imu_lidar"], dtype=np.float64)
        if T.shape != (4, 4):
            raise DataError(f"{path}: T_imu_lidar has shape {T.shape}, expected 4x4")
    elif "translation_m" in data and ("quaternion_xyzw" in data or "rpy_deg" in data):
        t = torch.tensor(data["translation_m"], dtype=torch.float64)
        if "quaternion_xyzw" in data:
            R = geo.quat_to_matrix(torch.tensor(data["quaternion_xyzw"], dtype=torch.float64))
        else:
            rpy = torch.deg2rad(torch.tensor(data["rpy_deg"], dtype=torch.float64))
            R = geo.euler_rpy_to_matrix(rpy)
        T = geo.make_transform(R, t).numpy()
    else:
        raise DataError(
            f"{path}: no extrinsic found",
            fix="give T_imu_lidar (4x4), or translation_m with quaternion_xyzw or rpy_deg",
        )
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise DataError(f"{path}: the rotation of T_imu_lidar is not a proper rotation")
    offset_s = float(offset) if offset is not None else None
    return Extrinsic(torch.from_numpy(np.ascontiguousarray(T)), offset_s)


def read_status(path: str | Path) -> str | None:
    """The ``status`` of a calibration.yaml (``None`` when it has none, e.g. a ground truth).

    Raises:
        DataError: if the file is missing or not a YAML mapping.
    """
    return _load(Path(path)).get("status")


def refuse_not_calibrated(path: Path, data: dict[str, Any]) -> None:
    """Raises :class:`~l2calib.errors.NotCalibratedError` for a ``not-calibrated`` file's content.

    The message names the file, its status, whether it holds a partial result or nothing, and
    the first of its ``status_reasons``.
    """
    if data.get("status") != NOT_CALIBRATED:
        return
    reasons = data.get("status_reasons") or []
    why = f"; status_reasons[0]: {reasons[0]}" if reasons else ""
    what = (
        "its values are a partial result for diagnosis only, not an extrinsic to use"
        if "T_imu_lidar" in data
        else "calibrate stopped before training and wrote no extrinsic"
    )
    raise NotCalibratedError(
        f"{path}: status {NOT_CALIBRATED}: {what}{why}",
        fix="record the motion its status_reasons ask for and run l2calib calibrate again",
    )


def _load(path: Path) -> dict[str, Any]:
    """The YAML mapping in ``path``."""
    if not path.is_file():
        raise DataError(f"{path}: no such file", fix="give the calibration.yaml to evaluate")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise DataError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise DataError(
            f"{path}: not a calibration file (a YAML {type(data).__name__}, not a mapping)",
            fix="give the calibration.yaml written by l2calib calibrate",
        )
    return data
