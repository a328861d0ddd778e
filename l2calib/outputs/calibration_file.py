"""``calibration.yaml``: the result in every form a robotics user pastes somewhere.

Direction: ``T_imu_lidar`` maps points from the LiDAR frame into the IMU frame
(``p_imu = R p_lidar + t``); it is also the pose of the LiDAR in the IMU frame. FAST-LIO's
``extrinsic_T``/``extrinsic_R`` and a URDF joint from the IMU link (parent) to the LiDAR link
(child) both take exactly this transform. Its inverse is written too, labelled ``T_lidar_imu``.

``status`` (:mod:`l2calib.assess.status`) says whether to use it. A ``not-calibrated`` file holds
either a partial result for diagnosis (the probe after training found most axes flat) or, when
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

from pathlib import Path

import yaml

from l2calib.assess.result import CalibrationResult
from l2calib.assess.status import NOT_CALIBRATED, UNRELIABLE
from l2calib.outputs.calibration_read import read_extrinsic, read_status  # noqa: F401 (re-export)

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
