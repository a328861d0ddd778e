"""The filter loop: K candidate IEKFs run in lock-step over one prepared segment."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from l2calib.interfaces import CandidateStatus
from l2calib_backends.initialise import ReferenceMotion, initial_states
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors
from l2calib_backends.propagation import ImuNoise, PoseTrack, propagate
from l2calib_backends.update import UpdateSettings, iterated_update


@dataclass(frozen=True)
class RunSettings:
    """Everything :func:`run_segment` needs besides the data."""

    update: UpdateSettings
    noise: ImuNoise
    init_sigmas: dict[str, float]
    max_skipped_scans: int
    max_speed_m_s: float
    map_voxel_m: float
    plane_thickness_m: float


@dataclass(frozen=True)
class RunResult:
    """Per-candidate outputs over the scans after the first.

    Attributes:
        T_world_lidar: ``[K, N-1, 4, 4]`` estimated LiDAR poses at the scan ends.
        valid: ``[K, N-1]`` poses produced before any failure.
        status: ``[K]`` :class:`CandidateStatus` codes.
        correspondences: ``[K]`` mean number of point-to-plane matches per scan.
    """

    T_world_lidar: Tensor
    valid: Tensor
    status: Tensor
    correspondences: Tensor


def deskew(
    track: PoseTrack,
    R_end: Tensor,
    p_end: Tensor,
    points: Tensor,
    dt_end: Tensor,
    t_end: Tensor,
    R_il: Tensor,
    t_il: Tensor,
) -> Tensor:
    """Moves each filter's LiDAR points into the IMU frame at the scan end.

    Points ``[B, m, 3]`` were taken ``dt_end [B, m]`` s before the scan end; each filter's
    propagated motion and extrinsic move them.

    Returns:
        ``[B, m, 3]`` IMU-frame points at the scan end (``t_end [B]``, IMU clock).
    """
    q = points @ R_il.transpose(-1, -2) + t_il[:, None, :]  # IMU frame at t_j
    R_j, p_j = track.poses_at(t_end[:, None] - dt_end)
    world = (R_j @ q[..., None])[..., 0] + p_j
    return (world - p_end[:, None, :]) @ R_end


def lidar_poses(R: Tensor, p: Tensor, R_il: Tensor, t_il: Tensor) -> Tensor:
    """``T_world_lidar = T_world_imu T_imu_lidar`` as ``[B, 4, 4]``."""
    T = torch.zeros(R.shape[0], 4, 4, dtype=R.dtype)
    T[:, :3, :3] = R @ R_il
    T[:, :3, 3] = (R @ t_il[..., None])[..., 0] + p
    T[:, 3, 3] = 1.0
    return T


def window_starts(num_scans: int, window_scans: int) -> list[int]:
    """Start scans of the re-anchored windows (``window_scans <= 0``: one run over all)."""
    w = num_scans - 1 if window_scans <= 0 else window_scans
    return list(range(0, num_scans - 1, w))


def run_segment(
    seg: PreparedSegment,
    motion: ReferenceMotion,
    starts: list[int],
    T_imu_lidar: Tensor,
    time_offset_s: Tensor,
    settings: RunSettings,
    shared_map: VoxelPlaneMap | FrozenPlaneMap | None,
    seeds: ScanTensors | None = None,
) -> RunResult:
    """Runs K candidates over ``seg`` as K×W filters, one per candidate and window.

    Window ``w`` starts from the reference at scan ``starts[w]`` and estimates the scans up to
    the next start (the last one up to the final scan), so every scan but the first is estimated
    exactly once per candidate. ``shared_map=None`` selects the own-map (odometry) mode, where
    each filter's map starts from ``seeds.points[w]``: window ``w``'s first scan placed and
    deskewed by the reference (world frame).
    """
    K, W, N = T_imu_lidar.shape[0], len(starts), len(seg.end_t)
    B = K * W
    ends = torch.tensor(starts[1:] + [N - 1])  # last scan of each window
    first = torch.tensor(starts).repeat(K)  # [B]
    last = ends.repeat(K)
    cand = torch.arange(K).repeat_interleave(W)  # candidate of each filter
    R_il, t_il = T_imu_lidar[cand, :3, :3], T_imu_lidar[cand, :3, 3]
    off = time_offset_s[cand]
    state = initial_states(motion, T_imu_lidar, settings.init_sigmas)
    groups = torch.arange(B)[:, None]
    zeros = torch.zeros(B, 1, dtype=torch.int64)
    plane_map = shared_map
    if plane_map is None:
        plane_map = VoxelPlaneMap(settings.map_voxel_m, max_thickness_m=settings.plane_thickness_m)
        if seeds is None:
            raise ValueError("the odometry mode needs the seed points of each window")
        slot = torch.arange(W).repeat(K)
        world, keep = seeds.points[slot], seeds.mask[slot]
        plane_map.insert(world[keep], groups.expand(-1, keep.shape[1])[keep])
    map_groups = zeros if shared_map is not None else groups

    def query(p_w: Tensor, widen: bool):
        return plane_map.query(p_w, map_groups, widen)

    out = torch.zeros(K, N - 1, 4, 4, dtype=T_imu_lidar.dtype)
    valid = torch.zeros(K, N - 1, dtype=torch.bool)
    status = torch.full((B,), int(CandidateStatus.OK), dtype=torch.int64)
    alive = torch.ones(B, dtype=torch.bool)
    skipped = torch.zeros(B, dtype=torch.int64)
    corr_sum = torch.zeros(B, dtype=torch.float64)
    upd = seg.update
    for j in range(1, int((last - first).max()) + 1):
        scan = torch.minimum(first + j, last)
        active = (first + j) <= last
        t1 = seg.end_t[scan] + off
        t0 = torch.where(active, seg.end_t[scan - 1] + off, t1)
        prior, track = propagate(state, seg.imu, t0, t1, settings.noise)
        q = deskew(track, prior.R, prior.p, upd.points[scan], upd.dt_end[scan], t1, R_il, t_il)
        mask = upd.mask[scan] & active[:, None]
        post, n_ok = iterated_update(prior, q, mask, upd.ranges[scan], query, settings.update)
        corr_sum += torch.where(active, n_ok, 0).to(torch.float64)
        skipped = torch.where(
            active & (n_ok < settings.update.min_correspondences), skipped + 1, skipped
        )
        # A candidate that loses track keeps running on its IMU: its drift is what grades it
        # (as in the paper's LIO). Only a non-finite or absurd state stops a filter.
        lost = (skipped >= settings.max_skipped_scans) & (status == int(CandidateStatus.OK))
        status = torch.where(alive & lost, int(CandidateStatus.FEW_CORRESPONDENCES), status)
        diverged = alive & (~post.is_finite() | (post.v.norm(dim=-1) > settings.max_speed_m_s))
        status = torch.where(diverged, int(CandidateStatus.DIVERGED), status)
        alive = alive & ~diverged
        state = post.where(alive & active, state)  # diverged filters stay frozen (and finite)
        poses = lidar_poses(state.R, state.p, R_il, t_il)
        rec = active.nonzero().squeeze(-1)
        out[cand[rec], scan[rec] - 1] = poses[rec]
        valid[cand[rec], scan[rec] - 1] = alive[rec]
        if shared_map is None and bool((alive & active).any()):
            ins = seg.insert
            qi = deskew(track, prior.R, prior.p, ins.points[scan], ins.dt_end[scan], t1, R_il, t_il)
            world = qi @ state.R.transpose(-1, -2) + state.p[:, None, :]
            keep = (alive & active)[:, None] & ins.mask[scan]
            plane_map.insert(world[keep], groups.expand(-1, keep.shape[1])[keep])
    eye = torch.eye(4, dtype=out.dtype)
    out = torch.where(valid[..., None, None], out, eye)
    per_cand = status.reshape(K, W)
    cand_status = torch.where(
        (per_cand == int(CandidateStatus.DIVERGED)).any(1),
        int(CandidateStatus.DIVERGED),
        per_cand.max(1).values,
    )
    return RunResult(out, valid, cand_status, corr_sum.reshape(K, W).sum(1) / max(N - 1, 1))
