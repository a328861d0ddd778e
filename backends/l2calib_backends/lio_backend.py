"""The shared part of the LiDAR-inertial backends (``iekf``, ``gtsam``).

:class:`LioBackend` prepares the data once (downsampled scans, the reference's motion at each
window start, the map) and runs every candidate over every prepared segment; a subclass
supplies the per-segment loop (:meth:`LioBackend._run_segment`) and its start-state priors.
Both backends therefore see exactly the same data.
"""

from __future__ import annotations

import logging
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np
import torch

from l2calib.data import Segment
from l2calib.errors import BackendError
from l2calib.interfaces import CandidateTrajectories, OdometryBackend, ReferenceTrajectory
from l2calib_backends.data_fraction import (
    WindowPlan,
    full_plan,
    motion_subset,
    plan_windows,
    seeds_subset,
    window_counts,
)
from l2calib_backends.iekf import RunResult
from l2calib_backends.initialise import ReferenceMotion, reference_motion
from l2calib_backends.options import AUTO_WINDOW_SCANS, LioOptions
from l2calib_backends.plane_map import VoxelPlaneMap
from l2calib_backends.prepare import PreparedSegment, prepare_segment
from l2calib_backends.reference_map import build_reference_maps, seed_points
from l2calib_backends.scan_loop import window_starts

_log = logging.getLogger(__name__)


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


class LioBackend(OdometryBackend):
    """Batched LIO over prepared segments; subclasses run the per-segment loop.

    Args:
        config: The backend's options (the :class:`~l2calib_backends.options.LioOptions` fields
            drive :meth:`prepare`).
    """

    outputs_in_reference_frame = True  # every filter / graph starts from the reference pose

    def __init__(self, config: LioOptions) -> None:
        self.config = config
        self.init_sigmas = config.init_sigmas()  # 'auto' resolved in prepare()
        self.window_scans = config.window_scans
        self._segments: list[PreparedSegment] = []
        self._motions: list[ReferenceMotion] = []
        self._starts: list[list[int]] = []
        self._seeds: list = []
        self._plans: list[WindowPlan] = []  # the windows evaluate() runs (use_data_fraction)
        self._maps: list[VoxelPlaneMap | None] = []  # per segment: its world frame's shared map
        if config.threads:
            torch.set_num_threads(config.threads)

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
                c.voxel_point,
            )
            for i, s in enumerate(segments)
        ]
        map_rng = np.random.default_rng(c.seed) if c.voxel_point == "random" else None
        rate = mean_rotation_rate(self._segments)
        weak = rate < c.weak_excitation_rate_rad_s
        self.window_scans = resolve_window_scans(c, self._segments)
        self._use_init_sigmas(c.init_sigmas(weak))
        self.start_biases = c.start_bias_mode(weak)
        _log.info(
            "mean |ω| %.2f rad/s (%s): %s, start priors %s, start biases %s",
            rate,
            "weakly excited" if weak else "well excited",
            "one continuous run per segment"
            if self.window_scans == 0
            else f"windows of {self.window_scans} scans",
            self.init_sigmas,
            self.start_biases,
        )
        self._starts = [window_starts(len(s.measurements), self.window_scans) for s in segments]
        self._plans = [
            full_plan(st, len(p.end_t)) for st, p in zip(self._starts, self._segments, strict=True)
        ]
        self._seeds = [None] * len(segments)
        if c.map_mode == "odometry":
            self._seeds = [
                seed_points(
                    s,
                    r.trajectory,
                    st,
                    c.scan_voxel_m / 4,
                    c.min_range_m,
                    c.max_range_m,
                    c.voxel_point,
                    map_rng,
                )
                for s, r, st in zip(segments, references, self._starts, strict=True)
            ]
        self._motions = [
            reference_motion(p, r.trajectory, st, self.start_biases)
            for p, r, st in zip(self._segments, references, self._starts, strict=True)
        ]
        self._maps = [None] * len(segments)
        if c.map_mode == "shared-map":
            self._maps = build_reference_maps(
                segments,
                references,
                c.map_voxel_m,
                c.plane_thickness_m,
                c.min_range_m,
                c.max_range_m,
                c.voxel_point,
                map_rng,
            )

    @abstractmethod
    def _use_init_sigmas(self, sigmas: dict[str, float]) -> None:
        """Takes the start-state priors resolved at :meth:`prepare` (``auto`` depends on data)."""

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
            for seg, motion, plan, seeds, shared in zip(
                self._segments, self._motions, self._plans, self._seeds, self._maps, strict=True
            ):
                res = self._run_segment(
                    seg, motion_subset(motion, plan.keep), plan.starts, T, off,
                    seeds_subset(seeds, plan.keep), plan.ends, shared,
                )  # fmt: skip
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

    def use_data_fraction(self, fraction: float) -> int:
        """Evaluates on about ``fraction`` of every segment; returns the scans per candidate.

        Which windows or scans: :mod:`l2calib_backends.data_fraction`.
        """
        if not self._segments:
            raise BackendError("use_data_fraction() called before prepare()", fix="call prepare()")
        # counted over all segments together; a continuous run is one window, kept whole
        counts = window_counts([len(st) for st in self._starts], float(fraction))
        self._plans = [
            plan_windows(st, len(seg.end_t), float(fraction), count=n)
            for st, seg, n in zip(self._starts, self._segments, counts, strict=True)
        ]
        return self.measurements_per_candidate()

    def measurements_per_candidate(self) -> int:
        """Scans each candidate is estimated on by :meth:`evaluate` now."""
        return sum(plan.scans for plan in self._plans)

    @abstractmethod
    def _run_segment(  # noqa: ANN001
        self, seg, motion, starts, T, off, seeds, ends=None, shared_map=None
    ) -> RunResult:
        """One prepared segment for all candidates ``T`` ``[K, 4, 4]`` with offsets ``off``.

        Windows start at ``starts`` and end at ``ends`` (default: each at the next start);
        ``shared_map``: the segment's world frame's map in shared-map mode, else ``None``.
        """
