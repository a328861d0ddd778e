"""Maps and start points placed by the reference trajectory (no extrinsic enters).

The shared map all candidates of a LIO backend query (``map_mode: shared-map``) and the first
map points of each window in ``odometry`` mode.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from l2calib.data import LidarScan, Segment
from l2calib.interfaces import ReferenceTrajectory
from l2calib.references.ct_map import voxel_pick
from l2calib.trajectory import Trajectory
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import ScanTensors, voxel_means


def reference_world_points(
    scan: LidarScan,
    traj: Trajectory,
    voxel_m: float,
    min_range_m: float,
    max_range_m: float,
    voxel_point: str = "earliest",
    rng: np.random.Generator | None = None,
) -> torch.Tensor:
    """World points ``[P, 3]`` of a scan placed and deskewed by the reference LiDAR trajectory.

    The reference is a trajectory of the LiDAR itself, so each point is moved by the reference
    pose interpolated at the point's own time: no extrinsic enters. Points are thinned to one per
    ``voxel_m`` cell (``voxel_point``: the earliest fired or a random one, drawn with ``rng``
    or seed 0, before they are placed; ``centroid``: the mean of each world-frame cell's placed
    points), and points outside the reference's time span are dropped.
    """
    pts = np.asarray(scan.points_lidar, dtype=np.float64)
    range_m = np.linalg.norm(pts, axis=1)
    keep = np.flatnonzero((range_m >= min_range_m) & (range_m <= max_range_m))
    if voxel_point == "centroid":
        sel = keep
    else:
        if voxel_point == "random" and rng is None:
            rng = np.random.default_rng(0)
        pick = voxel_pick(pts[keep], voxel_m, rng if voxel_point == "random" else None)
        sel = keep[np.sort(pick)]
    stamps = scan.point_stamps_ns[sel]
    uniq, inv = np.unique(stamps, return_inverse=True)
    poses, ok = traj.sample(uniq, max_gap_s=0.5)
    if not ok.any():
        return torch.zeros(0, 3, dtype=torch.float64)
    T = torch.zeros(len(uniq), 4, 4, dtype=torch.float64)
    T[torch.from_numpy(ok)] = poses.matrices()
    T_pt = T[torch.from_numpy(inv)]
    p = torch.from_numpy(pts[sel])
    world = (T_pt[:, :3, :3] @ p[..., None])[..., 0] + T_pt[:, :3, 3]
    world = world[torch.from_numpy(ok[inv])]
    if voxel_point == "centroid" and len(world):
        world = torch.from_numpy(voxel_means(world.numpy(), voxel_m)[0])
    return world


def build_reference_map(
    segments: Sequence[Segment],
    references: Sequence[ReferenceTrajectory],
    voxel_m: float,
    thickness_m: float,
    min_range_m: float,
    max_range_m: float,
    voxel_point: str = "earliest",
    rng: np.random.Generator | None = None,
) -> FrozenPlaneMap:
    """One plane map from every scan of every segment, placed by the reference trajectory.

    Returned frozen (read-only, binary-search lookups): it never changes afterwards.
    ``voxel_point`` / ``rng``: how each scan is thinned (:func:`reference_world_points`).
    """
    plane_map = VoxelPlaneMap(voxel_m, max_thickness_m=thickness_m)
    for seg, ref in zip(segments, references, strict=True):
        for scan in seg.scans:
            world = reference_world_points(
                scan, ref.trajectory, voxel_m / 4, min_range_m, max_range_m, voxel_point, rng
            )
            plane_map.insert(world, torch.zeros(len(world), dtype=torch.int64))
    return FrozenPlaneMap(plane_map)


def build_reference_maps(
    segments: Sequence[Segment],
    references: Sequence[ReferenceTrajectory],
    voxel_m: float,
    thickness_m: float,
    min_range_m: float,
    max_range_m: float,
    voxel_point: str = "earliest",
    rng: np.random.Generator | None = None,
) -> list[FrozenPlaneMap]:
    """One map per reference world frame; returns each segment's (shared by its frame).

    References only share a map when they share a world frame (``trajectory.world_frame``):
    a ground-truth file's or RTK's frame spans every segment, while a LiDAR-only odometry
    (``ct-lidar:<run>``, ``kiss-icp:<segment>``) starts each run at its own origin. One map
    over segments in different frames overlays scans that do not belong together: on the
    simulated ground vehicle (three drives, ct-lidar), the odometry at the TRUE extrinsic then
    disagreed with the reference by 5.6 cm on average where it agrees to 0.34 cm with the
    exact trajectory, and the calibrations ended 14-15 cm off along y.
    """
    by_frame: dict[str, list[int]] = {}
    for i, ref in enumerate(references):
        by_frame.setdefault(ref.trajectory.world_frame, []).append(i)
    out: list[FrozenPlaneMap | None] = [None] * len(segments)
    for members in by_frame.values():
        shared = build_reference_map(
            [segments[i] for i in members], [references[i] for i in members],
            voxel_m, thickness_m, min_range_m, max_range_m, voxel_point, rng,
        )  # fmt: skip
        for i in members:
            out[i] = shared
    return out


def seed_points(
    seg: Segment,
    traj: Trajectory,
    starts: list[int],
    voxel_m: float,
    r_min: float,
    r_max: float,
    voxel_point: str = "earliest",
    rng: np.random.Generator | None = None,
) -> ScanTensors:
    """Reference-placed world points of each window's first scan (odometry mode's first map)."""
    clouds = [
        reference_world_points(seg.scans[i], traj, voxel_m, r_min, r_max, voxel_point, rng)
        for i in starts
    ]
    m = max([len(c) for c in clouds] + [1])
    points = torch.zeros(len(clouds), m, 3, dtype=torch.float64)
    mask = torch.zeros(len(clouds), m, dtype=torch.bool)
    for i, c in enumerate(clouds):
        points[i, : len(c)] = c
        mask[i, : len(c)] = True
    zeros = torch.zeros(len(clouds), m, dtype=torch.float64)
    return ScanTensors(points, zeros, mask, zeros)
