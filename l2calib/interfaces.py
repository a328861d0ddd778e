"""Interfaces that plugins implement: odometry backends and reference sources.

They live in the core package so that third-party plugins depend on ``l2calib`` only;
``l2calib_backends`` re-exports :class:`OdometryBackend` for convenience.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

import numpy as np
import torch

from l2calib.data import Segment
from l2calib.trajectory import Trajectory


@dataclass(frozen=True, eq=False)
class ReferenceTrajectory:
    """A reference trajectory of the LiDAR frame for one segment.

    Attributes:
        segment: Name of the segment it belongs to.
        trajectory: Poses ``T_world_lidar`` (any world frame; the reward aligns it), int64 ns.
        constrains: ``"pose"`` if orientations are meaningful, ``"position"`` if only positions
            are (e.g. RTK): the reward then drops its rotation term.
        source: Name of the reference plugin that produced it.
        time_offset_hint_s: A LiDAR–IMU time offset (s, ``t_imu = t_lidar + offset``) the source
            measured on this segment (e.g. gt-file's clock check), used as the starting value
            when the offset is estimated; ``None``: nothing measured.
        alternative: The same reference computed another way, at the same stamps, whose
            difference from ``trajectory`` is about the size of ``trajectory``'s own error
            (ct-lidar with the backward pass: the forward pass alone, which differs from the
            two passes' average by half their disagreement); the uncertainty estimate re-scores
            against it. ``None``: the source has no second estimate.
    """

    segment: str
    trajectory: Trajectory
    constrains: Literal["pose", "position"] = "pose"
    source: str = ""
    time_offset_hint_s: float | None = None
    alternative: Trajectory | None = None


class ReferenceSource(ABC):
    """Produces a reference trajectory of the LiDAR per segment (group ``l2calib.references``)."""

    @abstractmethod
    def compute(self, segments: Sequence[Segment]) -> list[ReferenceTrajectory]:
        """Returns one reference per segment, in the same order."""


class CandidateStatus(IntEnum):
    """Outcome of one candidate extrinsic in :meth:`OdometryBackend.evaluate`."""

    OK = 0
    DIVERGED = 1  #: the filter blew up (huge innovation, NaN, covariance collapse)
    FEW_CORRESPONDENCES = 2  #: too few valid point associations to update
    FAILED = 3  #: any other per-candidate failure


@dataclass(frozen=True, eq=False)
class CandidateTrajectories:
    """Estimated LiDAR trajectories of K candidates over one segment.

    Attributes:
        segment: Segment name.
        stamps_ns: ``[N]`` int64 pose stamps, shared by all candidates (LiDAR clock).
        T_world_lidar: ``[K, N, 4, 4]`` float64 estimated LiDAR poses (the IMU pose estimate
            composed with the candidate extrinsic, as in the paper's reward).
        valid: ``[K, N]`` bool, poses that exist (False after divergence).
        status: ``[K]`` int64 :class:`CandidateStatus` codes.
    """

    segment: str
    stamps_ns: np.ndarray
    T_world_lidar: torch.Tensor
    valid: torch.Tensor
    status: torch.Tensor

    @property
    def num_candidates(self) -> int:
        """K."""
        return int(self.T_world_lidar.shape[0])


class OdometryBackend(ABC):
    """Tightly-coupled odometry that scores candidate extrinsics (group ``l2calib.backends``).

    Batched by design: :meth:`evaluate` runs K candidates in one call. A backend speaks of sensor
    measurements in general (``Segment.measurements``); a LiDAR backend reads ``Segment.scans``.

    Attributes:
        outputs_in_reference_frame: True if the estimates are expressed in the reference
            trajectory's world frame (the backend starts from the reference pose), so the reward
            needs no alignment.
    """

    outputs_in_reference_frame: bool = False

    @abstractmethod
    def prepare(
        self, segments: Sequence[Segment], references: Sequence[ReferenceTrajectory]
    ) -> None:
        """One-off work before evaluations (downsampling, caching, map building)."""

    @abstractmethod
    def evaluate(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ) -> list[CandidateTrajectories]:
        """Runs the odometry for K candidates on every prepared segment.

        Args:
            T_imu_lidar: ``[K, 4, 4]`` float64 candidate extrinsics (LiDAR -> IMU).
            time_offset_s: ``[K]`` float64 candidate offsets (``t_imu = t_lidar + offset``) or
                ``None`` for zero.

        Returns:
            One :class:`CandidateTrajectories` per prepared segment. Never raises for a single
            bad candidate: that is reported in ``status`` and ``valid``; never returns NaN.
        """

    def use_data_fraction(self, fraction: float) -> int:
        """Runs the following :meth:`evaluate` calls on about ``fraction`` (0–1] of the data.

        Optional (coarse-to-fine training): the trainer scores wide policies on a part of the
        prepared data. Every candidate of one call must see the same part, and ``1.0`` must
        restore all of it. A backend that cannot subsample keeps using everything.

        Returns:
            The number of measurements (scans) each candidate is estimated on from now on.
        """
        return self.measurements_per_candidate()

    def measurements_per_candidate(self) -> int:
        """Measurements (scans) each candidate is estimated on by :meth:`evaluate` now.

        Used to count the work (``candidate_scans``); ``0`` when the backend does not say.
        """
        return 0

    def close(self) -> None:  # noqa: B027 - optional hook
        """Releases resources (worker pools, files). Optional."""


@dataclass(frozen=True, eq=False)
class Extrinsic:
    """One extrinsic: a policy's mode, a candidate or a result.

    Attributes:
        T_imu_lidar: ``[4, 4]`` float64 transform mapping LiDAR-frame points into the IMU frame.
        time_offset_s: LiDAR–IMU time offset (s, ``t_imu = t_lidar + offset``), or ``None`` when
            it is not estimated.
    """

    T_imu_lidar: torch.Tensor
    time_offset_s: float | None = None

    @property
    def t_imu_lidar(self) -> torch.Tensor:
        """``[3]`` translation (m): the LiDAR's origin in the IMU frame."""
        return self.T_imu_lidar[:3, 3]

    @property
    def quat_xyzw(self) -> torch.Tensor:
        """``[4]`` rotation LiDAR → IMU as a unit quaternion (x, y, z, w)."""
        from l2calib.geometry import matrix_to_quat

        return matrix_to_quat(self.T_imu_lidar[:3, :3])


@dataclass(frozen=True, eq=False)
class PolicySpread:
    """Per-axis spreads of a policy (how wide it still samples), not an uncertainty of the data.

    Attributes:
        rotation_sigma_rad: ``[3]`` rotation σ about the mode's (LiDAR) axes (rad).
        translation_sigma_m: ``[3]`` translation σ along the IMU axes (m).
        time_offset_sigma_s: The time offset's σ (s), or ``None`` when it is not estimated.
    """

    rotation_sigma_rad: torch.Tensor
    translation_sigma_m: torch.Tensor
    time_offset_sigma_s: float | None = None

    @property
    def rotation_sigma_deg(self) -> torch.Tensor:
        """``[3]`` rotation σ (deg)."""
        return torch.rad2deg(self.rotation_sigma_rad)


class CalibrationPolicy(ABC):
    """What the trainer needs of a policy plugin (group ``l2calib.policies``).

    A plugin's spec builds one with ``spec.build(options, action_dim=7|8, prior=…, seed=…)``;
    ``action_dim`` comes from the env's ``action_spec`` (7: quaternion xyzw + translation m;
    8: + time offset s). Only where set, the training also passes ``init_time_offset_s``
    (the offset's starting mean, s) and ``rotation_start`` (an object with ``quat_xyzw`` and
    ``sigma_deg`` per LiDAR axis: :class:`l2calib.train.rotation_start.RotationStart`) and
    ``translation_start`` (``translation_m`` and ``sigma_m`` per IMU axis:
    :class:`l2calib.train.lever_start.LeverStart`), so a plugin that takes none of them still
    works where they are not set (``train.rotation_from_rates: off``).

    Attributes:
        actor: TorchRL ``ProbabilisticActor`` reading ``"observation"`` and writing ``"action"``
            ``[..., action_dim]`` and its log-probability (:attr:`log_prob_key`).
        value: TorchRL ``ValueOperator`` writing ``"state_value"``.
    """

    actor: torch.nn.Module
    value: torch.nn.Module

    @property
    @abstractmethod
    def log_prob_key(self) -> str:
        """Key of the action's log-probability in the actor's output."""

    @abstractmethod
    def mode(self) -> Extrinsic:
        """The most likely extrinsic (with ``time_offset_s`` when it is estimated)."""

    @abstractmethod
    def uncertainty(self) -> PolicySpread:
        """The policy's current per-axis spreads."""

    @abstractmethod
    def param_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        """Parameters by role (the trainer steps each group by its own rule).

        ``rotation_mean``, ``translation_mean``, optionally ``time_offset_mean`` (stepped in
        proportion to their spread) and ``other`` (spreads, value head).
        """
