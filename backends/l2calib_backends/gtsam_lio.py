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
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from l2calib.interfaces import CandidateStatus
from l2calib_backends.gtsam_graph import GraphSettings, ScanGraph, imu_intervals, imu_params
from l2calib_backends.initialise import ReferenceMotion, initial_states
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.registration import RegistrationSettings, register_scans
from l2calib_backends.scan_loop import (
    Batch,
    MapSettings,
    RunResult,
    StepInput,
    StepOutput,
    drive,
)
from l2calib_backends.state import DIM

_log = logging.getLogger(__name__)
_OK = int(CandidateStatus.OK)
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
    ends: list[int] | None = None,
) -> RunResult:
    """Runs K candidates over ``seg`` as K×W graphs, one per candidate and window.

    Same windows, arguments and outputs as :func:`l2calib_backends.iekf.run_segment`.
    """
    batch = Batch.layout(starts, len(seg.end_t), T_imu_lidar, time_offset_s, ends)
    dtype = T_imu_lidar.dtype
    sigmas = dict(settings.graph.init_sigmas, grav=1.0)
    state = initial_states(motion, T_imu_lidar, sigmas, time_offset_s)
    state.P = torch.eye(DIM, dtype=dtype).repeat(batch.B, 1, 1) * 1e-6  # unused: graphs hold it
    W = batch.W
    params = [imu_params(state.g[k * W].numpy(), settings.noise) for k in range(batch.K)]
    graphs = [
        ScanGraph(
            params[int(batch.cand[b])],
            state.R[b].numpy(),
            state.p[b].numpy(),
            state.v[b].numpy(),
            settings.graph,
            torch.cat([state.ba[b], state.bg[b]]).numpy(),
        )
        for b in range(batch.B)
    ]

    def step(x: StepInput) -> StepOutput:
        reg = register_scans(
            x.prior.R, x.prior.p, x.points, x.mask, x.ranges, x.query, settings.registration
        )
        accel, gyro, dt = (v.numpy() for v in imu_intervals(seg.imu, x.t0, x.t1))
        todo = (x.active & x.alive).nonzero().squeeze(-1)
        new, codes = _step_graphs(
            graphs, todo.tolist(), accel, gyro, dt, reg, settings.max_speed_m_s
        )
        new, codes = torch.from_numpy(new), torch.from_numpy(codes)
        all_codes = torch.full((batch.B,), _OK, dtype=torch.int64)
        all_codes[todo] = codes
        good = todo[codes == _OK]
        new = new[codes == _OK]
        post = replace(
            x.prior,
            R=x.prior.R.clone(),
            p=x.prior.p.clone(),
            v=x.prior.v.clone(),
            bg=x.prior.bg.clone(),
            ba=x.prior.ba.clone(),
        )
        post.R[good] = new[:, :9].reshape(-1, 3, 3)
        post.p[good], post.v[good] = new[:, 9:12], new[:, 12:15]
        post.bg[good], post.ba[good] = new[:, 15:18], new[:, 18:21]
        return StepOutput(post, reg.num_matches, reg.ok, all_codes)

    prog = drive(
        seg,
        batch,
        state,
        settings.noise,
        step,
        shared_map,
        seeds,
        MapSettings(settings.map_voxel_m, settings.plane_thickness_m),
        settings.max_skipped_scans,
        settings.max_speed_m_s,
    )
    if settings.smoothed_output:
        _smoothed(graphs, prog.alive, batch.first, batch.cand, T_imu_lidar, prog.out)
    return prog.result(batch)


def _smoothed(graphs, alive, first, cand, T_imu_lidar: Tensor, out: Tensor) -> None:
    """Replaces the filtered poses of the surviving graphs by their final smoothed estimates."""
    for b in alive.nonzero().squeeze(-1).tolist():
        if graphs[b].index == 0:
            continue
        T_wi = torch.from_numpy(graphs[b].smoothed_poses())
        k, s0 = int(cand[b]), int(first[b])
        out[k, s0 : s0 + len(T_wi)] = T_wi @ T_imu_lidar[k]
