"""LiDAR-only odometry with KISS-ICP (PRBonn/kiss-icp) as a pure function over scans.

Which time does a KISS-ICP pose refer to? With per-point timestamps and deskewing on, KISS-ICP
(``Preprocessor::Preprocess`` in ``cpp/kiss_icp/core/Preprocessing.cpp``) normalises the point
times to ``[0, 1]`` over the scan and moves every point by ``exp((τ - 1) · log(Δ))``, i.e. into the
sensor frame at the scan's *latest* point; the registered pose is therefore the LiDAR pose at
``scan.end_stamp_ns``. Without deskewing the scan is treated as rigid and the pose best matches the
middle of the sweep, so we stamp it there. KISS-ICP's first pose is the identity: the trajectory's
world frame is the LiDAR frame at the first scan (``world_frame="kiss_icp_map"``).

Iterated deskewing (``deskew_iterations > 1``): KISS-ICP deskews a scan with the *previous* scan's
motion (constant velocity) before registering it. Under fast, changing rotation (a hand-swung rig
at 2-4 rad/s) that prediction is poor and the distorted scan corrupts the map. With iterations, the
scan is deskewed again with the motion just estimated for it (``last_pose⁻¹ · new_pose``) and
re-registered from the new pose; the map and the adaptive threshold are updated once, with the
final result, exactly as ``KissICP.register_frame`` does. It reuses KISS-ICP's own preprocessor,
registration, voxel map and threshold objects (kiss-icp 1.3 Python API).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from l2calib.data import LidarScan
from l2calib.errors import DataError
from l2calib.references.options import KissIcpOptions
from l2calib.trajectory import Trajectory

__all__ = ["KissIcpOptions", "pose_stamp_ns", "run_kiss_icp"]


def pose_stamp_ns(scan: LidarScan, deskew: bool) -> int:
    """The time a KISS-ICP pose of ``scan`` refers to (see the module docstring)."""
    if deskew:
        return scan.end_stamp_ns
    return (scan.stamp_ns + scan.end_stamp_ns) // 2


def _register_iterated(odom, frame: np.ndarray, times: np.ndarray, iterations: int) -> None:  # noqa: ANN001
    """``KissICP.register_frame`` with the deskew repeated using the motion just estimated."""
    guess = odom.last_pose @ odom.last_delta
    sigma = odom.adaptive_threshold.get_threshold()
    delta, pose = odom.last_delta, guess
    for _ in range(iterations):
        deskewed = odom.preprocessor.preprocess(frame, times, delta)
        source, frame_downsample = odom.voxelize(deskewed)
        pose = odom.registration.align_points_to_map(
            points=source,
            voxel_map=odom.local_map,
            initial_guess=pose,
            max_correspondance_distance=3 * sigma,
            kernel=sigma,
        )
        delta = np.linalg.inv(odom.last_pose) @ pose
    odom.adaptive_threshold.update_model_deviation(np.linalg.inv(guess) @ pose)
    odom.local_map.update(frame_downsample, pose)
    odom.last_delta = delta
    odom.last_pose = pose


def run_kiss_icp(
    scans: Sequence[LidarScan],
    options: KissIcpOptions | None = None,
    progress: bool = False,
    deskew_iterations: int = 1,
) -> Trajectory:
    """Runs KISS-ICP over ``scans`` (time order) and returns the LiDAR trajectory.

    Args:
        scans: LiDAR scans with per-point ``offset_s``.
        options: KISS-ICP settings (defaults if ``None``).
        progress: Show a rich progress bar.
        deskew_iterations: 1 = stock KISS-ICP; more = iterated deskewing (module docstring).

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
        if deskew_iterations > 1 and opts.deskew:
            _register_iterated(odom, frame, times, deskew_iterations)
        else:
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
