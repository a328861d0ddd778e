"""Rewards that turn trajectory agreement into a number in (0, 1].

* ``paper`` (L2Calib, Sec. III-C): after Umeyama-aligning the reference onto the estimate,

  ``R = exp(-sqrt(Σ e_t / (4N)) - sqrt(Σ e_r / (π² N)))``

  with ``e_t(i) = |R_e(i) t_BA + t_e(i) - t_r(i)|`` and
  ``e_r(i) = arccos((tr(R_e(i) R_BA R_r(i)ᵀ) - 1) / 2)``: the estimated IMU pose composed with the
  candidate extrinsic (= estimated LiDAR pose) against the aligned reference LiDAR pose. Note the
  paper sums the errors themselves, not their squares.
* ``position``: ``exp(-RMSE_t / 2)``, what the paper's public code computes; also used when the
  reference constrains positions only (RTK).

A candidate whose odometry failed gets reward 0 (worse than any finite error), never a score
computed on the poses it produced before failing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from l2calib.alignment import align_reference_to_estimates, pose_errors

RewardKind = Literal["paper", "position"]
AlignKind = Literal["se3", "sim3", "none"]


@dataclass(frozen=True)
class RewardBreakdown:
    """Reward and its ingredients for K candidates.

    Attributes:
        reward: ``[K]`` in ``[0, 1]``.
        mean_e_t: ``[K]`` mean translation error (m) over valid poses.
        mean_e_r: ``[K]`` mean rotation error (rad) over valid poses (NaN if not used).
        num_poses: ``[K]`` number of poses that entered the reward.
    """

    reward: Tensor
    mean_e_t: Tensor
    mean_e_r: Tensor
    num_poses: Tensor


def paper_reward(e_t: Tensor, e_r: Tensor, valid: Tensor | None = None) -> Tensor:
    """``exp(-sqrt(Σe_t/(4N)) - sqrt(Σe_r/(π²N)))`` over the last dim (paper, Sec. III-C)."""
    w = torch.ones_like(e_t) if valid is None else valid.to(e_t.dtype)
    n = w.sum(-1).clamp_min(1)
    term_t = torch.sqrt((e_t * w).sum(-1) / (4 * n))
    term_r = torch.sqrt((e_r * w).sum(-1) / (math.pi**2 * n))
    return torch.exp(-term_t - term_r)


def position_reward(e_t: Tensor, valid: Tensor | None = None) -> Tensor:
    """``exp(-RMSE_t / 2)`` over the last dim (the paper's public code)."""
    w = torch.ones_like(e_t) if valid is None else valid.to(e_t.dtype)
    n = w.sum(-1).clamp_min(1)
    return torch.exp(-torch.sqrt((e_t**2 * w).sum(-1) / n) / 2)


def lidar_poses_from_imu(T_world_imu: Tensor, T_imu_lidar: Tensor) -> Tensor:
    """Estimated LiDAR poses ``T_world_imu · T_imu_lidar`` (``[K, N, 4, 4]`` and ``[K, 4, 4]``)."""
    return T_world_imu @ T_imu_lidar[..., None, :, :]


def trajectory_reward(
    T_ref_lidar: Tensor,
    T_est_lidar: Tensor,
    valid: Tensor | None = None,
    kind: RewardKind = "paper",
    use_rotation: bool = True,
    failed: Tensor | None = None,
    min_poses: int = 3,
    align: AlignKind = "se3",
) -> RewardBreakdown:
    """Aligns the reference onto each estimate and scores the candidates.

    Args:
        T_ref_lidar: ``[N, 4, 4]`` (or ``[K, N, 4, 4]``) reference LiDAR poses at the estimate's
            stamps (see :func:`l2calib.alignment.associate`).
        T_est_lidar: ``[K, N, 4, 4]`` estimated LiDAR poses.
        valid: ``[K, N]`` poses that exist in both.
        kind: ``"paper"`` or ``"position"``.
        use_rotation: ``False`` drops the rotation term (position-only references); the
            ``paper`` reward then keeps only its translation term.
        failed: ``[K]`` bool, candidates whose odometry failed: reward 0.
        min_poses: Candidates with fewer valid poses than this get reward 0.
        align: ``"se3"`` (Umeyama on positions, the paper), ``"sim3"``, or ``"none"`` when the
            estimate is already expressed in the reference's frame (e.g. a backend started from
            the reference pose): position-only alignment of a nearly straight trajectory leaves
            the rotation about its direction to noise, which then pollutes ``e_r``.

    Returns:
        A :class:`RewardBreakdown`.
    """
    K, N = T_est_lidar.shape[:2]
    if valid is None:
        valid = torch.ones(K, N, dtype=torch.bool, device=T_est_lidar.device)
    # Backends must not return NaN, but poses marked invalid may hold anything: neutralise them
    # so they cannot poison the masked sums of the alignment.
    eye = torch.eye(4, dtype=T_est_lidar.dtype, device=T_est_lidar.device)
    T_est_lidar = torch.where(valid[..., None, None], T_est_lidar, eye)
    if align == "none":
        aligned = T_ref_lidar.expand_as(T_est_lidar)
    else:
        aligned = align_reference_to_estimates(T_ref_lidar, T_est_lidar, valid, align == "sim3")
    e_t, e_r = pose_errors(T_est_lidar, aligned)
    w = valid.to(e_t.dtype)
    n = w.sum(-1)
    if kind == "paper":
        reward = paper_reward(e_t, e_r if use_rotation else torch.zeros_like(e_r), valid)
    elif kind == "position":
        reward = position_reward(e_t, valid)
    else:
        raise ValueError(f"unknown reward kind {kind!r}")
    bad = n < min_poses
    if failed is not None:
        bad = bad | failed.to(torch.bool)
    reward = torch.where(bad, torch.zeros_like(reward), reward)
    mean_t = (e_t * w).sum(-1) / n.clamp_min(1)
    mean_r = (e_r * w).sum(-1) / n.clamp_min(1)
    if not use_rotation:
        mean_r = torch.full_like(mean_r, float("nan"))
    return RewardBreakdown(reward, mean_t, mean_r, n.to(torch.int64))
