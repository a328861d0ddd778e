"""Ground-truth IMU–LiDAR extrinsics of real rigs, and the sensors that go with them.

``T_imu_lidar`` maps LiDAR points into the IMU frame (``p_imu = R p_lidar + t``). Rotations are
given as roll-pitch-yaw in degrees, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

Sources (the project's reference notes): NTU VIRAL (Ouster OS1-16 → VN100), MCD (Ouster → VN200,
rotation rounded to ``diag(1, -1, -1)``) and the L2Calib paper's handheld rig (Livox MID-360 →
MTi-300).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.errors import ConfigError


@dataclass(frozen=True)
class RigPreset:
    """A rig: extrinsic and the LiDAR/IMU models it carries.

    Attributes:
        name: Preset name.
        translation_m: ``t_imu_lidar`` (LiDAR origin in the IMU frame, m).
        rpy_deg: Roll, pitch, yaw of ``R_imu_lidar`` (degrees, ZYX convention).
        lidar: Default LiDAR model name.
        imu: Default IMU model name.
        description: Where the numbers come from.
    """

    name: str
    translation_m: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    lidar: str
    imu: str
    description: str


RIGS: dict[str, RigPreset] = {
    "ntu-viral": RigPreset(
        "ntu-viral",
        (-0.050, 0.0, 0.055),
        (0.0, 0.0, 0.0),
        "ouster-os1-16",
        "vn100",
        "NTU VIRAL UAV: horizontal Ouster OS1-16 to VectorNav VN100",
    ),
    "mcd": RigPreset(
        "mcd",
        (-0.049, -0.031, -0.018),
        (180.0, 0.0, 0.0),
        "ouster-os1-64",
        "vn200",
        "MCD: Ouster to VectorNav VN200, R ~ diag(1, -1, -1)",
    ),
    "paper-handheld": RigPreset(
        "paper-handheld",
        (0.650, -0.372, -0.016),
        (180.0, 90.0, 0.0),
        "livox-mid360",
        "mti-300",
        "L2Calib handheld rig: Livox MID-360 to Xsens MTi-300, sensors deliberately far apart",
    ),
}
RIG_NAMES = tuple(RIGS)


def get_rig(name: str) -> RigPreset:
    """The named preset; :class:`ConfigError` listing the known names otherwise."""
    if name not in RIGS:
        raise ConfigError(
            f"unknown rig preset {name!r}", fix=f"choose one of: {', '.join(RIG_NAMES)}"
        )
    return RIGS[name]


def extrinsic_matrix(translation_m: tuple[float, ...], rpy_deg: tuple[float, ...]) -> np.ndarray:
    """``[4, 4]`` float64 ``T_imu_lidar`` from a translation and roll-pitch-yaw in degrees."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", np.radians(rpy_deg)[::-1]).as_matrix()
    T[:3, 3] = translation_m
    return T


def describe_extrinsic(T_imu_lidar: np.ndarray) -> dict[str, list[float]]:
    """Translation, quaternion xyzw (w >= 0) and rpy (degrees) of a ``[4, 4]`` transform.

    At gimbal lock (pitch ±90°) roll is reported as 0 and yaw absorbs it (l2calib.geometry).
    """
    import torch

    from l2calib import geometry as geo

    R = torch.as_tensor(np.asarray(T_imu_lidar)[:3, :3], dtype=torch.float64)
    return {
        "translation_m": [float(v) for v in np.asarray(T_imu_lidar)[:3, 3]],
        "quat_xyzw": [float(v) for v in geo.matrix_to_quat(R)],
        "rpy_deg": [float(v) for v in np.degrees(geo.matrix_to_euler_rpy(R).numpy())],
    }
