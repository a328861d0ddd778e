"""The IEKF's run over one prepared segment: the shared scan driver with an iterated update.

Per scan (:func:`l2calib_backends.scan_loop.drive`): IMU propagation with covariance, per-point
deskew with the candidate extrinsic, then the FAST-LIO2-style iterated point-to-plane update of
:func:`l2calib_backends.update.iterated_update` as the correction step.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from l2calib.interfaces import CandidateStatus
from l2calib_backends.initialise import ReferenceMotion, initial_states
from l2calib_backends.plane_map import FrozenPlaneMap, VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, ScanTensors
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.scan_loop import (
    Batch,
    MapSettings,
    RunResult,
    StepInput,
    StepOutput,
    drive,
)
from l2calib_backends.update import UpdateSettings, iterated_update

__all__ = ["RunResult", "RunSettings", "run_segment"]


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


def run_segment(
    seg: PreparedSegment,
    motion: ReferenceMotion,
    starts: list[int],
    T_imu_lidar: Tensor,
    time_offset_s: Tensor,
    settings: RunSettings,
    shared_map: VoxelPlaneMap | FrozenPlaneMap | None,
    seeds: ScanTensors | None = None,
    ends: list[int] | None = None,
) -> RunResult:
    """Runs K candidates over ``seg`` as K×W filters, one per candidate and window.

    Windows, maps and statuses: :func:`l2calib_backends.scan_loop.drive`.
    """
    batch = Batch.layout(starts, len(seg.end_t), T_imu_lidar, time_offset_s, ends)
    ok = int(CandidateStatus.OK)

    def step(x: StepInput) -> StepOutput:
        post, n_ok = iterated_update(x.prior, x.points, x.mask, x.ranges, x.query, settings.update)
        updated = n_ok >= settings.update.min_correspondences
        return StepOutput(post, n_ok, updated, torch.full_like(n_ok, ok, dtype=torch.int64))

    prog = drive(
        seg,
        batch,
        initial_states(motion, T_imu_lidar, settings.init_sigmas, time_offset_s),
        settings.noise,
        step,
        shared_map,
        seeds,
        MapSettings(settings.map_voxel_m, settings.plane_thickness_m),
        settings.max_skipped_scans,
        settings.max_speed_m_s,
    )
    return prog.result(batch)
