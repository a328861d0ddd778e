"""What ``l2calib inspect`` found per topic: the LiDAR, IMU and NavSatFix reports.

Plain records, filled by :mod:`l2calib.preflight` and read by the checks
(:mod:`l2calib.preflight_checks`).
"""

from __future__ import annotations

from dataclasses import dataclass

from l2calib.io.imu_reader import ImuUnits
from l2calib.io.lidar_conventions import TimeConvention
from l2calib.io.stamps import StampStats


@dataclass
class LidarTopicReport:
    """Findings for one LiDAR topic (shares are of all points of all messages)."""

    topic: str
    msgtype: str
    stamps: StampStats
    layout: str = "unknown"
    convention: TimeConvention | None = None
    points_per_scan: float = 0.0
    nan_share: float = 0.0
    zero_share: float = 0.0
    range_share: float = 0.0
    empty_scans: int = 0
    rel_time_s: tuple[float, float] = (float("nan"), float("nan"))
    scan_duration_s: float = float("nan")
    scan_stamps: tuple[int, int] = (0, 0)


@dataclass
class ImuTopicReport:
    """Findings for one IMU topic (values after unit conversion)."""

    topic: str
    stamps: StampStats
    units: ImuUnits | None = None
    gravity_m_s2: float = float("nan")
    gravity_at_rest: bool = False
    mean_abs_gyro_rad_s: tuple[float, float, float] = (float("nan"),) * 3
    max_gyro_rad_s: float = float("nan")


@dataclass
class NavSatTopicReport:
    """Findings for one NavSatFix topic."""

    topic: str
    stamps: StampStats
    fix_share: float = 0.0
    rtk_share: float = 0.0
