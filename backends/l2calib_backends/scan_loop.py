"""The per-scan driver shared by the IEKF and the GTSAM backends.

K candidates × W windows run as B = K·W filters in lock-step over one prepared segment. Per scan,
for all filters at once: propagate with the IMU, deskew the scan with each candidate's extrinsic,
let the backend's *step* correct the prior (an iterated Kalman update, or a registration plus a
factor-graph update), then book-keep what both backends share: statuses (lost, diverged,
failed), the recorded LiDAR poses and, in the own-map (odometry) mode, the map insertion.
Window ``w`` starts from the reference at scan ``starts[w]`` and estimates the scans up to the
next start (the last one up to the final scan), so every scan but the first is estimated
exactly once per candidate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from l2calib.interfaces import CandidateStatus
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors
from l2calib_backends.propagation import ImuNoise, PoseTrack, propagate
from l2calib_backends.state import FilterState

_OK, _LOST = int(CandidateStatus.OK), int(CandidateStatus.FEW_CORRESPONDENCES)
_DIVERGED = int(CandidateStatus.DIVERGED)


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


@dataclass(frozen=True)
class Batch:
    """How K candidates × W windows are laid out as B = K·W filters (filter b = k·W + w).

    Attributes:
        K, W, N: Candidates, windows, scans of the segment.
        first, last: ``[B]`` first (reference-anchored) and last scan of each filter's window.
        cand: ``[B]`` candidate of each filter.
        R_il, t_il: ``[B, 3, 3]``, ``[B, 3]`` each filter's ``T_imu_lidar``.
        off: ``[B]`` each filter's LiDAR–IMU time offset (s).
    """

    K: int
    W: int
    N: int
    first: Tensor
    last: Tensor
    cand: Tensor
    R_il: Tensor
    t_il: Tensor
    off: Tensor

    @classmethod
    def layout(
        cls,
        starts: list[int],
        num_scans: int,
        T_imu_lidar: Tensor,
        time_offset_s: Tensor,
        ends: list[int] | None = None,
    ) -> Batch:
        """The layout for window ``starts`` over ``num_scans`` scans and K candidates.

        Window ``w`` estimates the scans after ``starts[w]`` up to ``ends[w]`` (default: up to
        the next start, the last window up to the final scan); scans outside every window stay
        invalid (a coarse evaluation: :mod:`l2calib_backends.data_fraction`).
        """
        K, W = T_imu_lidar.shape[0], len(starts)
        if ends is None:
            ends = starts[1:] + [num_scans - 1]
        cand = torch.arange(K).repeat_interleave(W)
        return cls(
            K=K,
            W=W,
            N=num_scans,
            first=torch.tensor(starts).repeat(K),
            last=torch.tensor(ends).repeat(K),
            cand=cand,
            R_il=T_imu_lidar[cand, :3, :3],
            t_il=T_imu_lidar[cand, :3, 3],
            off=time_offset_s[cand],
        )

    @property
    def B(self) -> int:  # noqa: N802 - the batch size's usual name
        """Number of filters."""
        return self.K * self.W


@dataclass(frozen=True)
class StepInput:
    """What a backend's correction step sees for one scan (all ``[B, ...]``).

    Attributes:
        prior: Propagated states at the scan end.
        points: ``[B, m, 3]`` deskewed points in the IMU frame at the scan end.
        mask: ``[B, m]`` usable points (False for filters whose window is over).
        ranges: ``[B, m]`` point ranges (m).
        query: Plane-map lookup ``query(points_world, widen)``.
        t0, t1: ``[B]`` previous and current scan ends (IMU clock, s).
        active: ``[B]`` filters whose window contains this scan.
        alive: ``[B]`` filters that have not diverged or failed.
    """

    prior: FilterState
    points: Tensor
    mask: Tensor
    ranges: Tensor
    query: Callable
    t0: Tensor
    t1: Tensor
    active: Tensor
    alive: Tensor


@dataclass(frozen=True)
class StepOutput:
    """A correction step's result.

    Attributes:
        state: Corrected states (entries of inactive or dead filters are ignored).
        num_matches: ``[B]`` point-to-plane matches used.
        updated: ``[B]`` the scan corrected the filter (enough matches).
        codes: ``[B]`` OK, or the CandidateStatus that stops the filter (DIVERGED, FAILED).
    """

    state: FilterState
    num_matches: Tensor
    updated: Tensor
    codes: Tensor


Step = Callable[[StepInput], StepOutput]


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


def count_misses(misses: Tensor, updated: Tensor, active: Tensor) -> Tensor:
    """Consecutive scans without an update ``[B]``: +1 on an active miss, 0 after an update."""
    return torch.where(updated, 0, torch.where(active, misses + 1, misses))


@dataclass(frozen=True)
class MapSettings:
    """The plane map of the own-map (odometry) mode."""

    voxel_m: float
    thickness_m: float


@dataclass
class Progress:
    """What :func:`drive` accumulates: raw outputs before the per-candidate reduction."""

    out: Tensor  # [K, N-1, 4, 4]
    valid: Tensor  # [K, N-1]
    status: Tensor  # [B]
    alive: Tensor  # [B]
    corr_sum: Tensor  # [B]

    def result(self, batch: Batch) -> RunResult:
        """Per-candidate :class:`RunResult` (a candidate's worst window decides its status)."""
        out = torch.where(self.valid[..., None, None], self.out, torch.eye(4, dtype=self.out.dtype))
        per_cand = self.status.reshape(batch.K, batch.W)
        cand_status = torch.where((per_cand == _DIVERGED).any(1), _DIVERGED, per_cand.max(1).values)
        corr = self.corr_sum.reshape(batch.K, batch.W).sum(1) / max(batch.N - 1, 1)
        return RunResult(out, self.valid, cand_status, corr)


def drive(
    seg: PreparedSegment,
    batch: Batch,
    state: FilterState,
    noise: ImuNoise,
    step: Step,
    shared_map: VoxelPlaneMap | FrozenPlaneMap | None,
    seeds: ScanTensors | None,
    own_map: MapSettings,
    max_skipped_scans: int,
    max_speed_m_s: float,
) -> Progress:
    """Runs the B filters over the segment's scans with the backend's correction ``step``.

    ``shared_map=None`` selects the own-map (odometry) mode, where each filter's map starts
    from ``seeds.points[w]`` (window ``w``'s first scan placed and deskewed by the reference,
    world frame) and grows with the filter's own estimates.

    A filter that loses track (``max_skipped_scans`` consecutive scans without an update) keeps
    running on its IMU: its drift is what grades it (as in the paper's LIO). Only a step failure, a
    non-finite state or a speed above ``max_speed_m_s`` stops a filter (frozen, finite).
    """
    B, K, N = batch.B, batch.K, batch.N
    groups = torch.arange(B)[:, None]
    plane_map = shared_map
    if plane_map is None:
        if seeds is None:
            raise ValueError("the odometry mode needs the seed points of each window")
        plane_map = VoxelPlaneMap(own_map.voxel_m, max_thickness_m=own_map.thickness_m)
        slot = torch.arange(batch.W).repeat(K)
        world, keep = seeds.points[slot], seeds.mask[slot]
        plane_map.insert(world[keep], groups.expand(-1, keep.shape[1])[keep])
    map_groups = torch.zeros(B, 1, dtype=torch.int64) if shared_map is not None else groups

    def query(p_w: Tensor, widen: bool):
        return plane_map.query(p_w, map_groups, widen)

    dtype = state.R.dtype
    prog = Progress(
        out=torch.zeros(K, N - 1, 4, 4, dtype=dtype),
        valid=torch.zeros(K, N - 1, dtype=torch.bool),
        status=torch.full((B,), _OK, dtype=torch.int64),
        alive=torch.ones(B, dtype=torch.bool),
        corr_sum=torch.zeros(B, dtype=torch.float64),
    )
    skipped = torch.zeros(B, dtype=torch.int64)
    first, last, cand = batch.first, batch.last, batch.cand
    R_il, t_il = batch.R_il, batch.t_il
    upd = seg.update
    for j in range(1, int((last - first).max()) + 1):
        scan = torch.minimum(first + j, last)
        active = (first + j) <= last
        t1 = seg.end_t[scan] + batch.off
        t0 = torch.where(active, seg.end_t[scan - 1] + batch.off, t1)
        prior, track = propagate(state, seg.imu, t0, t1, noise)
        q = deskew(track, prior.R, prior.p, upd.points[scan], upd.dt_end[scan], t1, R_il, t_il)
        mask = upd.mask[scan] & active[:, None]
        res = step(StepInput(prior, q, mask, upd.ranges[scan], query, t0, t1, active, prog.alive))
        prog.corr_sum += torch.where(active, res.num_matches, 0).to(torch.float64)
        skipped = count_misses(skipped, res.updated, active)
        lost = prog.alive & (skipped >= max_skipped_scans) & (prog.status == _OK)
        prog.status = torch.where(lost, _LOST, prog.status)
        new = res.state
        blown = ~new.is_finite() | (new.v.norm(dim=-1) > max_speed_m_s)
        failed = prog.alive & active & ((res.codes != _OK) | blown)
        prog.status = torch.where(
            failed, torch.where(res.codes != _OK, res.codes, _DIVERGED), prog.status
        )
        prog.alive = prog.alive & ~failed
        state = new.where(prog.alive & active, state)  # stopped filters stay frozen (finite)
        poses = lidar_poses(state.R, state.p, R_il, t_il)
        rec = active.nonzero().squeeze(-1)
        prog.out[cand[rec], scan[rec] - 1] = poses[rec]
        prog.valid[cand[rec], scan[rec] - 1] = prog.alive[rec]
        if shared_map is None and bool((prog.alive & active).any()):
            ins = seg.insert
            qi = deskew(track, prior.R, prior.p, ins.points[scan], ins.dt_end[scan], t1, R_il, t_il)
            world = qi @ state.R.transpose(-1, -2) + state.p[:, None, :]
            keep = (prog.alive & active)[:, None] & ins.mask[scan]
            plane_map.insert(world[keep], groups.expand(-1, keep.shape[1])[keep])
    return prog
