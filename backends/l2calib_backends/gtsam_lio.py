"""The GTSAM LIO loop: K×W factor graphs advanced in lock-step over one prepared segment.

Per scan, for all filters at once (torch): propagate each filter's latest graph estimate with
the IMU (:func:`~l2calib_backends.propagation.propagate`, the IEKF's propagation, used here for
the predicted pose and the deskew track only), deskew the scan with the candidate extrinsic,
and register it to the plane map (:mod:`l2calib_backends.registration`). Then, filter by filter
(GTSAM), add the preintegrated IMU factor and the registered pose to its graph and update iSAM2
(:mod:`l2calib_backends.gtsam_graph`). Windows, start states, statuses and outputs follow the
IEKF exactly (:func:`l2calib_backends.iekf.run_segment`), so both backends are interchangeable.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from l2calib.interfaces import CandidateStatus
from l2calib_backends.gtsam_graph import GraphSettings, ScanGraph, imu_intervals, imu_params
from l2calib_backends.iekf import RunResult, deskew, lidar_poses
from l2calib_backends.initialise import ReferenceMotion, initial_states
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors
from l2calib_backends.propagation import ImuNoise, propagate
from l2calib_backends.registration import RegistrationSettings, register_scans
from l2calib_backends.state import DIM

_log = logging.getLogger(__name__)
_OK, _LOST = int(CandidateStatus.OK), int(CandidateStatus.FEW_CORRESPONDENCES)
_DIVERGED, _FAILED = int(CandidateStatus.DIVERGED), int(CandidateStatus.FAILED)


@dataclass(frozen=True)
class GtsamRunSettings:
    """Everything :func:`run_segment_gtsam` needs besides the data."""

    registration: RegistrationSettings
    graph: GraphSettings
    noise: ImuNoise
    max_skipped_scans: int
    max_speed_m_s: float
    map_voxel_m: float
    plane_thickness_m: float
    smoothed_output: bool = False


def _step_graphs(graphs, todo, accel, gyro, dt, reg, max_speed):
    """Steps the graphs ``todo``; returns their new states ``[n, 21]`` and outcome codes."""
    R, p = reg.R.numpy(), reg.p.numpy()
    info, ok = reg.information.numpy(), reg.ok.numpy()
    states = np.zeros((len(todo), 21))
    codes = np.full(len(todo), _OK)
    for n, b in enumerate(todo):
        pose = (R[b], p[b]) if ok[b] else None
        try:
            graphs[b].step(accel[b], gyro[b], dt[b], pose, info[b])
            states[n] = np.concatenate([graphs[b].latest(), graphs[b].biases()])
        except RuntimeError:  # gtsam: indeterminant / ill-posed linear system
            codes[n] = _DIVERGED
            continue
        except Exception as exc:  # noqa: BLE001 - one bad candidate must not end the evaluation
            _log.warning("gtsam graph %d failed: %s: %s", b, type(exc).__name__, exc)
            codes[n] = _FAILED
            continue
        if not np.isfinite(states[n]).all() or np.linalg.norm(states[n, 12:15]) > max_speed:
            codes[n] = _DIVERGED
    return np.nan_to_num(states), codes


def run_segment_gtsam(
    seg: PreparedSegment,
    motion: ReferenceMotion,
    starts: list[int],
    T_imu_lidar: Tensor,
    time_offset_s: Tensor,
    settings: GtsamRunSettings,
    shared_map: VoxelPlaneMap | FrozenPlaneMap | None,
    seeds: ScanTensors | None = None,
) -> RunResult:
    """Runs K candidates over ``seg`` as K×W graphs, one per candidate and window.

    Same windows, arguments and outputs as :func:`l2calib_backends.iekf.run_segment`.
    """
    K, W, N = T_imu_lidar.shape[0], len(starts), len(seg.end_t)
    nb = K * W
    dtype = T_imu_lidar.dtype
    ends = torch.tensor(starts[1:] + [N - 1])
    first, last = torch.tensor(starts).repeat(K), ends.repeat(K)
    cand = torch.arange(K).repeat_interleave(W)
    R_il, t_il = T_imu_lidar[cand, :3, :3], T_imu_lidar[cand, :3, 3]
    off = time_offset_s[cand]
    sigmas = dict(settings.graph.init_sigmas, grav=1.0)
    state = initial_states(motion, T_imu_lidar, sigmas)
    for name in ("R", "p", "v", "bg", "ba"):  # updated in place below
        setattr(state, name, getattr(state, name).clone())
    state.P = torch.eye(DIM, dtype=dtype).repeat(nb, 1, 1) * 1e-6  # unused: graphs hold it
    params = [imu_params(state.g[k * W].numpy(), settings.noise) for k in range(K)]
    graphs = [
        ScanGraph(
            params[int(cand[b])],
            state.R[b].numpy(),
            state.p[b].numpy(),
            state.v[b].numpy(),
            settings.graph,
        )
        for b in range(nb)
    ]
    groups = torch.arange(nb)[:, None]
    plane_map = shared_map
    if plane_map is None:
        if seeds is None:
            raise ValueError("the odometry mode needs the seed points of each window")
        plane_map = VoxelPlaneMap(settings.map_voxel_m, max_thickness_m=settings.plane_thickness_m)
        slot = torch.arange(W).repeat(K)
        world, keep = seeds.points[slot], seeds.mask[slot]
        plane_map.insert(world[keep], groups.expand(-1, keep.shape[1])[keep])
    map_groups = torch.zeros(nb, 1, dtype=torch.int64) if shared_map is not None else groups

    def query(p_w: Tensor, widen: bool):
        return plane_map.query(p_w, map_groups, widen)

    out = torch.zeros(K, N - 1, 4, 4, dtype=dtype)
    valid = torch.zeros(K, N - 1, dtype=torch.bool)
    status = torch.full((nb,), _OK, dtype=torch.int64)
    alive = torch.ones(nb, dtype=torch.bool)
    skipped = torch.zeros(nb, dtype=torch.int64)
    corr_sum = torch.zeros(nb, dtype=torch.float64)
    upd = seg.update
    for j in range(1, int((last - first).max()) + 1):
        scan = torch.minimum(first + j, last)
        active = (first + j) <= last
        t1 = seg.end_t[scan] + off
        t0 = torch.where(active, seg.end_t[scan - 1] + off, t1)
        prior, track = propagate(state, seg.imu, t0, t1, settings.noise)
        q = deskew(track, prior.R, prior.p, upd.points[scan], upd.dt_end[scan], t1, R_il, t_il)
        mask = upd.mask[scan] & active[:, None]
        reg = register_scans(
            prior.R, prior.p, q, mask, upd.ranges[scan], query, settings.registration
        )
        accel, gyro, dt = (x.numpy() for x in imu_intervals(seg.imu, t0, t1))
        todo = (active & alive).nonzero().squeeze(-1)
        new, codes = _step_graphs(
            graphs, todo.tolist(), accel, gyro, dt, reg, settings.max_speed_m_s
        )
        new, codes = torch.from_numpy(new), torch.from_numpy(codes)
        bad = codes != _OK
        status[todo[bad]] = codes[bad]
        alive[todo[bad]] = False
        good = todo[~bad]
        state.R[good] = new[~bad, :9].reshape(-1, 3, 3)
        state.p[good], state.v[good] = new[~bad, 9:12], new[~bad, 12:15]
        state.bg[good], state.ba[good] = new[~bad, 15:18], new[~bad, 18:21]
        n_ok = reg.num_matches
        corr_sum += torch.where(active, n_ok, 0).to(torch.float64)
        few = active & ~reg.ok
        skipped = torch.where(few, skipped + 1, skipped)
        lost = alive & (skipped >= settings.max_skipped_scans) & (status == _OK)
        status = torch.where(lost, _LOST, status)
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
    if settings.smoothed_output:
        _smoothed(graphs, alive, first, cand, T_imu_lidar, out)
    out = torch.where(valid[..., None, None], out, torch.eye(4, dtype=dtype))
    per_cand = status.reshape(K, W)
    cand_status = torch.where((per_cand == _DIVERGED).any(1), _DIVERGED, per_cand.max(1).values)
    return RunResult(out, valid, cand_status, corr_sum.reshape(K, W).sum(1) / max(N - 1, 1))


def _smoothed(graphs, alive, first, cand, T_imu_lidar: Tensor, out: Tensor) -> None:
    """Replaces the filtered poses of the surviving graphs by their final smoothed estimates."""
    for b in alive.nonzero().squeeze(-1).tolist():
        if graphs[b].index == 0:
            continue
        T_wi = torch.from_numpy(graphs[b].smoothed_poses())
        k, s0 = int(cand[b]), int(first[b])
        out[k, s0 : s0 + len(T_wi)] = T_wi @ T_imu_lidar[k]
