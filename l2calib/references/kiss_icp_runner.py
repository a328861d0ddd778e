"""LiDAR-only odometry with KISS-ICP (PRBonn/kiss-icp) as a pure function over scans.

Which time does a KISS-ICP pose refer to? With per-point timestamps and deskewing on, KISS-ICP
(``Preprocessor::Preprocess`` in ``cpp/kiss_icp/core/Preprocessing.cpp``) normalises the point
times to ``[0, 1]`` over the scan and moves every point by ``exp((τ - 1) · log(Δ))``, i.e. into the
sensor frame at the scan's *latest* point; the registered pose is therefore the LiDAR pose at
``scan.end_stamp_ns``. Without deskewing the scan is treated as rigid and the pose best matches the
middle of the sweep, so we stamp it there. KISS-ICP's first pose is the identity: the trajectory's
world frame is the LiDAR frame at the first scan (``world_frame="kiss_icp_map"``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydantic import Field

from l2calib.data import LidarScan
from l2calib.errors import DataError, ReferenceSourceError
from l2calib.recipe import StrictModel
from l2calib.trajectory import Trajectory


class KissIcpOptions(StrictModel):
    """KISS-ICP settings (a flat view of its ``KISSConfig``)."""

    voxel_size: float | None = Field(None, gt=0, description="m; default: max_range_m / 100")
    max_range_m: float = Field(100.0, gt=0)
    min_range_m: float = Field(0.5, ge=0)
    deskew: bool = Field(True, description="motion-compensate with per-point times")
    max_points_per_voxel: int = Field(20, ge=1)
    initial_threshold: float = Field(2.0, gt=0, description="initial correspondence threshold (m)")
    min_motion_th: float = Field(0.1, ge=0)
    fixed_threshold: float | None = Field(None, gt=0)
    max_num_iterations: int = Field(500, ge=1)
    convergence_criterion: float = Field(1e-4, gt=0)
    max_num_threads: int = Field(0, ge=0, description="0: all cores")

    def kiss_config(self):  # noqa: ANN201 - kiss_icp.config.KISSConfig, imported lazily
        """The equivalent ``kiss_icp.config.KISSConfig``."""
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import (
            AdaptiveThresholdConfig,
            DataConfig,
            MappingConfig,
            RegistrationConfig,
        )

        if self.min_range_m >= self.max_range_m:
            raise ReferenceSourceError(
                f"kiss-icp: min_range_m ({self.min_range_m}) >= max_range_m ({self.max_range_m})",
                fix="make min_range_m smaller than max_range_m",
            )
        return KISSConfig(
            data=DataConfig(
                max_range=self.max_range_m, min_range=self.min_range_m, deskew=self.deskew
            ),
            mapping=MappingConfig(
                voxel_size=self.voxel_size or self.max_range_m / 100.0,
                max_points_per_voxel=self.max_points_per_voxel,
            ),
            registration=RegistrationConfig(
                max_num_iterations=self.max_num_iterations,
                convergence_criterion=self.convergence_criterion,
                max_num_threads=self.max_num_threads,
            ),
            adaptive_threshold=AdaptiveThresholdConfig(
                fixed_threshold=self.fixed_threshold,
                initial_threshold=self.initial_threshold,
                min_motion_th=self.min_motion_th,
            ),
        )


def pose_stamp_ns(scan: LidarScan, deskew: bool) -> int:
    """The time a KISS-ICP pose of ``scan`` refers to (see the module docstring)."""
    if deskew:
        return scan.end_stamp_ns
    return (scan.stamp_ns + scan.end_stamp_ns) // 2


def run_kiss_icp(
    scans: Sequence[LidarScan], options: KissIcpOptions | None = None, progress: bool = False
) -> Trajectory:
    """Runs KISS-ICP over ``scans`` (time order) and returns the LiDAR trajectory.

    Args:
        scans: LiDAR scans with per-point ``offset_s``.
        options: KISS-ICP settings (defaults if ``None``).
        progress: Show a rich progress bar.

    Returns:
        ``T_kiss_icp_map_lidar`` poses (``body_frame="lidar"``) stamped per :func:`pose_stamp_ns`.

    Raises:
        DataError: if fewer than 2 scans are given or stamps are not increasing.
    """
    from kiss_icp.kiss_icp import KissICP

    opts = options or KissIcpOptions()
    if len(scans) < 2:
        raise DataError(
            f"kiss-icp needs at least 2 scans, got {len(scans)}", fix="give a longer segment"
        )
    odom = KissICP(opts.kiss_config())
    stamps, poses = [], []
    items = scans
    if progress:
        from rich.progress import track

        items = track(scans, description="kiss-icp")
    for scan in items:
        frame = np.asarray(scan.points_lidar, dtype=np.float64)
        times = np.asarray(scan.offset_s, dtype=np.float64) if opts.deskew else np.zeros(0)
        odom.register_frame(frame, times)
        stamps.append(pose_stamp_ns(scan, opts.deskew))
        poses.append(odom.last_pose.copy())
    stamps_arr = np.asarray(stamps, dtype=np.int64)
    if np.any(np.diff(stamps_arr) <= 0):
        raise DataError(
            "kiss-icp: scan stamps are not strictly increasing",
            fix="sort the scans by time and drop duplicates",
        )
    return Trajectory.from_matrices(stamps_arr, np.stack(poses), "lidar", "kiss_icp_map")
