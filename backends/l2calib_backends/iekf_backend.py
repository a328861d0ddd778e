"""``iekf`` backend: batched FAST-LIO2-style LIO scoring K candidate extrinsics per call."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch

from l2calib.data import LidarScan, Segment
from l2calib.errors import BackendError
from l2calib.interfaces import CandidateTrajectories, OdometryBackend, ReferenceTrajectory
from l2calib.recipe import ImuInput
from l2calib.trajectory import Trajectory
from l2calib_backends.iekf import RunResult, RunSettings, run_segment
from l2calib_backends.initialise import ReferenceMotion, reference_motion
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors, prepare_segment
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.scan_loop import window_starts
from l2calib_backends.specs import AUTO_WINDOW_SCANS, IekfOptions, LioOptions
from l2calib_backends.update import UpdateSettings

_log = logging.getLogger(__name__)


def reference_world_points(
    scan: LidarScan, traj: Trajectory, voxel_m: float, min_range_m: float, max_range_m: float
) -> torch.Tensor:
    """World points ``[P, 3]`` of a scan placed and deskewed by the reference LiDAR trajectory.

    The reference is a trajectory of the LiDAR itself, so each point is moved by the reference
    pose interpolated at the point's own time: no extrinsic enters. Points are thinned to one per
    ``voxel_m`` cell first, and points outside the reference's time span are dropped.
    """
    pts = np.asarray(scan.points_lidar, dtype=np.float64)
    rng = np.linalg.norm(pts, axis=1)
    keep = np.flatnonzero((rng >= min_range_m) & (rng <= max_range_m))
    ijk = np.floor(pts[keep] / voxel_m).astype(np.int64) + (1 << 20)
    _, first = np.unique((ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2], return_index=True)
    sel = keep[np.sort(first)]
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
    return world[torch.from_numpy(ok[inv])]


def build_reference_map(
    segments: Sequence[Segment],
    references: Sequence[ReferenceTrajectory],
    voxel_m: float,
    thickness_m: float,
    min_range_m: float,
    max_range_m: float,
) -> FrozenPlaneMap:
    """One plane map from every scan of every segment, placed by the reference trajectory.

    Returned frozen (read-only, binary-search lookups): it never changes afterwards.
    """
    plane_map = VoxelPlaneMap(voxel_m, max_thickness_m=thickness_m)
    for seg, ref in zip(segments, references, strict=True):
        for scan in seg.scans:
            world = reference_world_points(
                scan, ref.trajectory, voxel_m / 4, min_range_m, max_range_m
            )
            plane_map.insert(world, torch.zeros(len(world), dtype=torch.int64))
    return FrozenPlaneMap(plane_map)


def _seed_points(
    seg: Segment, traj: Trajectory, starts: list[int], voxel_m: float, r_min: float, r_max: float
) -> ScanTensors:
    """Reference-placed world points of each window's first scan (odometry mode's first map)."""
    clouds = [reference_world_points(seg.scans[i], traj, voxel_m, r_min, r_max) for i in starts]
    m = max([len(c) for c in clouds] + [1])
    points = torch.zeros(len(clouds), m, 3, dtype=torch.float64)
    mask = torch.zeros(len(clouds), m, dtype=torch.bool)
    for i, c in enumerate(clouds):
        points[i, : len(c)] = c
        mask[i, : len(c)] = True
    zeros = torch.zeros(len(clouds), m, dtype=torch.float64)
    return ScanTensors(points, zeros, mask, zeros)


def mean_rotation_rate(segments: Sequence[PreparedSegment]) -> float:
    """Mean gyro norm (rad/s) over all IMU samples of the prepared segments."""
    rates = torch.cat([s.imu.gyro.norm(dim=-1) for s in segments])
    return float(rates.mean()) if len(rates) else 0.0


def resolve_window_scans(options: LioOptions, segments: Sequence[PreparedSegment]) -> int:
    """``window_scans`` to use: the option, or for ``auto`` a choice by rotation rate.

    Ten-scan windows keep grossly wrong candidates graded smoothly and run 3× faster, which a
    learner starting from a uniform rotation needs on well-excited data. Under weak excitation
    (UAV, ground vehicle) they hide the small IMU–LiDAR inconsistencies that grade the lever
    arm, so a continuous run per segment (0) is used when the mean gyro norm over all segments
    is below ``weak_excitation_rate_rad_s`` (measured in ``docs/backends.md``).
    """
    if options.window_scans != "auto":
        return int(options.window_scans)
    weak = mean_rotation_rate(segments) < options.weak_excitation_rate_rad_s
    return 0 if weak else AUTO_WINDOW_SCANS


class IekfBackend(OdometryBackend):
    """Batched iterated ESKF LIO (see :mod:`l2calib_backends.iekf`).

    Args:
        config: Backend options.
        imu: IMU noise densities from the recipe (defaults of :class:`ImuInput` if ``None``).
    """

    outputs_in_reference_frame = True  # every filter starts from the reference pose

    def __init__(self, config: IekfOptions, imu: ImuInput | None = None, **_: object) -> None:
        self.config = config
        noise = ImuNoise.from_recipe(imu)
        c = config
        self.settings = RunSettings(
            update=UpdateSettings(
                max_iterations=c.max_iterations,
                point_sigma_m=c.point_sigma_m,
                min_correspondences=c.min_correspondences,
            ),
            noise=noise,
            init_sigmas=c.init_sigmas(),  # 'auto' resolved in prepare()
            max_skipped_scans=c.max_skipped_scans,
            max_speed_m_s=c.max_speed_m_s,
            map_voxel_m=c.map_voxel_m,
            plane_thickness_m=c.plane_thickness_m,
        )
        self.init_sigmas = c.init_sigmas()
        self.window_scans = c.window_scans
        self._segments: list[PreparedSegment] = []
        self._motions: list[ReferenceMotion] = []
        self._starts: list[list[int]] = []
        self._map: VoxelPlaneMap | None = None
        if c.threads:
            torch.set_num_threads(c.threads)

    def prepare(
        self, segments: Sequence[Segment], references: Sequence[ReferenceTrajectory]
    ) -> None:
        """Downsamples scans, samples the reference motion and (shared-map) builds the map."""
        if len(segments) != len(references):
            raise BackendError(
                f"{len(segments)} segments but {len(references)} references",
                fix="give one reference per segment",
            )
        c = self.config
        self._segments = [
            prepare_segment(
                s,
                c.scan_voxel_m,
                c.points_per_scan,
                c.map_points_per_scan,
                c.min_range_m,
                c.max_range_m,
                c.seed + i,
            )
            for i, s in enumerate(segments)
        ]
        rate = mean_rotation_rate(self._segments)
        weak = rate < c.weak_excitation_rate_rad_s
        self.window_scans = resolve_window_scans(c, self._segments)
        self._use_init_sigmas(c.init_sigmas(weak))
        _log.info(
            "mean |ω| %.2f rad/s (%s): %s, start priors %s",
            rate,
            "weakly excited" if weak else "well excited",
            "one continuous run per segment"
            if self.window_scans == 0
            else f"windows of {self.window_scans} scans",
            self.init_sigmas,
        )
        self._starts = [window_starts(len(s.measurements), self.window_scans) for s in segments]
        self._seeds = [None] * len(segments)
        if c.map_mode == "odometry":
            self._seeds = [
                _seed_points(s, r.trajectory, st, c.scan_voxel_m / 4, c.min_range_m, c.max_range_m)
                for s, r, st in zip(segments, references, self._starts, strict=True)
            ]
        self._motions = [
            reference_motion(p, r.trajectory, st)
            for p, r, st in zip(self._segments, references, self._starts, strict=True)
        ]
        self._map = None
        if c.map_mode == "shared-map":
            self._map = build_reference_map(
                segments,
                references,
                c.map_voxel_m,
                c.plane_thickness_m,
                c.min_range_m,
                c.max_range_m,
            )

    def _use_init_sigmas(self, sigmas: dict[str, float]) -> None:
        """Start-state priors resolved at :meth:`prepare` (``auto`` depends on the data)."""
        self.init_sigmas = sigmas
        self.settings = replace(self.settings, init_sigmas=sigmas)

    def evaluate(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ) -> list[CandidateTrajectories]:
        """Runs all candidates on every prepared segment (see :class:`OdometryBackend`)."""
        if not self._segments:
            raise BackendError("evaluate() called before prepare()", fix="call prepare() first")
        T = torch.as_tensor(T_imu_lidar, dtype=torch.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise BackendError(
                f"T_imu_lidar must be [K, 4, 4], got {tuple(T.shape)}",
                fix="stack the K candidate extrinsics into one [K, 4, 4] float64 tensor",
            )
        K = T.shape[0]
        off = (
            torch.zeros(K, dtype=torch.float64)
            if time_offset_s is None
            else torch.as_tensor(time_offset_s, dtype=torch.float64).reshape(K)
        )
        outputs = []
        with torch.no_grad():
            for seg, motion, starts, seeds in zip(
                self._segments, self._motions, self._starts, self._seeds, strict=True
            ):
                res = self._run_segment(seg, motion, starts, T, off, seeds)
                outputs.append(
                    CandidateTrajectories(
                        segment=seg.name,
                        stamps_ns=seg.end_stamps_ns[1:],
                        T_world_lidar=res.T_world_lidar,
                        valid=res.valid,
                        status=res.status,
                    )
                )
        return outputs

    def _run_segment(self, seg, motion, starts, T, off, seeds) -> RunResult:  # noqa: ANN001
        """One prepared segment for all candidates (the GTSAM backend overrides this)."""
        return run_segment(seg, motion, starts, T, off, self.settings, self._map, seeds)
