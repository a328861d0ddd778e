"""l2calib: target-free IMU-LiDAR extrinsic calibration by reinforcement learning on SE(3).

Frames are named in variables: ``T_imu_lidar`` maps points from the LiDAR frame into the IMU
frame (``p_imu = T_imu_lidar @ p_lidar``). Quaternions are ``quat_xyzw`` (Hamilton, scalar last).
Time stamps are int64 nanoseconds (``stamp_ns``); durations in seconds carry ``_s``.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
